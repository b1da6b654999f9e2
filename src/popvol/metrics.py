"""Image error metrics against a reference, and the comparison figure.

All functions take linear HDR images float (H, W, 3) of equal shape.
"""
from __future__ import annotations

import numpy as np

from .envmap import LUMINANCE
from .errors import PopvolError

RELMSE_EPS = 0.01


def _pair(img, ref):
    img = np.asarray(img, np.float64)
    ref = np.asarray(ref, np.float64)
    if img.shape != ref.shape:
        raise PopvolError(f"image {img.shape[1::-1]} and reference {ref.shape[1::-1]} differ in size; "
                          "render with the reference's width and height")
    return img, ref


def relmse(img, ref, eps: float = RELMSE_EPS) -> float:
    """Relative mean squared error: mean over pixels and channels of (img - ref)^2 / (ref^2 + eps)."""
    img, ref = _pair(img, ref)
    return float(np.mean((img - ref) ** 2 / (ref ** 2 + eps)))


def relmse_map(img, ref, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel relMSE (mean over channels), float64 (H, W)."""
    img, ref = _pair(img, ref)
    return np.mean((img - ref) ** 2 / (ref ** 2 + eps), axis=-1)


def rmse(img, ref) -> float:
    img, ref = _pair(img, ref)
    return float(np.sqrt(np.mean((img - ref) ** 2)))


def brightness_ratio(img, ref) -> float:
    """Mean of the image over mean of the reference (1 = equally bright)."""
    img, ref = _pair(img, ref)
    return float(img.mean() / max(ref.mean(), 1e-300))


def luminance(rgb) -> np.ndarray:
    """Relative luminance of linear RGB (Rec. 709 weights, ``envmap.LUMINANCE``), float64."""
    rgb = np.asarray(rgb, np.float64)
    return rgb @ LUMINANCE


def ssim(img, ref) -> float:
    """Structural similarity of the luminances (scikit-image, data range = reference's max)."""
    from skimage.metrics import structural_similarity
    img, ref = _pair(img, ref)
    a, b = luminance(img), luminance(ref)
    win = min(7, *(s - (1 - s % 2) for s in a.shape))     # odd, <= image size
    if win < 3:
        return float("nan")
    return float(structural_similarity(a, b, data_range=max(float(b.max() - b.min()), 1e-12), win_size=win))


def flip(img, ref) -> float | None:
    """Mean HDR-FLIP error (NVIDIA's flip-evaluator), or None if it is not installed or the
    reference has no light to set FLIP's exposure range from (it exits the process then)."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    img, ref = _pair(img, ref)
    lum = luminance(ref)
    if not lum.max() > 0 or not np.median(lum) >= 0:
        return None
    try:
        _, mean_error, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref, np.float32),
                                                   np.ascontiguousarray(np.maximum(img, 0), np.float32), "HDR")
    except (SystemExit, RuntimeError, ValueError):
        return None
    return float(mean_error)


def compare(img, ref) -> dict:
    """Every metric at once (the keys of ``popvol compare --json``)."""
    return {"relmse": relmse(img, ref), "relmse_eps": RELMSE_EPS, "rmse": rmse(img, ref),
            "brightness_ratio": brightness_ratio(img, ref), "ssim": ssim(img, ref), "flip": flip(img, ref)}


def comparison_figure(path, img, ref, exposure: float = 0.0, title: str = "") -> None:
    """popvol | reference | per-pixel relative error (log scale heat map with a colour bar)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from .io.images import tonemap
    img, ref = _pair(img, ref)
    h, w = ref.shape[:2]
    aspect = w / h
    fig, axes = plt.subplots(1, 3, figsize=(3 * 3.6 * aspect / 1.2 + 1.2, 3.6 / 1.2 + 0.6), dpi=80,
                             gridspec_kw={"width_ratios": [1, 1, 1.12]})
    err = np.sqrt(relmse_map(img, ref))          # relative error per pixel
    axes[0].imshow(tonemap(img, exposure))
    axes[0].set_title(f"popvol (brightness x{brightness_ratio(img, ref):.2f})")
    axes[1].imshow(tonemap(ref, exposure))
    axes[1].set_title("reference")
    im = axes[2].imshow(np.maximum(err, 1e-3), cmap="inferno", norm=LogNorm(vmin=1e-3, vmax=max(1.0, err.max())))
    axes[2].set_title(f"relative error (relMSE {relmse(img, ref):.3g})")
    fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.02, label="|popvol - ref| / sqrt(ref^2 + 0.01)")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
