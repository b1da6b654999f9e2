"""Environment light: a lat-long radiance map (or an analytic sky) seen as the background and
decomposed into K directional lights, each propagated like a sun (docs/METHOD.md, "Environment
lights").

Convention (Mitsuba 3's ``envmap``, so that the reference export is the map itself): the texel
at row i, column j of an (H, W) map holds the radiance arriving FROM the direction
    theta = (i + 1/2) pi / H,  phi = (j + 1/2) 2 pi / W,
    d = (sin theta sin phi, cos theta, -sin theta cos phi)        (y up; theta from +y),
so u = atan2(d.x, -d.z) / 2 pi, v = acos(d.y) / pi. Maps must be 2:1 (W = 2 H).

Decomposition (median cut): starting from the whole sphere, the region with the most energy is
cut in two along its longer angular extent at its energy median, until there are K regions.
Region r becomes a directional light travelling along -m_r / |m_r|, with
    E_r = sum_r L dOmega          (RGB; the light's irradiance parameter),
    m_r = sum_r lum(L) omega dOmega,   a0_r = |m_r| / sum_r lum(L) dOmega,
so the lights' E sum to the map's integral of L over the sphere (the fluence it creates in
empty space). A sun (texels brighter than half the brightest, when that is 50x the map's mean)
is taken out first as a light of its own; median cut alone would split it among regions.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .check import MAX_POWER
from .errors import PopvolError
from .io.images import luminance
from .lights import DirectionalLight

#: Largest radiance (texel times scale, or a sky's colour) accepted: the lights a map becomes
#: carry up to 4 pi times it as irradiance, which must stay within check.MAX_POWER.
MAX_RADIANCE = MAX_POWER / 16


@dataclass
class EnvMap:
    radiance: np.ndarray       # float32 (H, W, 3), W = 2 H, linear RGB radiance
    source: str = "<envmap>"

    def __post_init__(self):
        r = np.asarray(self.radiance, np.float32)
        if r.ndim != 3 or r.shape[2] != 3 or r.shape[0] < 1:
            raise PopvolError(f"{self.source}: environment map must be an RGB image, got shape {r.shape}")
        if r.shape[1] != 2 * r.shape[0]:
            raise PopvolError(f"{self.source}: environment map is {r.shape[1]}x{r.shape[0]}; a lat-long map "
                              "is twice as wide as it is high")
        if not np.all(np.isfinite(r)) or r.min() < 0:
            raise PopvolError(f"{self.source}: environment map has NaN, infinite or negative texels")
        if r.max() > MAX_RADIANCE:
            raise PopvolError(f"{self.source}: environment map has radiance up to {float(r.max()):.3g}, more "
                              f"than {MAX_RADIANCE:g}")
        self.radiance = np.ascontiguousarray(r)


def texel_geometry(H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (H, W, 3) of texel centres (toward the environment) and solid angles (H, W)."""
    theta = (np.arange(H) + 0.5) * np.pi / H
    phi = (np.arange(W) + 0.5) * 2 * np.pi / W
    T, P = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], axis=-1)
    edges = np.cos(np.arange(H + 1) * np.pi / H)
    omega = (edges[:-1] - edges[1:])[:, None] * (2 * np.pi / W) * np.ones((1, W))
    return d, omega


def integral(env: EnvMap) -> np.ndarray:
    """int L dOmega over the sphere, RGB (the fluence the map creates in empty space)."""
    _, omega = texel_geometry(*env.radiance.shape[:2])
    return (env.radiance * omega[..., None]).sum(axis=(0, 1), dtype=np.float64)


def sky(zenith, horizon, ground=(0.0, 0.0, 0.0), height: int = 64, source: str = "<sky>") -> EnvMap:
    """An analytic sky: radiance blends from ``horizon`` (elevation 0) to ``zenith`` (straight
    up) as sqrt(sin(elevation)); ``ground`` below the horizon."""
    d, _ = texel_geometry(height, 2 * height)
    el = np.clip(d[..., 1], 0.0, 1.0)[..., None]
    t = np.sqrt(el)
    up = (1 - t) * np.asarray(horizon, float) + t * np.asarray(zenith, float)
    rad = np.where(d[..., 1:2] >= 0, up, np.asarray(ground, float))
    return EnvMap(rad.astype(np.float32), source)


def load(path, scale=1.0, field: str = "scale", where: str = "") -> EnvMap:
    """A lat-long map from OpenEXR (.exr) or Radiance RGBE (.hdr, through OpenCV, the
    ``hdr`` extra), times ``scale`` (1 or 3 numbers; ``field`` names it in messages). A file
    that is missing or unreadable is a one-line PopvolError that begins with ``where`` (e.g.
    "scene.toml: lights[0].file: ")."""
    from pathlib import Path
    from .io.files import why_not_file
    from .io.images import read_exr
    path = Path(path)
    if not path.is_file():
        raise PopvolError(f"{where}environment map {path} "
                          + ("is a folder" if path.is_dir() else why_not_file(path)))
    suffix = path.suffix.lower()
    try:
        if suffix == ".exr":
            rad = read_exr(path)
        elif suffix == ".hdr":
            rad = _read_hdr(path)
        else:
            raise PopvolError(f"{path}: popvol reads environment maps as OpenEXR (.exr) or Radiance "
                              f"(.hdr); convert {path.suffix or 'it'} to one of them")
    except PopvolError as e:
        raise PopvolError(f"{where}{e}") from None
    rad = np.asarray(rad, np.float32)
    if rad.ndim == 3 and rad.shape[-1] == 3 and rad.size and np.all(np.isfinite(rad)) and rad.min() >= 0:
        scale = np.broadcast_to(np.asarray(scale, np.float64), (3,))
        peak = (rad.reshape(-1, 3).max(axis=0).astype(np.float64) * scale).max()
        if not peak <= MAX_RADIANCE:               # the product would overflow or be refused
            raise PopvolError(f"{field} = {scale.tolist()} makes the radiance of {path} reach {peak:.3g}, more "
                              f"than {MAX_RADIANCE:g}; lower it")
    return EnvMap(rad * np.asarray(scale, np.float32), str(path))


def _read_hdr(path) -> np.ndarray:
    try:
        import cv2
    except ImportError:
        raise PopvolError(f"{path}: reading Radiance .hdr needs OpenCV: pip install 'popvol[hdr]' "
                          "(or convert the map to OpenEXR)") from None
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)    # popvol says what failed, in one line
    try:
        img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if img is None or img.ndim != 3 or img.shape[2] != 3:
        raise PopvolError(f"{path}: not a readable Radiance .hdr image")
    return np.ascontiguousarray(img[..., ::-1], np.float32)      # OpenCV gives BGR


SUN_CONTRAST = 50.0     # a map has a sun if its brightest texel is this many times the mean


def decompose(env: EnvMap, k: int) -> list[DirectionalLight]:
    """K directional lights: the sun (texels brighter than half the brightest, if that is
    SUN_CONTRAST times the map's mean luminance) as one light, the rest by median cut."""
    rad = env.radiance.astype(np.float64)
    H, W = rad.shape[:2]
    d, omega = texel_geometry(H, W)
    lights = []
    sun = sun_texels(env)
    if k > 1 and sun.any():
        lights.append(dataclasses.replace(_region_light(rad, d, omega, sun, f"{env.source}: sun"), a0=1.0))
        rad = np.where(sun[..., None], 0.0, rad)
        k -= 1
    regions = _median_cut_lights(rad, d, omega, k, env.source)
    for light in regions:       # regions of the map without its sun (not: one light holding it)
        light.map_region = bool(lights) or not sun.any()
        if lights:
            light.texels = light.texels & ~sun
    return lights + regions


def sun_texels(env: EnvMap) -> np.ndarray:
    """bool (H, W): the map's sun, the texels brighter than half the brightest if that is
    SUN_CONTRAST times the map's mean luminance (none otherwise)."""
    rad = env.radiance.astype(np.float64)
    _, omega = texel_geometry(*rad.shape[:2])
    lum = luminance(rad)
    mean = (lum * omega).sum() / (4 * np.pi)
    if mean > 0 and lum.max() > SUN_CONTRAST * mean:
        return lum > 0.5 * lum.max()
    return np.zeros(lum.shape, bool)


def _region_light(rad, d, omega, mask, source) -> DirectionalLight:
    """The directional light of the texels in ``mask`` (module docstring)."""
    w = omega * mask
    E = (rad * w[..., None]).sum(axis=(0, 1))
    lum = luminance(rad) * w
    m = (lum[..., None] * d).sum(axis=(0, 1))
    if lum.sum() <= 0 or np.linalg.norm(m) == 0:    # no luminance (pure blue) or symmetric
        m = (w[..., None] * d).sum(axis=(0, 1))
        a0 = float(np.linalg.norm(m) / w.sum())
    else:
        a0 = float(np.linalg.norm(m) / lum.sum())
    direction = -m / np.linalg.norm(m) if np.linalg.norm(m) > 0 else np.array([0.0, -1.0, 0.0])
    return DirectionalLight(direction, E, a0=min(a0, 1.0), source=source, from_environment=True, texels=mask)


def _median_cut_lights(rad, d, omega, k, source) -> list[DirectionalLight]:
    H, W = rad.shape[:2]
    energy = luminance(rad) * omega                     # (H, W) luminous "power"
    regions = [(0, H, 0, W)]
    while len(regions) < k:
        splittable = [r for r in regions if (r[1] - r[0]) * (r[3] - r[2]) > 1]
        if not splittable:
            break
        r = max(splittable, key=lambda r: energy[r[0]:r[1], r[2]:r[3]].sum())
        i0, i1, j0, j1 = r
        if energy[i0:i1, j0:j1].sum() <= 0:
            break
        theta_mid = (0.5 * (i0 + i1)) * np.pi / H
        tall = (i1 - i0) * np.pi / H >= (j1 - j0) * 2 * np.pi / W * np.sin(theta_mid)
        if (tall and i1 - i0 > 1) or j1 - j0 == 1:
            profile = energy[i0:i1, j0:j1].sum(axis=1)
            cut = i0 + _median_cut(profile)
            new = [(i0, cut, j0, j1), (cut, i1, j0, j1)]
        else:
            profile = energy[i0:i1, j0:j1].sum(axis=0)
            cut = j0 + _median_cut(profile)
            new = [(i0, i1, j0, cut), (i0, i1, cut, j1)]
        regions.remove(r)
        regions += new
    lights = []
    for i0, i1, j0, j1 in regions:
        mask = np.zeros((H, W), bool)
        mask[i0:i1, j0:j1] = True
        if (rad[mask] > 0).any():
            lights.append(_region_light(rad, d, omega, mask, f"{source}: region {len(lights)}"))
    return lights


def _median_cut(profile: np.ndarray) -> int:
    """Index (1 .. n-1) splitting ``profile`` into two parts of about equal sum."""
    c = np.cumsum(profile)
    cut = int(np.searchsorted(c, 0.5 * c[-1])) + 1
    return min(max(cut, 1), len(profile) - 1)
