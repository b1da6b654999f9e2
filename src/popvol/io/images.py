"""Images: linear HDR as OpenEXR (written and read), display images as PNG (exposure + a tone
curve + sRGB), written atomically (io/files.py).

Images are float32 (H, W, 3) linear Rec.709 RGB radiance. Tone mapping happens only when a
display image (PNG) is made; the EXR keeps the linear values.

Tone curves (:data:`TONES`):

- ``"aces"`` (default): the ACES 2.0 SDR output transform (100 nits, Rec.709 primaries, sRGB
  display encoding), applied by OpenColorIO from its built-in config :data:`OCIO_CONFIG`
  (pinned by version so that images stay reproducible). Mid grey 0.18 shows at 10 % of the
  display's white luminance (10 of 100 nits, sRGB code 89); highlights roll off instead of
  clipping (1.0 shows at code 180, 4.0 at 229, white is reached near 128).
- ``"clip"``: exposure, clip to [0, 1], sRGB encoding: popvol's tone curve before ACES.

Exposure is a number of stops or ``"auto"`` (:func:`auto_exposure`).
"""
from __future__ import annotations

import contextlib
import functools
import io
import math
import os
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from ..errors import PopvolError
from .files import file_name, folder_problem, why_missing, write_atomically_together

SUFFIXES = (".png", ".exr")
_FLOAT32_MAX = float(np.finfo(np.float32).max)

#: The tone curves of the PNG.
TONES = ("aces", "clip")

#: OpenColorIO's built-in config, pinned by version (it ships with OpenColorIO >= 2.6), and the
#: colour space, display and view of the "aces" tone curve.
OCIO_CONFIG = "cg-config-v5.0.0_aces-v2.1_ocio-v2.6"
OCIO_SOURCE = "Linear Rec.709 (sRGB)"
OCIO_DISPLAY = "sRGB - Display"
OCIO_VIEW = "ACES 2.0 - SDR 100 nits (Rec.709)"

#: Rec.709 / sRGB luminance weights (ITU-R BT.709).
LUMINANCE = (0.2126, 0.7152, 0.0722)

#: :func:`auto_exposure`: the percentile of the lit pixels' luminance that is metered ...
AUTO_PERCENTILE = 99.0
#: ... and the scene-linear value it is placed at, per tone curve: for "aces" 1.44 = 0.18 x 2^3,
#: Zone VIII of Adams's zone system (three stops over middle grey: "white with texture"),
#: which ACES 2.0 SDR shows at 77 % of the display's range (sRGB code 197); for "clip" the
#: value the sRGB encoding shows at that same 77 % (0.556), so both curves meter alike.
AUTO_TARGET = {"aces": 1.44, "clip": 0.556}

#: Scaled radiance is capped here before the float32 OCIO transform (ACES 2.0 SDR is white
#: from about 128 up; the cap keeps huge exposures from overflowing float32).
_CAP = 1e6
_CHUNK = 1 << 18                   # pixels tone mapped at a time (bounds the temporaries)


def linear_to_srgb(x):
    """The sRGB transfer function (IEC 61966-2-1) on linear values in [0, 1]."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def luminance(rgb) -> np.ndarray:
    """float64 (...) Rec.709 luminance of linear RGB (..., 3): an image, an environment map.
    By elementwise products, not ``rgb @ LUMINANCE``: a BLAS call on a large array leaves
    OpenBLAS's threads spinning, and they take the second core from the Numba kernels that
    follow (domains.frame_to_world)."""
    rgb = np.asarray(rgb)
    return sum(w * rgb[..., i].astype(np.float64) for i, w in enumerate(LUMINANCE))


def auto_exposure(rgb, mask=None, tone: str = "aces") -> float:
    """Exposure in stops from the image's Rec.709 luminance: the ``AUTO_PERCENTILE`` (99th)
    percentile of the lit pixels is placed at ``AUTO_TARGET[tone]`` (for "aces" 1.44, Zone
    VIII, shown at 77 % of the display's range, sRGB code 197).

    Why: expose for the highlights, as a photographer does for a sunlit cloud. The brightest
    percent of the frame (a cloud's sunlit rim, or the sky behind it) reads near-white with
    texture, not clipped, and the curve's shoulder keeps detail in the last percent above it.
    A percentile, unlike the maximum, ignores fireflies or a light seen directly; unlike a
    log-average key it does not turn a bright sky grey or depend on how much of the frame
    is background. The target was chosen by eye on the scenes of examples/.

    Only lit pixels count (luminance > 0; ``mask``, bool (H, W), narrows them further): a
    black background carries no exposure information. NaN and inf are ignored; an image
    with no lit pixel gets 0.0. Scale-free: ``auto_exposure(k * rgb) == auto_exposure(rgb) -
    log2(k)``.
    """
    if tone not in AUTO_TARGET:
        raise PopvolError(f"tone {tone!r} is unknown (known: {', '.join(TONES)})")
    y = luminance(rgb)
    ok = np.isfinite(y) & (y > 0)
    if mask is not None:
        ok &= np.asarray(mask, bool)
    y = y[ok]
    if y.size == 0:
        return 0.0
    key = float(np.percentile(y, AUTO_PERCENTILE))
    if not (key > 0 and math.isfinite(key)):
        return 0.0
    return math.log2(AUTO_TARGET[tone]) - math.log2(key)


#: The "aces" curve is applied as a 3-D table of the exact transform (:func:`_aces_processor`):
#: ACES_LUT_SIZE^3 samples over log2 of the scaled radiance from ACES_LUT_LOG2[0] (black to
#: the display: code 0) to ACES_LUT_LOG2[1] (white but for the most saturated colours),
#: interpolated tetrahedrally by OpenColorIO.
ACES_LUT_SIZE = 65
ACES_LUT_LOG2 = (-14.0, 9.0)


@functools.cache
def _exact_processor():
    """OpenColorIO's exact CPU processor of the ACES 2.0 SDR sRGB view (built once)."""
    try:
        import PyOpenColorIO as ocio
        config = ocio.Config.CreateFromBuiltinConfig(OCIO_CONFIG)
        exact = config.getProcessor(OCIO_SOURCE, OCIO_DISPLAY, OCIO_VIEW, ocio.TRANSFORM_DIR_FORWARD)
    except Exception as e:          # not installed, or too old to ship OCIO_CONFIG
        raise PopvolError(f"tone 'aces' needs OpenColorIO >= 2.6 with its built-in config {OCIO_CONFIG} "
                          f"(pip install 'opencolorio>=2.6'), or use tone 'clip' ({' '.join(str(e).split())})") from None
    return exact.getDefaultCPUProcessor()


@functools.cache
def _aces_processor():
    """OpenColorIO CPU processor of the ACES 2.0 SDR sRGB view, baked into a 3-D table.

    Why: the exact transform costs about 0.6 us per pixel on one core (0.15 s for a 640x360
    frame, a third of a viewer draft); the table costs 0.17 s once per process, then 0.09 us
    per pixel. On the gallery's Mitsuba references at their auto exposure and 3 stops either
    side, no pixel differs from the exact transform by more than one code (8 % of them by one);
    tests/test_tone.py checks this against the exact transform."""
    cpu = _exact_processor()                             # a one-line error if OCIO is missing
    import PyOpenColorIO as ocio
    n, (lo, hi) = ACES_LUT_SIZE, ACES_LUT_LOG2
    x = 2.0 ** np.linspace(lo, hi, n)
    grid = np.stack(np.meshgrid(x, x, x, indexing="ij"), -1).astype(np.float32).reshape(1, -1, 3)
    table = grid.copy()
    cpu.applyRGB(table)                                  # red slowest, blue fastest: OCIO's order
    # the exact transform maps one point of this grid, (189.0, 114.9, 89.5), to black (a
    # singularity of OpenColorIO 2.6's ACES 2.0 code); such points are taken 1e-4 brighter
    bad = (table.max(axis=-1) <= 0.0) & (grid.max(axis=-1) > 1e-2)
    if bad.any():
        nudged = grid[bad][None] * np.float32(1.0001)
        cpu.applyRGB(nudged)
        table[bad] = nudged[0]
    lut = ocio.Lut3DTransform(n)
    lut.setData(table.reshape(-1))
    lut.setInterpolation(ocio.INTERP_TETRAHEDRAL)
    shaper = ocio.AllocationTransform()
    shaper.setAllocation(ocio.ALLOCATION_LG2)            # log2, [lo, hi] -> [0, 1], clamped
    shaper.setVars([lo, hi])
    baked = ocio.Config.CreateRaw().getProcessor(ocio.GroupTransform([shaper, lut]))
    return baked.getDefaultCPUProcessor()


def aces_exact(rgb) -> np.ndarray:
    """float32 (..., 3): OpenColorIO's exact ACES 2.0 SDR sRGB view of linear ``rgb`` (display
    values in [0, 1], not rounded). Slow; what :func:`tonemap` approximates with a table."""
    x = np.array(rgb, np.float32).reshape(1, -1, 3)          # a copy: applyRGB works in place
    _exact_processor().applyRGB(x)
    return x.reshape(np.shape(rgb))


#: the exposures a number may give, in stops: method.exposure's range
EXPOSURE_STOPS = 64.0      # tests/test_tone.py holds it equal to KNOB["exposure"].allowed


def resolve_exposure(rgb, exposure="auto", tone: str = "aces") -> float:
    """``exposure`` in stops: the number itself (within +-EXPOSURE_STOPS), or
    :func:`auto_exposure` of ``rgb`` for "auto"."""
    if isinstance(exposure, str):
        if exposure != "auto":
            raise PopvolError(f"exposure {exposure!r} must be a number of stops or 'auto'")
        return auto_exposure(rgb, tone=tone)
    if isinstance(exposure, bool) or not isinstance(exposure, (int, float, np.integer, np.floating)) \
            or not abs(float(exposure)) <= EXPOSURE_STOPS:
        raise PopvolError(f"exposure = {exposure!r} must be 'auto' or a finite number of stops in "
                          f"[{-EXPOSURE_STOPS:g}, {EXPOSURE_STOPS:g}]")
    return float(exposure)


def tonemap(rgb, exposure="auto", tone: str = "aces") -> np.ndarray:
    """uint8 (H, W, 3) display image of the linear (H, W, 3) ``rgb``: scaled by 2^exposure
    (``exposure`` in stops, or "auto": :func:`auto_exposure`), then the ``tone`` curve
    ("aces": ACES 2.0 SDR via OpenColorIO; "clip": clip to [0, 1] and sRGB-encode), rounded."""
    if tone not in TONES:
        raise PopvolError(f"tone {tone!r} is unknown (known: {', '.join(TONES)})")
    scale = 2.0 ** resolve_exposure(rgb, exposure, tone)
    if tone == "clip":
        x = np.asarray(rgb, np.float64) * scale
        return np.round(np.clip(linear_to_srgb(np.clip(x, 0.0, 1.0)), 0.0, 1.0) * 255).astype(np.uint8)
    rgb = np.asarray(rgb)
    out = np.empty(rgb.shape, np.uint8)
    proc = _aces_processor()
    flat, flat_out = rgb.reshape(-1, 3), out.reshape(-1, 3)
    for i in range(0, flat.shape[0], _CHUNK):
        x = np.clip(flat[i:i + _CHUNK].astype(np.float64) * scale, 0.0, _CAP).astype(np.float32)[None]
        proc.applyRGB(x)
        flat_out[i:i + _CHUNK] = np.round(np.clip(x[0], 0.0, 1.0) * 255)
    return out


def _check(path: Path, rgb) -> np.ndarray:
    """``rgb`` as an image :func:`write_image` writes: (height, width, 3) real numbers, at least
    one pixel, finite, >= 0 and within float32's range (an EXR stores float32); else one line
    naming ``path``, how many pixels are wrong and where the first is."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise PopvolError(f"{path}: image must be (height, width, 3), got {rgb.shape}")
    if rgb.dtype.kind not in "fiub":
        raise PopvolError(f"{path}: image must hold real numbers, not {rgb.dtype} values")
    if rgb.size == 0:
        raise PopvolError(f"{path}: image has no pixels (shape {rgb.shape})")
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(rgb) & (rgb >= 0) & (rgb <= _FLOAT32_MAX)).all(axis=2)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise PopvolError(f"{path}: image has {int(bad.sum())} pixels that are NaN, infinite, negative or beyond "
                          f"float32's range (first at row {row}, column {col}: {rgb[row, col].tolist()}); it must be "
                          "linear radiance >= 0")
    if problem := folder_problem(path.parent):
        raise PopvolError(f"{path}: folder {path.parent} {problem}")
    return rgb


def _png_writer(path: Path, rgb, exposure="auto", tone: str = "aces"):
    """write(tmp) of an 8-bit sRGB PNG of :func:`tonemap` (``exposure`` in stops or "auto",
    ``tone``); OSError becomes a one-line PopvolError naming ``path``."""
    from PIL import Image
    image = Image.fromarray(tonemap(_check(path, rgb), exposure, tone), "RGB")

    def write(tmp):
        try:
            image.save(tmp, format="PNG")
        except OSError as e:
            raise PopvolError(f"{path}: cannot write PNG ({e})") from None
    return write


def _exr_writer(path: Path, rgb):
    """write(tmp) of linear float32 RGB, ZIP-compressed scanlines; the binding's errors become a
    one-line PopvolError naming ``path``."""
    import OpenEXR
    rgb = np.ascontiguousarray(_check(path, rgb), np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp):
        try:
            with OpenEXR.File(header, {"RGB": rgb}) as f:
                f.write(str(tmp))
        except Exception as e:  # the binding raises plain exceptions
            raise PopvolError(f"{path}: cannot write EXR ({e})") from None
    return write


def write_together(items) -> None:
    """Write (path, write) pairs together (io.files.write_atomically_together); a path that is a
    folder is refused before anything is written, and an OSError of the temporary files or the
    renames becomes a one-line PopvolError naming the first path."""
    for path, _ in items:
        if Path(path).is_dir():
            raise PopvolError(f"{path}: is a folder, not a file")
    try:
        write_atomically_together(items)
    except OSError as e:
        raise PopvolError(f"{items[0][0]}: cannot write ({e.strerror or e})") from None


def write_png(path, rgb, exposure="auto", tone: str = "aces") -> None:
    """8-bit sRGB PNG of :func:`tonemap` (``exposure`` in stops or "auto", ``tone``)."""
    path = Path(path)
    write_together([(path, _png_writer(path, rgb, exposure, tone))])


def write_exr(path, rgb) -> None:
    """Linear float32 RGB, ZIP-compressed scanlines."""
    path = Path(path)
    write_together([(path, _exr_writer(path, rgb))])


MAX_EXR_SIDE = 65536               # pixels on a side of an EXR that popvol reads (a 64k lat-long map)
MAX_EXR_PIXELS = 2 ** 29           # ... and in all: 6 GiB as float32 RGB


def exr_size(path) -> tuple[int, int]:
    """(width, height) of an EXR from its header alone, at most MAX_EXR_SIDE on a side and
    MAX_EXR_PIXELS in all; anything else is a one-line PopvolError naming the file."""
    import OpenEXR
    path = Path(path)
    if not path.is_file():
        raise PopvolError(f"{path}: EXR file {why_missing(path)}" if not path.exists() else f"{path}: not a file")
    try:
        with OpenEXR.File(str(path), header_only=True) as f:       # its size before its pixels
            (x0, y0), (x1, y1) = (np.asarray(v, np.int64) for v in f.header()["dataWindow"])
        width, height = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
    except Exception as e:  # the binding raises plain exceptions
        raise PopvolError(f"{path}: not a readable OpenEXR file ({e})") from None
    if not (0 < width <= MAX_EXR_SIDE and 0 < height <= MAX_EXR_SIDE and width * height <= MAX_EXR_PIXELS):
        raise PopvolError(f"{path}: EXR declares {width}x{height} pixels; popvol reads at most {MAX_EXR_SIDE} "
                          f"on a side and {MAX_EXR_PIXELS:.3g} in all")
    return width, height


def _flush_c_streams() -> None:
    """fflush(NULL): write out what C's stdio holds for every stream (C++'s std::cout shares
    C's stdout buffer), before the file descriptors it writes to are swapped back."""
    import ctypes
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)


#: one held block at a time: the file descriptors it swaps are the process's
_HOLDING = threading.Lock()


@contextlib.contextmanager
def library_output(said: list):
    """Hold what C/C++ code writes to the process's stdout and stderr (file descriptors 1 and 2)
    inside the block, and append it to ``said`` (one str) after: OpenEXR reports a damaged
    file's pixels there (its C library on stderr, the Python binding's warning on stdout) before
    the binding raises. Python's own streams are flushed first, so nothing of theirs is held;
    what another thread prints during the block is held with it (the block is one file read),
    and one block runs at a time (a lock), so threads reading EXRs do not swap each other's."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _flush_c_streams()
    python = io.StringIO()                 # what the binding prints through Python's streams
    with _HOLDING, tempfile.TemporaryFile() as held:
        saved = [os.dup(1), os.dup(2)]
        try:
            os.dup2(held.fileno(), 1)
            os.dup2(held.fileno(), 2)
            with contextlib.redirect_stdout(python), contextlib.redirect_stderr(python):
                yield
        finally:
            _flush_c_streams()             # C's stdout buffers what the library printed
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            held.seek(0)
            said.append(held.read(1 << 16).decode("utf-8", "replace") + python.getvalue()[:1 << 16])


def read_exr(path) -> np.ndarray:
    """float32 (H, W, 3) linear RGB from an EXR with R, G, B channels (its size checked first,
    :func:`exr_size`). Pixels the library cannot read (a file cut short, a corrupt chunk: it
    says so on the process's stdout or stderr, :func:`library_output`) are one PopvolError line
    naming the file, whatever the binding returns."""
    import OpenEXR
    path = Path(path)
    exr_size(path)
    said = []
    try:
        with library_output(said):
            with OpenEXR.File(str(path)) as f:
                ch = f.channels()
                if "RGB" in ch:
                    rgb = ch["RGB"].pixels
                elif "RGBA" in ch:              # the binding groups R, G, B and A into one array
                    rgb = ch["RGBA"].pixels[..., :3]
                else:
                    rgb = np.stack([ch[c].pixels for c in "RGB"], axis=-1)
    except KeyError as e:
        raise PopvolError(f"{path}: EXR has no {e} channel; popvol reads R, G, B") from None
    except Exception as e:
        raise PopvolError(f"{path}: cannot read EXR ({damage(said, path) or e})") from None
    if damage(said, path):
        raise PopvolError(f"{path}: cannot read EXR ({damage(said, path)})")
    return np.asarray(rgb, np.float32)


def damage(said: list, path: Path) -> str:
    """What OpenEXR said of ``path``'s pixels (:func:`library_output`), as a short reason
    without the file's name (the message has it): empty if it said nothing."""
    text = " ".join(" ".join(said).replace(f"{path}:", "").replace(str(path), "the file").split())
    if not text:
        return ""
    return f"its pixel data is truncated or corrupt; OpenEXR: {text[:160]}"


def image_writer(path, rgb, exposure="auto", tone: str = "aces"):
    """write(tmp) of the image :func:`write_image` writes at ``path`` (by its suffix), for
    io.files.write_atomically_together; its errors are one-line PopvolErrors naming ``path``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".png":
        return _png_writer(path, rgb, exposure, tone)
    if suffix == ".exr":
        return _exr_writer(path, rgb)
    raise PopvolError(f"{path}: unsupported image type {suffix or '(none)'}; use one of {', '.join(SUFFIXES)}")


def write_image(path, rgb, exposure="auto", tone: str = "aces", exr=None) -> None:
    """Write by suffix: .png (tone mapped with ``exposure`` and ``tone``, see :func:`tonemap`)
    or .exr (linear; exposure and tone do not apply). ``exr``: also write the linear image
    there, together with ``path``: if either write fails, neither file is replaced."""
    path = _output_path(path, "path")
    items = [(path, image_writer(path, rgb, exposure, tone))]
    if exr is not None:
        exr = _output_path(exr, "exr")
        if exr.suffix.lower() != ".exr":
            raise PopvolError(f"exr = {exr}: must name an .exr file")
        items.append((exr, _exr_writer(exr, rgb)))
    write_together(items)


def _output_path(path, name: str) -> Path:
    """``path`` (str or os.PathLike) as a Path; else one line naming the argument."""
    return Path(file_name(path, f"write_image: {name}"))
