"""The participating medium: a density grid in world space and its optical constants.

Conventions (METHOD.md, "Conventions"):
- ``density[i, j, k]`` is indexed x, y, z; the centre of voxel (i, j, k) is at
  ``origin + (i, j, k) * voxel_size`` (OpenVDB style). The medium occupies the union of the
  voxel *cells*, ``[origin - voxel/2, origin + (n - 1/2) * voxel]``; outside it is vacuum.
- Extinction sigma_t(x) = scale * density(x)  [1 / world unit];
  scattering sigma_s = albedo * sigma_t; absorption sigma_a = sigma_t - sigma_s.
- Phase function: Henyey-Greenstein with asymmetry g.

``albedo`` and ``g`` are constants for now. They are stored as grids of shape (1, 1, 1)
(broadcast everywhere) so that kernels already take per-voxel grids: a later per-voxel albedo
or g is a grid of the density's shape, with no kernel change.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import PopvolError

#: Bytes that one medium voxel costs in solver and renderer working sets (density, 2 fields
#: per light). Used for memory estimates before allocating.
BYTES_PER_WORLD_VOXEL = 4 * 3


@dataclass
class Medium:
    """A heterogeneous medium.

    Attributes:
        density: float32 (nx, ny, nz), non-negative, finite.
        voxel_size: float64 (3,), world units, > 0.
        origin: float64 (3,), world position of the centre of voxel (0, 0, 0).
        scale: sigma_t = scale * density, in 1 / world unit, >= 0.
        albedo: single-scattering albedo in [0, 1].
        g: Henyey-Greenstein asymmetry in (-1, 1).
        source: where the density came from (file path or generator), for messages.
    """

    density: np.ndarray
    voxel_size: np.ndarray
    origin: np.ndarray
    scale: float = 1.0
    albedo: float = 1.0
    g: float = 0.0
    source: str = "<array>"
    _field: str = field(default="medium", repr=False)

    def __post_init__(self):
        d = np.asarray(self.density)
        if d.ndim != 3 or min(d.shape) < 1:
            raise PopvolError(f"{self.source}: density must be a 3-D array with every size >= 1, got shape {d.shape}")
        d = np.ascontiguousarray(d, dtype=np.float32)
        bad = ~np.isfinite(d)
        if bad.any():
            idx = tuple(int(v) for v in np.argwhere(bad)[0])
            raise PopvolError(f"{self.source}: density has {int(bad.sum())} NaN/inf voxels (first at {idx}); it must be finite")
        if d.size and d.min() < 0:
            idx = tuple(int(v) for v in np.unravel_index(int(np.argmin(d)), d.shape))
            raise PopvolError(f"{self.source}: density has negative values (min {float(d.min()):g} at {idx}); it must be >= 0")
        self.density = d
        self.voxel_size = _vec3(self.voxel_size, f"{self._field}.voxel_size", self.source, positive=True)
        self.origin = _vec3(self.origin, f"{self._field}.origin", self.source)
        self.scale = _number(self.scale, f"{self._field}.scale", self.source, lo=0.0)
        self.albedo = _number(self.albedo, f"{self._field}.albedo", self.source, lo=0.0, hi=1.0)
        self.g = _number(self.g, f"{self._field}.g", self.source, lo=-1.0, hi=1.0, open_interval=True)

    # -- geometry -------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.density.shape)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World AABB (lo, hi) of the voxel cells, each float64 (3,)."""
        lo = self.origin - 0.5 * self.voxel_size
        hi = self.origin + (np.asarray(self.shape) - 0.5) * self.voxel_size
        return lo, hi

    # -- optics as grids (kernels take grids; constants are (1, 1, 1) grids) ---------------
    def albedo_grid(self) -> np.ndarray:
        return np.full((1, 1, 1), self.albedo, np.float32)

    def g_grid(self) -> np.ndarray:
        return np.full((1, 1, 1), self.g, np.float32)

    def max_optical_depth(self) -> float:
        """Largest sigma_t times the longest side: a rough scale of how dense the medium is."""
        lo, hi = self.bounds
        return float(self.scale * self.density.max() * np.max(hi - lo))


def _vec3(value, name: str, source: str, positive: bool = False) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.ndim == 0:
        v = np.full(3, float(v))
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise PopvolError(f"{source}: {name} must be 3 finite numbers (or one), got {value!r}")
    if positive and np.any(v <= 0):
        raise PopvolError(f"{source}: {name} = {v.tolist()} must be > 0")
    return v


def _number(value, name: str, source: str, lo=None, hi=None, open_interval=False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PopvolError(f"{source}: {name} must be a number, got {value!r}") from None
    rng = f"{'(' if open_interval else '['}{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}{')' if open_interval else ']'}"
    ok = np.isfinite(x)
    if ok and lo is not None:
        ok = x > lo if open_interval else x >= lo
    if ok and hi is not None:
        ok = x < hi if open_interval else x <= hi
    if not ok:
        raise PopvolError(f"{source}: {name} = {value!r} is outside {rng}")
    return x
