"""Images: linear HDR as OpenEXR (written and read), display images as PNG (exposure + sRGB),
written atomically (io/files.py).

Images are float32 (H, W, 3) linear RGB radiance. Clipping to [0, 1] happens only when a
display image (PNG) is made; the EXR keeps the linear values.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import PopvolError
from .files import write_atomically

SUFFIXES = (".png", ".exr")


def linear_to_srgb(x):
    """The sRGB transfer function (IEC 61966-2-1) on linear values in [0, 1]."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def tonemap(rgb, exposure: float = 0.0) -> np.ndarray:
    """uint8 (H, W, 3) display image: scale by 2^exposure, sRGB-encode, clip to [0, 1], round."""
    x = np.asarray(rgb, np.float64) * 2.0**exposure
    return np.round(np.clip(linear_to_srgb(np.clip(x, 0.0, 1.0)), 0.0, 1.0) * 255).astype(np.uint8)


def _check(path: Path, rgb) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise PopvolError(f"{path}: image must be (height, width, 3), got {rgb.shape}")
    if not np.all(np.isfinite(rgb)) or rgb.min() < 0:
        raise PopvolError(f"{path}: image has non-finite or negative pixels; this is a popvol bug, please report it")
    if not path.parent.is_dir():
        raise PopvolError(f"{path}: folder {path.parent} does not exist")
    return rgb


def write_png(path, rgb, exposure: float = 0.0) -> None:
    from PIL import Image
    path = Path(path)
    rgb = _check(path, rgb)
    image = Image.fromarray(tonemap(rgb, exposure), "RGB")
    try:
        write_atomically(path, lambda tmp: image.save(tmp, format="PNG"))
    except OSError as e:
        raise PopvolError(f"{path}: cannot write PNG ({e})") from None


def write_exr(path, rgb) -> None:
    """Linear float32 RGB, ZIP-compressed scanlines."""
    import OpenEXR
    path = Path(path)
    rgb = np.ascontiguousarray(_check(path, rgb), np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    try:
        with OpenEXR.File(header, {"RGB": rgb}) as f:
            write_atomically(path, lambda tmp: f.write(str(tmp)))
    except Exception as e:  # the binding raises plain exceptions
        raise PopvolError(f"{path}: cannot write EXR ({e})") from None


def read_exr(path) -> np.ndarray:
    """float32 (H, W, 3) linear RGB from an EXR with R, G, B channels."""
    import OpenEXR
    path = Path(path)
    if not path.is_file():
        raise PopvolError(f"{path}: EXR file not found")
    try:
        with OpenEXR.File(str(path)) as f:
            ch = f.channels()
            if "RGB" in ch:
                rgb = ch["RGB"].pixels
            else:
                rgb = np.stack([ch[c].pixels for c in "RGB"], axis=-1)
    except KeyError as e:
        raise PopvolError(f"{path}: EXR has no {e} channel; popvol reads R, G, B") from None
    except Exception as e:
        raise PopvolError(f"{path}: cannot read EXR ({e})") from None
    return np.asarray(rgb, np.float32)


def write_image(path, rgb, exposure: float = 0.0) -> None:
    """Write by suffix: .png (tone mapped with ``exposure``) or .exr (linear)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        write_png(path, rgb, exposure)
    elif suffix == ".exr":
        write_exr(path, rgb)
    else:
        raise PopvolError(f"{path}: unsupported image type {suffix or '(none)'}; use one of {', '.join(SUFFIXES)}")
