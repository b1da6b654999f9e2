"""Image error metrics of popvol against a reference, on the pixels that see the medium, and the
comparison figure.

Images are linear HDR RGB, float (H, W, 3) of equal shape (any float dtype; computed in
float64). A *mask* is bool (H, W): the pixels that see the medium. The relative metrics are
taken on those pixels only, so that a black background adds no zeros to them and a sky seen
around the medium does not count.

Definitions (M = the masked pixels, N = |M|, Y = luminance = RGB . ``io.images.LUMINANCE``):

- ``eps = EPS_FRACTION * (mean over M of Y_ref)^2``, ``EPS_FRACTION = 0.01``: a floor of the
  denominator one tenth of the medium's mean luminance, squared. It scales with the
  reference, so every metric below is unchanged when both images are scaled by the same
  factor.
- relMSE = ``1 / (3 N) * sum over p in M and the channels c of
  (img[p, c] - ref[p, c])^2 / (ref[p, c]^2 + eps)``: per channel, so that an error of colour
  counts as well as one of luminance; one eps (from the luminance) for all three channels.
- brightness ratio = ``sum over M of Y_img / sum over M of Y_ref`` (1 = equally bright).
- band ratios: the same ratio on three bands of M by the reference's luminance rank: the
  dimmest 50 % of M (``dim``), the next 40 % (``mid``) and the brightest 10 % (``bright``);
  ties are split by pixel order (a stable sort), so the bands always have those sizes.
  Ranked by a noisy reference, its brightest pixels are also those whose noise came out
  high, so a band's ratio would be biased by the reference's own noise: low in the bright
  band, high in the dim one (a Mitsuba image against an independent Mitsuba reference of the
  same scene, the sun behind the camera, 1024 spp each: dim x1.26, bright x0.70;
  scripts/band_bias.py). Where the reference
  holds two independent images (``Reference.halves``: its passes in subset B and the others),
  each is ranked and the band measured against the other: ``sum over both of Y_img on the
  band of one / sum over both of Y_ref of the other on it`` (:func:`band_ratios`), which no
  pixel's own noise selects. The half's noise still mixes some pixels of the next band into
  each, so a real flattening of the contrast shows a little smaller than ranked by the truth
  (tests/test_metrics.py: x0.87 against x0.84 in the brightest tenth, halves of 20 % noise).
- the reference's own noise, in the same metric: ``1 / (3 N) * sum over M and c of
  var[p, c] / (ref[p, c]^2 + eps)`` with ``var`` the variance of the reference's mean per pixel
  (``Reference.variance``) and the same eps and mask: the relMSE expected of the reference
  itself against the truth.
- relMSE against a noiseless reference, extrapolated (:func:`extrapolated_relmse`): against a
  reference that averages P independent passes, the expected relMSE is about ``e + c / P``,
  ``e`` popvol's relMSE against the truth and ``c / P`` what the reference's noise adds (its
  variance falls as 1 / P). Measured against the reference (P passes) and against each of its
  two independent halves (``Reference.halves``, P_a and P_b passes), the three figures give
  ``e`` and ``c`` by least squares. This sees the noise as the metric does, which the variance
  estimate above does not: that one leaves out what the noise does through the denominator
  (ref^2 + eps), and a few passes misjudge a variance that rare bright samples (fireflies)
  carry. On the suite's references the share the fit finds, ``c / P``, is 0.4-1.6 times the
  variance estimate (2.3 on a 768-spp reference of the densest cloud; docs/ACCURACY.md), and on
  three references extended after the fit it predicted their relMSE (README, "What it
  computes").

The mask: with the scene at hand, :func:`optical_depth_mask`, the pixels whose camera ray
(through the pixel's centre) crosses the medium with optical depth above
``MASK_OPTICAL_DEPTH``; without it, :func:`luminance_mask`, the pixels whose reference
luminance exceeds ``LUMINANCE_MASK_FRACTION`` of its maximum. The latter is right only on a
black background: a bright background (a sky) passes it everywhere.

A metric without a value (an empty mask, a reference that is black on the mask, an empty band)
is NaN.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .io.images import LUMINANCE, luminance
from .errors import PopvolError
from .io.files import write_atomically

#: eps of relMSE = EPS_FRACTION * (mean reference luminance on the mask)^2
EPS_FRACTION = 0.01
#: a camera ray sees the medium when its optical depth exceeds this (about 1 % extinction)
MASK_OPTICAL_DEPTH = 0.01
#: fallback mask without a scene: reference luminance above this fraction of its maximum
LUMINANCE_MASK_FRACTION = 0.01
#: (name, lower, upper) fractions of the masked pixels ranked by reference luminance
BANDS = (("dim", 0.0, 0.5), ("mid", 0.5, 0.9), ("bright", 0.9, 1.0))


def _pair(img, ref):
    img = np.asarray(img, np.float64)
    ref = np.asarray(ref, np.float64)
    if img.shape != ref.shape:
        raise PopvolError(f"image {img.shape[1::-1]} and reference {ref.shape[1::-1]} differ in size; "
                          "render with the reference's width and height")
    return img, ref


# -- the mask ------------------------------------------------------------------------------

def luminance_mask(ref, fraction: float = LUMINANCE_MASK_FRACTION) -> np.ndarray:
    """bool (H, W): reference luminance above ``fraction`` of its maximum (none if the reference
    is black). The fallback when the scene is not at hand; it assumes a black background (a
    bright sky passes it everywhere; :func:`optical_depth_mask` does not)."""
    y = luminance(ref)
    top = float(y.max()) if y.size else 0.0
    if not top > 0:
        return np.zeros(y.shape, bool)
    return y > fraction * top


def camera_optical_depth(scene, step: float = 0.5) -> np.ndarray:
    """float64 (H, W): optical depth of each camera ray through its pixel's centre across the
    medium, in the channel of largest extinction (``max(scale) * integral of density``).

    Marched from the ray's entry to its exit of the medium's box with at most ``step`` times the
    smallest voxel size (midpoint rule), the density trilinear between voxel centres and
    clamped to the edge in the outer half cell, as the renderer takes it.
    """
    cam, med = scene.camera, scene.medium
    lo, hi = med.bounds
    tau = np.zeros(cam.height * cam.width)
    _optical_depth(np.ascontiguousarray(cam.ray_directions().reshape(-1, 3)), np.asarray(cam.origin, np.float64),
                   lo, hi, med.density, np.asarray(med.origin, np.float64), np.asarray(med.voxel_size, np.float64),
                   step * float(med.voxel_size.min()), tau)
    return tau.reshape(cam.height, cam.width) * float(np.max(med.scale))


@nb.njit(parallel=True, cache=True)
def _optical_depth(dirs, o, lo, hi, density, origin, voxel, h, out):
    """out[r] = integral of the density along o + t dirs[r] inside the box [lo, hi] (t >= 0)."""
    nx, ny, nz = density.shape
    for r in nb.prange(dirs.shape[0]):
        t0, t1 = 0.0, np.inf
        for a in range(3):
            da = dirs[r, a]
            if da == 0.0:
                if o[a] < lo[a] or o[a] > hi[a]:
                    t1 = -1.0
                continue
            ta, tb = (lo[a] - o[a]) / da, (hi[a] - o[a]) / da
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if not t1 > t0:
            continue
        n = max(1, int(np.ceil((t1 - t0) / h)))
        dt = (t1 - t0) / n
        acc = 0.0
        for k in range(n):
            t = t0 + (k + 0.5) * dt
            cx = min(max((o[0] + t * dirs[r, 0] - origin[0]) / voxel[0], 0.0), nx - 1.0)
            cy = min(max((o[1] + t * dirs[r, 1] - origin[1]) / voxel[1], 0.0), ny - 1.0)
            cz = min(max((o[2] + t * dirs[r, 2] - origin[2]) / voxel[2], 0.0), nz - 1.0)
            i, j, l = min(int(cx), max(nx - 2, 0)), min(int(cy), max(ny - 2, 0)), min(int(cz), max(nz - 2, 0))
            fx, fy, fz = cx - i, cy - j, cz - l
            i1, j1, l1 = min(i + 1, nx - 1), min(j + 1, ny - 1), min(l + 1, nz - 1)
            acc += ((1 - fx) * ((1 - fy) * ((1 - fz) * density[i, j, l] + fz * density[i, j, l1])
                                + fy * ((1 - fz) * density[i, j1, l] + fz * density[i, j1, l1]))
                    + fx * ((1 - fy) * ((1 - fz) * density[i1, j, l] + fz * density[i1, j, l1])
                            + fy * ((1 - fz) * density[i1, j1, l] + fz * density[i1, j1, l1])))
        out[r] = acc * dt


def medium_in_view(scene, threshold: float = MASK_OPTICAL_DEPTH) -> bool:
    """Whether any pixel is in :func:`optical_depth_mask`: some camera ray through a pixel's
    centre crosses the medium with optical depth above ``threshold``. False at once where the
    medium cannot reach it (max(scale) x max(density) x the box's diagonal); else the rays are
    marched as :func:`camera_optical_depth` marches them, in chunks that grow from 256 rays,
    spread over the image (a stride permutation of the pixels), until one crosses: a medium in
    view is found after a few rays, and the directions of a large image are never all held."""
    cam, med = scene.camera, scene.medium
    lo, hi = med.bounds
    scale = float(np.max(med.scale))
    if not scale * float(med.density.max()) * float(np.linalg.norm(hi - lo)) > threshold:
        return False
    n, w, h = cam.width * cam.height, cam.width, cam.height
    stride = next(p for p in (1_000_003, 999_983, 999_979) if math.gcd(p, n) == 1)
    fwd, right, up = cam.basis()
    tan_half = np.tan(np.radians(cam.fov) / 2)
    origin, voxel = np.asarray(med.origin, np.float64), np.asarray(med.voxel_size, np.float64)
    start, size = 0, 256
    while start < n:
        idx = (np.arange(start, min(start + size, n), dtype=np.int64) * stride) % n
        px, py = idx % w + 0.5, idx // w + 0.5           # as Camera.ray_directions
        sx = (2 * px / w - 1) * tan_half * (w / h)
        sy = (1 - 2 * py / h) * tan_half
        d = fwd + sx[:, None] * right + sy[:, None] * up
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        tau = np.zeros(len(idx))
        _optical_depth(np.ascontiguousarray(d), np.asarray(cam.origin, np.float64), lo, hi, med.density, origin,
                       voxel, 0.5 * float(voxel.min()), tau)
        if np.any(tau * scale > threshold):
            return True
        start, size = start + size, min(2 * size, 65536)
    return False


def optical_depth_mask(scene, threshold: float = MASK_OPTICAL_DEPTH) -> np.ndarray:
    """bool (H, W): the pixels whose camera ray crosses the medium with optical depth above
    ``threshold`` (:func:`camera_optical_depth`): the medium's pixels whatever the background."""
    return camera_optical_depth(scene) > threshold


def medium_mask(ref, scene=None) -> np.ndarray:
    """The metrics' mask, bool (H, W): :func:`optical_depth_mask` of ``scene`` if given (its
    camera must be the reference's size), else :func:`luminance_mask` of ``ref``."""
    if scene is None:
        return luminance_mask(ref)
    mask = optical_depth_mask(scene)
    ref = np.asarray(ref)
    if mask.shape != ref.shape[:2]:
        raise PopvolError(f"camera {mask.shape[1]}x{mask.shape[0]} and reference "
                          f"{ref.shape[1]}x{ref.shape[0]} differ in size")
    return mask


def _mask(mask, ref) -> np.ndarray:
    if mask is None:
        return luminance_mask(ref)
    mask = np.asarray(mask)
    if mask.shape != ref.shape[:2]:
        raise PopvolError(f"mask {mask.shape[1::-1]} and reference {ref.shape[1::-1]} differ in size")
    return mask.astype(bool)


# -- the metrics ---------------------------------------------------------------------------

def relmse_eps(ref, mask=None) -> float:
    """eps of relMSE: ``EPS_FRACTION * (mean reference luminance on the mask)^2`` (NaN on an
    empty mask). ``mask`` bool (H, W), default :func:`luminance_mask`."""
    ref = np.asarray(ref, np.float64)
    mask = _mask(mask, ref)
    if not mask.any():
        return float("nan")
    return EPS_FRACTION * float(luminance(ref)[mask].mean()) ** 2


def _relative(num, ref, mask):
    """Mean over masked pixels and channels of num / (ref^2 + eps); NaN where undefined."""
    eps = relmse_eps(ref, mask)
    if not eps > 0:
        return float("nan")
    return float(np.mean(num[mask] / (ref[mask] ** 2 + eps)))


def relmse(img, ref, mask=None) -> float:
    """Scale-free relMSE on the medium's pixels (module docstring): mean over the masked pixels
    and the 3 channels of (img - ref)^2 / (ref^2 + eps), eps = :func:`relmse_eps`.
    ``mask`` bool (H, W), default :func:`luminance_mask` of ``ref``."""
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    return _relative((img - ref) ** 2, ref, mask)


def relmse_map(img, ref, mask=None) -> np.ndarray:
    """Per-pixel relMSE (mean over channels, the same eps), float64 (H, W); NaN off the mask."""
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    eps = relmse_eps(ref, mask)
    out = np.full(ref.shape[:2], np.nan)
    if eps > 0:
        out[mask] = np.mean((img[mask] - ref[mask]) ** 2 / (ref[mask] ** 2 + eps), axis=-1)
    return out


def noise_relmse(variance, ref, mask=None) -> float:
    """The reference's own noise in the relMSE above: mean over the masked pixels and channels
    of variance / (ref^2 + eps), same eps. ``variance`` float (H, W, 3), the variance of the
    reference's mean per pixel; ``mask`` bool (H, W), default :func:`luminance_mask`."""
    var, ref = _pair(variance, ref)
    mask = _mask(mask, ref)
    return _relative(var, ref, mask)


def extrapolated_relmse(img, ref, halves, half_passes, mask=None) -> dict:
    """popvol's relMSE against a noiseless reference, extrapolated from the reference's passes.

    ``ref`` float (H, W, 3), the mean of P = P_a + P_b independent passes; ``halves`` its two
    independent parts (float (H, W, 3) each: the mean of P_a passes and of the other P_b,
    ``Reference.halves``); ``half_passes`` (P_a, P_b) (``Reference.half_passes``). The relMSE
    against a mean of P passes is expected to be ``e + c / P`` (module docstring); fitted by least
    squares to the relMSE against ``ref`` and against each half (the same mask and, per image, its
    own eps). Returns {"relmse": e, "noise": c / P}: popvol's relMSE against the truth and what the
    reference's noise adds to its relMSE against ``ref``. ``e`` may come out a little below 0 where
    popvol is within the reference's noise. Both None without halves or their pass counts; NaN
    where relMSE is undefined (an empty mask, a black reference)."""
    out = {"relmse": None, "noise": None}
    if halves is None or half_passes is None:
        return out
    pa, pb = (int(n) for n in half_passes)
    if pa < 1 or pb < 1:
        return out
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    counts = np.array([pa + pb, pa, pb], np.float64)
    figures = np.array([relmse(img, r, mask) for r in (ref, *(_pair(h, ref)[0] for h in halves))])
    if not np.all(np.isfinite(figures)):
        return {"relmse": float("nan"), "noise": float("nan")}
    # the straight line through (1 / P, relMSE) by least squares: slope c, intercept e
    x = 1.0 / counts
    c = float(np.sum((x - x.mean()) * (figures - figures.mean())) / np.sum((x - x.mean()) ** 2))
    e = float(figures.mean() - c * x.mean())
    return {"relmse": e, "noise": c / counts[0]}


def equal_error(error, noise, ref_spp, ref_seconds, popvol_seconds) -> dict:
    """How long the reference renderer would need to be as close to the truth as popvol is.

    ``error``: popvol's relMSE against the truth; ``noise``: what the reference's noise adds to
    the relMSE against it, the reference's own relMSE against the truth (both from
    :func:`extrapolated_relmse`, or the measured relMSE less :func:`noise_relmse` and that noise).
    The noise of a mean of independent samples falls as 1 / spp, so it equals ``error`` at
    ``spp = ref_spp * noise / error`` samples per pixel, which cost ``ref_seconds / ref_spp``
    each.

    Returns {"spp", "seconds", "speedup"} (speedup = those seconds / ``popvol_seconds``), each
    None when it cannot be told: no noise estimate (fewer than 2 passes), no timing, an error
    no larger than the noise (the reference is too noisy to show popvol's error), or a figure
    that would not be a finite number (computed in Python floats: no NumPy overflow warning)."""
    out = {"spp": None, "seconds": None, "speedup": None}
    if noise is None or error is None:
        return out
    noise, error = float(noise), float(error)
    if not (math.isfinite(noise) and noise > 0 and math.isfinite(error) and error > noise):
        return out

    def finite(x):
        return x if math.isfinite(x) else None
    out["spp"] = finite(float(ref_spp) * (noise / error))
    if out["spp"] is not None and ref_seconds and ref_seconds > 0 and ref_spp > 0:
        out["seconds"] = finite(float(ref_seconds) / float(ref_spp) * out["spp"])
        if out["seconds"] is not None and popvol_seconds and popvol_seconds > 0:
            out["speedup"] = finite(out["seconds"] / float(popvol_seconds))
    return out


def _ratio(y_img, y_ref) -> float:
    den = float(y_ref.sum())
    return float(y_img.sum()) / den if den > 0 else float("nan")


def brightness_ratio(img, ref, mask=None) -> float:
    """Sum of popvol's luminance over the reference's on the mask (1 = equally bright).
    ``mask`` bool (H, W), default :func:`luminance_mask` of ``ref``."""
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    return _ratio(luminance(img)[mask], luminance(ref)[mask])


def bands(ref, mask=None) -> dict:
    """The masked pixels in three bands of the reference's luminance: {name: bool (H, W)} for
    ``BANDS`` (dimmest 50 %, next 40 %, brightest 10 % of the mask's pixels by rank)."""
    ref = np.asarray(ref, np.float64)
    mask = _mask(mask, ref)
    flat = np.flatnonzero(mask)
    ranked = flat[np.argsort(luminance(ref).ravel()[flat], kind="stable")]
    n = len(ranked)
    out = {}
    for name, a, b in BANDS:
        m = np.zeros(mask.size, bool)
        m[ranked[int(np.floor(a * n)): int(np.floor(b * n)) if b < 1 else n]] = True
        out[name] = m.reshape(mask.shape)
    return out


def band_ratios(img, ref, mask=None, halves=None) -> dict:
    """{"dim", "mid", "bright"}: :func:`brightness_ratio` on each of :func:`bands` of ``ref``.

    ``halves``: two independent images of the reference (float (H, W, 3) each, e.g.
    ``Reference.halves``) or None. With them each half is ranked into bands and each band is
    measured against the other half (module docstring), so that the reference's noise does not
    pick the pixels it is measured on."""
    img, ref = _pair(img, ref)
    y_img = luminance(img)
    mask = _mask(mask, ref)
    if halves is None:
        y_ref = luminance(ref)
        return {name: _ratio(y_img[b], y_ref[b]) for name, b in bands(ref, mask).items()}
    a, b = (_pair(h, ref)[0] for h in halves)
    y_a, y_b = luminance(a), luminance(b)
    on_a, on_b = bands(a, mask), bands(b, mask)
    return {name: _ratio(np.concatenate([y_img[on_a[name]], y_img[on_b[name]]]),
                         np.concatenate([y_b[on_a[name]], y_a[on_b[name]]])) for name in on_a}


def ratio_map(img, ref, mask=None) -> np.ndarray:
    """Per-pixel popvol / reference luminance, float64 (H, W); NaN off the mask and where the
    reference is black."""
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    y_img, y_ref = luminance(img), luminance(ref)
    out = np.full(ref.shape[:2], np.nan)
    ok = mask & (y_ref > 0)
    out[ok] = y_img[ok] / y_ref[ok]
    return out


def rmse(img, ref) -> float:
    """Root mean squared error over the whole frame and the channels (absolute, in radiance)."""
    img, ref = _pair(img, ref)
    return float(np.sqrt(np.mean((img - ref) ** 2)))


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


def compare(img, ref, mask=None, variance=None, halves=None, half_passes=None) -> dict:
    """Every metric at once (the metric keys of ``popvol compare --json``).

    ``mask`` bool (H, W), default :func:`luminance_mask` of ``ref``; ``variance`` float (H, W, 3),
    the reference's variance of the mean, for ``reference_noise_relmse`` (None without it);
    ``halves``, two independent images of the reference for the bands (:func:`band_ratios`) and,
    with ``half_passes`` (their pass counts), for :func:`extrapolated_relmse`.
    Keys: relmse, relmse_eps, relmse_extrapolated (against a noiseless reference),
    reference_noise_observed (what the reference's noise adds to relmse, from the same fit),
    brightness_ratio, brightness_bands {dim, mid, bright}, bands_ranked_on ("independent halves"
    or "the reference"), reference_noise_relmse (from the variance), mask_pixels, pixels, rmse
    (whole frame, absolute), ssim, flip.
    """
    img, ref = _pair(img, ref)
    mask = _mask(mask, ref)
    extrapolated = extrapolated_relmse(img, ref, halves, half_passes, mask)
    return {"relmse": relmse(img, ref, mask), "relmse_eps": relmse_eps(ref, mask),
            "relmse_extrapolated": extrapolated["relmse"], "reference_noise_observed": extrapolated["noise"],
            "brightness_ratio": brightness_ratio(img, ref, mask),
            "brightness_bands": band_ratios(img, ref, mask, halves),
            "bands_ranked_on": "the reference" if halves is None else "independent halves",
            "reference_noise_relmse": None if variance is None else noise_relmse(variance, ref, mask),
            "mask_pixels": int(mask.sum()), "pixels": int(mask.size),
            "rmse": rmse(img, ref), "ssim": ssim(img, ref), "flip": flip(img, ref)}


def comparison_figure(path, img, ref, exposure="auto", title: str = "", mask=None, tone: str = "aces") -> None:
    """popvol | reference | per-pixel relative error (log heat map) | luminance ratio popvol /
    reference (diverging around 1, log scale 0.5 to 2); both maps on the mask only (``mask``
    bool (H, W), default :func:`luminance_mask` of ``ref``). popvol and the reference are tone
    mapped alike: ``exposure`` in stops, or "auto" from the reference, and ``tone``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from .io.images import resolve_exposure, tonemap
    img, ref = _pair(img, ref)
    exposure = resolve_exposure(ref, exposure, tone)          # the same stops for both
    mask = _mask(mask, ref)
    h, w = ref.shape[:2]
    aspect = w / h
    fig, axes = plt.subplots(1, 4, figsize=(4 * 3.6 * aspect / 1.2 + 2.4, 3.6 / 1.2 + 0.6), dpi=80,
                             gridspec_kw={"width_ratios": [1, 1, 1.12, 1.12]})
    err = np.sqrt(relmse_map(img, ref, mask))          # relative error per pixel, NaN off the mask
    bright = band_ratios(img, ref, mask)
    axes[0].imshow(tonemap(img, exposure, tone))
    axes[0].set_title(f"popvol (brightness x{brightness_ratio(img, ref, mask):.2f})")
    axes[1].imshow(tonemap(ref, exposure, tone))
    axes[1].set_title("reference")
    top = float(np.nanmax(err)) if np.isfinite(err).any() else 1.0
    im = axes[2].imshow(np.ma.masked_invalid(np.maximum(err, 1e-3)), cmap=plt.get_cmap("inferno").with_extremes(bad="0.85"),
                        norm=LogNorm(vmin=1e-3, vmax=max(1.0, top)))
    axes[2].set_title(f"relative error (relMSE {relmse(img, ref, mask):.3g})")
    fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.02, label="|popvol - ref| / sqrt(ref^2 + eps)")
    ratio = np.clip(ratio_map(img, ref, mask), 0.5, 2.0)
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.85")      # off the mask: grey
    im = axes[3].imshow(np.ma.masked_invalid(ratio), cmap=cmap, norm=LogNorm(vmin=0.5, vmax=2.0))
    axes[3].set_title("popvol / ref: dim x{dim:.2f}, mid x{mid:.2f}, bright x{bright:.2f}".format(**bright),
                      fontsize="small")
    cb = fig.colorbar(im, ax=axes[3], fraction=0.046, pad=0.02, label="luminance ratio")
    ticks = [0.5, 0.71, 1.0, 1.41, 2.0]
    cb.set_ticks(ticks)
    cb.set_ticklabels([f"{t:g}" for t in ticks])
    cb.minorticks_off()
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        write_atomically(path, fig.savefig)      # the temporary file keeps the suffix: the format
    finally:
        plt.close(fig)
