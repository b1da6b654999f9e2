"""A deterministic procedural cumulus cloud: the built-in demo medium (no data files needed).

The shape is a union of soft ellipsoidal puffs with a flattened base, eroded by fractal value
noise. The same ``seed`` and ``resolution`` always give the same grid (NumPy's PCG64).
"""
from __future__ import annotations

import numpy as np

from .medium import Medium

#: Peak bytes per voxel while a cloud is generated (coordinates, puffs, noise: measured ~40).
BYTES_PER_VOXEL = 48


def cloud_shape(resolution: int) -> tuple[int, int, int]:
    """The grid shape of :func:`cloud_density` at ``resolution``."""
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


def cloud_density(resolution: int = 96, seed: int = 7) -> np.ndarray:
    """Density in [0, 1] of a cumulus cloud, float32 (n, n//2 + n//4, n) indexed x, y, z."""
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


#: The demo cloud's optics (docs/SCENE.md: the procedural medium's defaults).
DEMO_OPTICS = {"scale": 12.0, "albedo": 0.99, "g": 0.85}


def demo_medium(resolution: int = 96, seed: int = 7, extent: float = 2.0,
                scale: float = 12.0, albedo: float = 0.99, g: float = 0.85, field: str | None = None) -> Medium:
    """The demo cloud as a :class:`Medium` of width ``extent`` world units centred at x = z = 0.

    With the defaults the cloud's core has sigma_t = 12 per unit, an optical depth of ~10 across.
    Refused with a PopvolError naming ``field`` (default: "resolution = N") if generating it
    would not fit in the memory available.
    """
    from .domains import check_memory
    shape = cloud_shape(resolution)
    check_memory(int(np.prod(shape, dtype=np.int64)) * BYTES_PER_VOXEL, field or f"resolution = {resolution}",
                 f"a procedural cloud of {shape[0]}x{shape[1]}x{shape[2]} voxels")
    density = cloud_density(resolution, seed)
    voxel = extent / resolution
    n = np.asarray(density.shape)
    origin = np.array([-extent / 2, 0.0, -extent / 2]) + 0.5 * voxel
    origin[1] = 0.5 * voxel
    assert n[0] == resolution
    return Medium(density, np.full(3, voxel), origin, scale=scale, albedo=albedo, g=g,
                  source=f"procedural cloud (resolution {resolution}, seed {seed})")
