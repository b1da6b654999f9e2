"""A deterministic procedural cumulus cloud: the built-in demo medium (no data files needed).

Two styles (``cloud_density(style=...)``, the scene key ``medium.style``):

- ``"cumulus"`` (the default): soft ellipsoidal puffs and a tower, with a flat base, eroded by fractal
  Perlin-Worley noise as in real-time cloud modelling (A. Schneider, "The real-time volumetric
  cloudscapes of Horizon: Zero Dawn", SIGGRAPH 2015, and the Nubis talks; S. Hillaire,
  "Physically based sky, atmosphere and cloud rendering in Frostbite", SIGGRAPH 2016). Two small
  tileable 32^3 textures, Perlin gradient noise and inverted Worley (cellular) noise, are made
  once from the seed; fractal noise is their sum over octaves, each octave a trilinear lookup
  with wrap-around at its own frequency and offset. The low-frequency Perlin-Worley noise
  (Perlin remapped by Worley fbm) carves the puffs into billows; the high-frequency Worley fbm
  then erodes the result, ``remap(base, k * noise, 1, 0, 1)``, more strongly towards the top
  and the thin edges, billowy above and wispy at the base. The lookups are separable (the grid
  is axis-aligned), so generation is fast: 96 x 72 x 96 voxels (resolution 96) in 0.13 s, or
  0.21 s with the machine's 2 cores shared by 4 busy processes (median of 5 by
  ``time.perf_counter``: ``python -m popvol.procedural [resolution]``; "smooth": 0.21 / 0.39 s).
  Peak memory ~40 bytes per voxel, as the smooth style's.
- ``"smooth"``: popvol 0.1's generator, kept bitwise: the same puffs without the tower, eroded
  only at large scale by value-noise fbm. Scenes whose references were made with it say so.
- ``"field"``: a field of small flat-based cumulus (a core and three turrets each, placed at
  random but apart) over a square, eroded by the same noise scaled to the small clouds, on
  voxels twice as tall as wide (:data:`VOXEL_ASPECT`), as the grids of atmospheric large-eddy
  simulations are: a test of non-cubic voxels and of many clouds in one domain.

``time`` (cumulus and field) animates the detail: at time t (seconds) the erosion noise is sampled at
positions moved by a constant wind of :data:`WIND` cloud widths (``extent``) per second, each
octave also drifting at its own small velocity, so the detail slides and evolves while the base
shape stays put. Density is a continuous function of t, and t = 0 is bitwise the default.

The same ``seed``, ``resolution``, ``style`` and ``time`` always give the same grid (NumPy's
PCG64; element-wise NumPy arithmetic only, no BLAS or threads, so the grid should not depend
on the machine either).
"""
from __future__ import annotations

import functools

import numpy as np

from .medium import Medium

#: Peak bytes per voxel while a cloud is generated (coordinates, puffs, noise: measured ~40).
BYTES_PER_VOXEL = 48


def cloud_shape(resolution: int, style: str = "cumulus") -> tuple[int, int, int]:
    """The grid shape of :func:`cloud_density` at ``resolution`` (the ``"field"`` style: an eighth
    as many voxels in y, each twice as tall: a quarter of the width)."""
    if style == "field":
        return resolution, max(4, resolution // 8), resolution
    return resolution, resolution // 2 + resolution // 4, resolution


def _value_noise(shape: tuple[int, int, int], cells: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth value noise in [0, 1], float32 ``shape``, with ``cells`` lattice cells per axis."""
    lattice = rng.random((cells + 2,) * 3).astype(np.float32)
    coords = [np.linspace(0, cells, n, endpoint=False, dtype=np.float32) for n in shape]
    idx = [np.floor(c).astype(np.int64) for c in coords]
    frac = [c - i for c, i in zip(coords, idx)]
    s = [f * f * (3 - 2 * f) for f in frac]  # smoothstep weights
    x0, y0, z0 = np.ix_(*idx)
    sx, sy, sz = np.ix_(*s)
    out = np.zeros(shape, np.float32)
    for dx in (0, 1):
        wx = sx if dx else 1 - sx
        for dy in (0, 1):
            wy = sy if dy else 1 - sy
            for dz in (0, 1):
                wz = sz if dz else 1 - sz
                out += wx * wy * wz * lattice[x0 + dx, y0 + dy, z0 + dz]
    return out


def _smooth_density(resolution: int = 96, seed: int = 7) -> np.ndarray:
    """The ``"smooth"`` style (popvol 0.1's cloud_density, unchanged): density in [0, 1]."""
    nx, ny, nz = cloud_shape(resolution)
    rng = np.random.default_rng(seed)
    x = (np.arange(nx, dtype=np.float32) + 0.5) / nx * 2 - 1          # [-1, 1]
    y = (np.arange(ny, dtype=np.float32) + 0.5) / nx * 2 - 0.25       # same units as x
    z = (np.arange(nz, dtype=np.float32) + 0.5) / nz * 2 - 1
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")

    # Puffs: centre (x, y, z) and radius, in the units above. A big core and smaller turrets.
    puffs = [(0.0, 0.15, 0.0, 0.55), (-0.38, 0.08, 0.12, 0.38), (0.4, 0.1, -0.1, 0.36),
             (0.1, 0.45, 0.05, 0.36), (-0.15, 0.55, -0.15, 0.25), (0.2, 0.05, 0.4, 0.3),
             (-0.1, 0.05, -0.42, 0.3), (0.45, 0.35, 0.2, 0.22)]
    shape = np.zeros((nx, ny, nz), np.float32)
    for cx, cy, cz, r in puffs:
        d2 = ((X - cx) ** 2 + ((Y - cy) * 1.15) ** 2 + (Z - cz) ** 2) / r**2
        shape = np.maximum(shape, 1 - d2)
    shape *= np.clip((Y + 0.12) / 0.12, 0, 1)  # flat base

    fbm = np.zeros_like(shape)
    amp, total = 1.0, 0.0
    for cells in (4, 8, 16, 32):
        fbm += amp * _value_noise(shape.shape, cells, rng)
        total += amp
        amp *= 0.5
    fbm /= total
    density = np.clip((shape - 0.55 * (1 - fbm)) * 2.5, 0, None)
    density = np.minimum(density, 1.0).astype(np.float32)
    return density



# ---------------------------------------------------------------------------------------------
# The "cumulus" style: puffs eroded by Perlin-Worley noise
# ---------------------------------------------------------------------------------------------

#: The styles of :func:`cloud_density` (the first is the default).
STYLES = ("cumulus", "smooth", "field")
#: The styles that ``time`` moves.
MOVING_STYLES = ("cumulus", "field")
#: The wind that carries the erosion noise as ``time`` goes on: cloud widths per second (x, y, z).
WIND = (0.02, 0.0, 0.01)
#: Each octave of the noise also drifts at up to this speed (cloud widths per second), so the
#: detail evolves ("boils") instead of only sliding with the wind.
BOIL = 0.01
#: The largest |time| accepted by the scene loader (seconds; 11.6 days).
TIME_LIMIT = 1e6
#: Voxels along each axis of the tileable noise textures.
TILE = 32

# Puffs: centre (x, y, z) and radius in units where the cloud spans x in [-1, 1]: the "smooth"
# style's big core and smaller turrets, and a tower above them.
_PUFFS = [(0.0, 0.15, 0.0, 0.55), (-0.38, 0.08, 0.12, 0.38), (0.4, 0.1, -0.1, 0.36),
          (0.1, 0.45, 0.05, 0.36), (-0.15, 0.55, -0.15, 0.25), (0.2, 0.05, 0.4, 0.3),
          (-0.1, 0.05, -0.42, 0.3), (0.45, 0.35, 0.2, 0.22),
          (0.02, 0.72, 0.0, 0.32), (-0.1, 0.88, 0.06, 0.2), (0.2, 0.8, -0.08, 0.2)]
_TOP = 1.05        # highest point of the puffs (y in the units above); the base is at y = -0.12
# Noise: (tiles per cloud width, octaves); erosion strengths (docs in _cumulus_density).
_SHAPE_NOISE = (2.0, 3)
_DETAIL_NOISE = (5.0, 2)
_SHAPE_EROSION = 0.6
_DETAIL_EROSION = (0.3, 0.3)      # at the base, added at the top
_GAIN = 3.0
# The fbm's central range, stretched to [0, 1] (a sum of octaves has less contrast than one).
_PW_RANGE = (0.6, 0.9)
_DETAIL_RANGE = (0.3, 0.72)


def _perlin_tile(rng: np.random.Generator, cells: int = 4, n: int = TILE) -> np.ndarray:
    """Tileable Perlin gradient noise in [0, 1], float32 (n, n, n), ``cells`` lattice cells per
    axis (random unit gradients, quintic fade)."""
    g = rng.standard_normal((cells, cells, cells, 3))
    g = (g / np.linalg.norm(g, axis=-1, keepdims=True)).astype(np.float32)
    p = (np.arange(n, dtype=np.float64) + 0.5) * cells / n
    i = np.floor(p).astype(np.int64)
    f = (p - i).astype(np.float32)
    s = f * f * f * (f * (f * 6 - 15) + 10)
    ax = lambda a, k: a.reshape([-1 if j == k else 1 for j in range(3)])
    out = np.zeros((n, n, n), np.float32)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                gr = g[ax((i + dx) % cells, 0), ax((i + dy) % cells, 1), ax((i + dz) % cells, 2)]
                dot = (gr[..., 0] * ax(f - dx, 0) + gr[..., 1] * ax(f - dy, 1) + gr[..., 2] * ax(f - dz, 2))
                w = ax(s if dx else 1 - s, 0) * ax(s if dy else 1 - s, 1) * ax(s if dz else 1 - s, 2)
                out += w * dot
    return ((out - out.min()) / (out.max() - out.min())).astype(np.float32)


def _worley_tile(rng: np.random.Generator, cells: int = 4, n: int = TILE) -> np.ndarray:
    """Tileable inverted Worley (cellular) noise in [0, 1], float32 (n, n, n): one random
    feature point per cell of a ``cells``^3 lattice; 1 - the distance to the nearest one,
    normalised (1 at the feature points: round billows)."""
    pts = rng.random((cells, cells, cells, 3)).astype(np.float32)
    p = ((np.arange(n, dtype=np.float64) + 0.5) * cells / n).astype(np.float32)
    c = np.floor(p).astype(np.int64)
    ax = lambda a, k: a.reshape([-1 if j == k else 1 for j in range(3)])
    best = np.full((n, n, n), np.inf, np.float32)
    for ox in (-1, 0, 1):
        for oy in (-1, 0, 1):
            for oz in (-1, 0, 1):
                cx, cy, cz = c + ox, c + oy, c + oz
                q = pts[ax(cx % cells, 0), ax(cy % cells, 1), ax(cz % cells, 2)]
                d2 = ((ax(p - cx, 0) - q[..., 0]) ** 2 + (ax(p - cy, 1) - q[..., 1]) ** 2
                      + (ax(p - cz, 2) - q[..., 2]) ** 2)
                np.minimum(best, d2, out=best)
    d = np.sqrt(best)
    return (1 - d / d.max()).astype(np.float32)


@functools.lru_cache(maxsize=4)
def _tiles(seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """The Perlin and Worley tiles of ``seed`` and the random generator's state after them,
    made once per seed (the frames of a sequence share them; 0.05 s of each frame at
    resolution 96). The arrays are read only."""
    rng = np.random.default_rng(seed)
    perlin, worley = _perlin_tile(rng), _worley_tile(rng)
    perlin.flags.writeable = worley.flags.writeable = False
    return perlin, worley, rng.bit_generator.state


def _lerp_axis(t: np.ndarray, u: np.ndarray, axis: int) -> np.ndarray:
    """Linear interpolation of ``t`` along ``axis`` at voxel coordinates ``u`` (1-D, voxel
    centres at i + 0.5), wrapping around."""
    n = t.shape[axis]
    u = u - 0.5
    i = np.floor(u)
    f = (u - i).astype(np.float32).reshape([-1 if j == axis else 1 for j in range(t.ndim)])
    i = i.astype(np.int64) % n
    a = np.take(t, i, axis=axis)
    return a + (np.take(t, (i + 1) % n, axis=axis) - a) * f


def _lookup(tex: np.ndarray, u, v, w) -> np.ndarray:
    """Trilinear lookup with wrap-around of a tileable texture at the grid of coordinates
    u x v x w (1-D each, in tiles: 1 = one texture width). Separable: three 1-D passes."""
    n = tex.shape[0]
    return _lerp_axis(_lerp_axis(_lerp_axis(tex, u * n, 0), v * n, 1), w * n, 2)


def _fbm(tex: np.ndarray, axes, freq: float, octaves: int, rng: np.random.Generator, time: float):
    """Fractal sum of ``octaves`` lookups of ``tex`` at frequencies freq * 2^k tiles per cloud
    width (amplitudes 1/2^k, normalised to [0, 1]). ``axes``: the grid's coordinates in cloud
    widths. Each octave has a random offset and drifts with WIND plus its own velocity (up to
    BOIL) over ``time``."""
    offsets = rng.random((octaves, 3))
    boil = rng.standard_normal((octaves, 3))
    boil *= BOIL * np.arange(1, octaves + 1)[:, None] / octaves / np.linalg.norm(boil, axis=1, keepdims=True)
    out, total, amp = 0.0, 0.0, 1.0
    for k in range(octaves):
        f = freq * 2.0**k
        moved = [(a - (WIND[j] + boil[k, j]) * time) * f + offsets[k, j] for j, a in enumerate(axes)]
        out = out + np.float32(amp) * _lookup(tex, *moved)
        total += amp
        amp *= 0.5
    return out * np.float32(1 / total)


def _remap(x, lo, hi, new_lo, new_hi):
    """Schneider's remap: x's range [lo, hi] mapped linearly to [new_lo, new_hi]."""
    return new_lo + (x - lo) / (hi - lo) * (new_hi - new_lo)


def _puff_union(puffs, X, Y, Z) -> np.ndarray:
    """float32 grid: the union of the ellipsoidal puffs (cx, cy, cz, r), 1 - the squared distance
    over r^2 of the nearest (1 at a centre, 0 on its surface, negative outside; squashed 1.15 in
    y), at the coordinates X, Y, Z (float32, broadcasting to the grid)."""
    shape = np.zeros(np.broadcast_shapes(X.shape, Y.shape, Z.shape), np.float32)
    for cx, cy, cz, r in puffs:
        d2 = ((X - cx) ** 2 + ((Y - cy) * 1.15) ** 2 + (Z - cz) ** 2) / np.float32(r * r)
        np.maximum(shape, 1 - d2, out=shape)
    return shape


def _erode(shape, height, axes, seed: int, time: float) -> np.ndarray:
    """Schneider's two erosions of a base ``shape`` (float32 grid, 1 at a puff's centre, 0 on its
    surface) by Perlin-Worley and Worley noise (the tiles of ``seed``; see
    :func:`_cumulus_density`); ``height`` (0 at the base, 1 at the top) makes the detail billowy
    above and wispy below; ``axes``: the grid's coordinates in cloud widths (1-D each). Density
    in [0, 1], float32."""
    perlin, worley, state = _tiles(seed)
    rng = np.random.default_rng(seed)
    rng.bit_generator.state = state                  # as if the tiles had just been drawn
    # Low frequencies: Perlin-Worley noise (Perlin fbm dilated by Worley fbm: Hillaire's
    # remap(perlin, 0, 1, worley, 1)) carves the puffs into billows.
    freq, octaves = _SHAPE_NOISE
    w = _fbm(worley, axes, freq, octaves, rng, time)
    pw = _remap(_fbm(perlin, axes, freq, octaves, rng, time), 0, 1, w, 1)
    pw = np.clip(_remap(pw, *_PW_RANGE, 0, 1), 0, 1)
    base = np.clip(_remap(shape, _SHAPE_EROSION * (1 - pw), 1, 0, 1), 0, 1)

    # High frequencies: Worley fbm erodes the edges, billowy (inverted) above, wispy at the
    # base (Schneider), more strongly towards the top.
    freq, octaves = _DETAIL_NOISE
    detail = np.clip(_remap(_fbm(worley, axes, freq, octaves, rng, time), *_DETAIL_RANGE, 0, 1), 0, 1)
    billowy = np.clip(height * 4, 0, 1)
    modifier = detail + (1 - 2 * detail) * billowy
    k = _DETAIL_EROSION[0] + _DETAIL_EROSION[1] * height
    density = _remap(base, modifier * k, 1, 0, 1) * np.float32(_GAIN)
    return np.clip(density, 0, 1).astype(np.float32)


def _cumulus_density(resolution: int, seed: int, time: float) -> np.ndarray:
    """The ``"cumulus"`` style. ``shape`` (1 - the squared distance over radius^2 of the nearest
    puff) is eroded twice by Schneider's remap(shape, lo, 1, 0, 1), which empties shape < lo:
    lo = _SHAPE_EROSION x (1 - Perlin-Worley) carves billows of ~1/8 cloud width; then
    lo = k x Worley detail (k from _DETAIL_EROSION: stronger with height), inverted above the
    lowest quarter (billowy) and not below it (wispy), at 1/20 and 1/40 cloud width. _GAIN
    steepens the edges; the result is clipped to [0, 1]."""
    nx, ny, nz = cloud_shape(resolution)
    x = (np.arange(nx, dtype=np.float64) + 0.5) / nx * 2 - 1      # [-1, 1]
    y = (np.arange(ny, dtype=np.float64) + 0.5) / nx * 2 - 0.25   # same units as x
    z = (np.arange(nz, dtype=np.float64) + 0.5) / nz * 2 - 1
    X = x.astype(np.float32)[:, None, None]
    Y = y.astype(np.float32)[None, :, None]
    Z = z.astype(np.float32)[None, None, :]

    # Base shape: the union of the puffs, cut flat at the base.
    shape = _puff_union(_PUFFS, X, Y, Z)
    shape *= np.clip((Y + 0.12) / 0.12, 0, 1)
    height = np.clip((Y + 0.12) / (_TOP + 0.12), 0, 1)              # 0 at the base, 1 at the top

    return _erode(shape, height, (x / 2, y / 2, z / 2), seed, time)


# ---------------------------------------------------------------------------------------------
# The "field" style: many small cumulus on voxels twice as tall as wide
# ---------------------------------------------------------------------------------------------

#: Voxel height over width of each style's grid (the field's voxels are twice as tall, as in
#: atmospheric models' grids).
VOXEL_ASPECT = {"cumulus": 1, "smooth": 1, "field": 2}
#: The field: how many clouds, their radius range (in units where the field spans x and z in
#: [-1, 1]) and the height of their flat base (at least one voxel up).
_FIELD_CLOUDS = 14
_FIELD_RADIUS = (0.1, 0.22)
_FIELD_BASE = 0.06


def _field_clouds(seed: int, base: float) -> list[tuple[float, float, float, float]]:
    """The field's puffs (cx, cy, cz, r): per cloud a core on the base and three turrets above
    it, placed at least 1.6 radii apart (rejection sampling, a generator of its own so the noise
    stays that of the tiles)."""
    rng = np.random.default_rng([seed, 2])
    puffs, centres = [], []
    for _ in range(1000):
        if len(centres) == _FIELD_CLOUDS:
            break
        r = rng.uniform(*_FIELD_RADIUS)
        c = rng.uniform(-0.9 + r, 0.9 - r, 2)
        if any(np.hypot(*(c - q)) < 1.6 * max(r, rq) for q, rq in centres):
            continue
        centres.append((c, r))
        puffs.append((c[0], base + 0.55 * r, c[1], r))
        for _ in range(3):
            a = rng.uniform(0, 2 * np.pi)
            d = rng.uniform(0.2, 0.5) * r
            puffs.append((c[0] + d * np.cos(a), base + rng.uniform(0.8, 1.4) * r, c[1] + d * np.sin(a),
                          rng.uniform(0.5, 0.7) * r))
    return puffs


def _field_density(resolution: int, seed: int, time: float) -> np.ndarray:
    """The ``"field"`` style: :data:`_FIELD_CLOUDS` small cumulus (puffs cut flat at a common
    base) over a square, each eroded as the ``"cumulus"`` style is, on voxels twice as tall as
    wide; the noise is scaled to the small clouds (about 4 noise cloud widths per unit)."""
    nx, ny, nz = cloud_shape(resolution, "field")
    x = (np.arange(nx, dtype=np.float64) + 0.5) / nx * 2 - 1
    y = (np.arange(ny, dtype=np.float64) + 0.5) / nx * 2 * VOXEL_ASPECT["field"]
    z = (np.arange(nz, dtype=np.float64) + 0.5) / nz * 2 - 1
    X = x.astype(np.float32)[:, None, None]
    Y = y.astype(np.float32)[None, :, None]
    Z = z.astype(np.float32)[None, None, :]
    base = max(_FIELD_BASE, 2.0 * VOXEL_ASPECT["field"] / nx)       # the lowest row stays empty
    puffs = _field_clouds(seed, base)
    shape = _puff_union(puffs, X, Y, Z)
    top = max(cy + r / 1.15 for _, cy, _, r in puffs)
    shape *= np.clip((Y - base) / 0.02, 0, 1)
    height = np.clip((Y - base) / (top - base), 0, 1)
    return _erode(shape, height, (x * 4, y * 4, z * 4), seed, time)


def cloud_density(resolution: int = 96, seed: int = 7, style: str = "cumulus", time: float = 0.0) -> np.ndarray:
    """Density in [0, 1] of a cumulus cloud, float32 :func:`cloud_shape` (n, n//2 + n//4, n;
    the field: n, n//8, n) indexed x, y, z.

    ``style``: one of :data:`STYLES` (module docstring). ``time`` (seconds, finite; cumulus and
    field) moves and evolves the erosion noise; 0 is bitwise the call without it.
    """
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    if not np.isfinite(time):
        raise ValueError(f"time must be finite, got {time!r}")
    if style == "smooth":
        if time != 0:
            raise ValueError("time applies to styles 'cumulus' and 'field' only")
        return _smooth_density(resolution, seed)
    if style == "field":
        return _field_density(resolution, seed, float(time))
    return _cumulus_density(resolution, seed, float(time))

#: The demo cloud's optics (docs/SCENE.md: the procedural medium's defaults).
DEMO_OPTICS = {"scale": 12.0, "albedo": 0.99, "g": 0.85}


def demo_medium(resolution: int = 96, seed: int = 7, extent: float = 2.0,
                scale: float = 12.0, albedo: float = 0.99, g: float = 0.85, field: str | None = None,
                style: str = "cumulus", time: float = 0.0) -> Medium:
    """The demo cloud as a :class:`Medium` of width ``extent`` world units centred at x = z = 0.

    With the defaults the cloud's core has sigma_t = 12 per unit, an optical depth of ~10 across.
    ``style`` and ``time``: as in :func:`cloud_density`.
    Refused with a PopvolError naming ``field`` (default: "resolution = N") if generating it
    would not fit in the memory available.
    """
    from .domains import check_memory
    shape = cloud_shape(resolution, style)
    check_memory(int(np.prod(shape, dtype=np.int64)) * BYTES_PER_VOXEL, field or f"resolution = {resolution}",
                 f"a procedural cloud of {shape[0]}x{shape[1]}x{shape[2]} voxels")
    density = cloud_density(resolution, seed, style, time)
    voxel = extent / resolution
    voxel_size = np.array([voxel, voxel * VOXEL_ASPECT[style], voxel])
    origin = np.array([-extent / 2, 0.0, -extent / 2]) + 0.5 * voxel_size
    assert density.shape[0] == resolution
    return Medium(density, voxel_size, origin, scale=scale, albedo=albedo, g=g,
                  source=f"procedural {style} cloud (resolution {resolution}, seed {seed}"
                         + (f", time {time:g})" if time else ")"))


def _timing(resolution: int = 96, repeat: int = 5) -> dict:
    """Median seconds (``time.perf_counter``) of ``repeat`` generations per style."""
    import statistics
    import time as clock
    out = {}
    for style in STYLES:
        times = []
        for _ in range(repeat):
            t0 = clock.perf_counter()
            cloud_density(resolution, 7, style)
            times.append(clock.perf_counter() - t0)
        out[style] = statistics.median(times)
    return out


if __name__ == "__main__":   # python -m popvol.procedural [resolution]: the time quoted above
    import sys
    res = int(sys.argv[1]) if len(sys.argv) > 1 else 96
    for style, seconds in _timing(res).items():
        print(f"{style}: {cloud_shape(res)} voxels in {seconds:.3f} s (median of 5)")
