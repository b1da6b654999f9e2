"""The participating medium: a density grid in world space and its optical constants.

Conventions:
- ``density[i, j, k]`` is indexed x, y, z; the centre of voxel (i, j, k) is at
  ``origin + (i, j, k) * voxel_size`` (OpenVDB style). The medium occupies the union of the
  voxel *cells*, ``[origin - voxel/2, origin + (n - 1/2) * voxel]``; outside it is vacuum.
- Extinction sigma_t(x) = scale * density(x)  [1 / world unit];
  scattering sigma_s = albedo * sigma_t; absorption sigma_a = sigma_t - sigma_s.
- Phase function: Henyey-Greenstein with asymmetry g.

Optics may be chromatic and per voxel: ``scale`` and a constant ``albedo`` are RGB (one number
means grey); ``albedo`` and ``g`` may also be grids of the density's shape (grey albedo per
voxel, g per voxel). Kernels take optics as grids; constants are grids of shape (1, 1, 1).
A chromatic medium (RGB scale or albedo that differ between channels) is propagated once per
channel; a grey one once.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import check
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
        scale: sigma_t = scale * density, in 1 / world unit, >= 0: one number or RGB; stored
            as float64 (3,).
        albedo: single-scattering albedo in [0, 1]: one number or RGB (stored float64 (3,)),
            or a float32 grid of the density's shape (grey, per voxel).
        g: Henyey-Greenstein asymmetry in (-1, 1): a number, or a float32 grid of the
            density's shape.
        source: where the density came from (file path or generator), for messages.
    """

    density: np.ndarray
    voxel_size: np.ndarray
    origin: np.ndarray
    scale: float | np.ndarray = 1.0
    albedo: float | np.ndarray = 1.0
    g: float | np.ndarray = 0.0
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
        f, src = self._field, self.source
        if check._is_scalar(self.voxel_size):          # one number: cubic voxels
            vs = check.number(self.voxel_size, f"{f}.voxel_size", src, 0.0, np.inf, open_interval=True)
            self.voxel_size = np.full(3, vs)
        else:
            self.voxel_size = check.vector(self.voxel_size, f"{f}.voxel_size", src, positive=True)
        self.origin = check.vector(self.origin, f"{f}.origin", src)
        self.scale = check.rgb(self.scale, f"{f}.scale", src)
        if _is_grid(self.albedo):
            self.albedo = _grid(self.albedo, d.shape, f"{f}.albedo", src, 0.0, 1.0, False)
        else:
            self.albedo = check.rgb(self.albedo, f"{f}.albedo", src, 0.0, 1.0)
        if _is_grid(self.g):
            self.g = _grid(self.g, d.shape, f"{f}.g", src, -1.0, 1.0, True)
        else:
            self.g = check.number(self.g, f"{f}.g", src, -1.0, 1.0, open_interval=True)

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

    # -- optics (kernels take grids; constants are (1, 1, 1) grids) -------------------------
    @property
    def albedo_per_voxel(self) -> bool:
        return np.ndim(self.albedo) == 3

    @property
    def g_per_voxel(self) -> bool:
        return np.ndim(self.g) == 3

    @property
    def n_channels(self) -> int:
        """1 for a grey medium, 3 when scale or albedo differ between R, G and B."""
        grey = np.all(self.scale == self.scale[0])
        if not self.albedo_per_voxel:
            grey = grey and np.all(self.albedo == self.albedo[0])
        return 1 if grey else 3

    def albedo_grid(self, channel: int = 0) -> np.ndarray:
        """float32 grid: the per-voxel albedo, or channel ``channel`` of a constant as (1, 1, 1)."""
        if self.albedo_per_voxel:
            return self.albedo
        return np.full((1, 1, 1), self.albedo[channel], np.float32)

    def g_grid(self) -> np.ndarray:
        return self.g if self.g_per_voxel else np.full((1, 1, 1), self.g, np.float32)

    @property
    def g_min(self) -> float:
        return float(np.min(self.g))

    def max_optical_depth(self) -> float:
        """Largest sigma_t times the longest side: a rough scale of how dense the medium is."""
        lo, hi = self.bounds
        return float(self.scale.max() * self.density.max() * np.max(hi - lo))


def _is_grid(value) -> bool:
    """A per-voxel optics grid: a 3-D numeric array."""
    return isinstance(value, np.ndarray) and value.ndim == 3 and value.dtype.kind in "iuf"


def _grid(value, shape, name: str, source: str, lo: float, hi: float, open_interval: bool) -> np.ndarray:
    """A per-voxel optics grid: the density's shape, finite, every value in the range."""
    a = np.asarray(value)
    if a.shape != tuple(shape):
        raise PopvolError(f"{source}: {name} grid has shape {a.shape}; it must match the density's {tuple(shape)}")
    a = np.ascontiguousarray(a, np.float32)
    ok = np.isfinite(a) & ((a > lo) & (a < hi) if open_interval else (a >= lo) & (a <= hi))
    if not ok.all():
        at = tuple(int(v) for v in np.argwhere(~ok)[0])
        rng = f"({lo:g}, {hi:g})" if open_interval else f"[{lo:g}, {hi:g}]"
        raise PopvolError(f"{source}: {name} grid has {int((~ok).sum())} values outside {rng} "
                          f"(first at {at}: {a[at]!r})")
    return a
