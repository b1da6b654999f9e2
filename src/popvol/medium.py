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

from dataclasses import dataclass, field, replace

import numpy as np

from . import check
from .errors import PopvolError

#: Bytes that one medium voxel costs in solver and renderer working sets (density, 2 fields
#: per light). Used for memory estimates before allocating.
BYTES_PER_WORLD_VOXEL = 4 * 3

# Limits that keep every product downstream finite and meaningful in float64 geometry and
# float32 fields (docs/SCENE.md, "Limits"):
#: |coordinate| of every point of the medium's box, in world units.
MAX_COORDINATE = 1e12
#: Smallest voxel, relative to max(1, the largest |coordinate| of the box): finer voxels are
#: lost in the rounding of float64 world positions.
MIN_RELATIVE_VOXEL = 1e-9
#: Largest medium.scale (it is stored in float32 beside the density).
MAX_SCALE = 1e30
#: Largest optical depth scale * max density * diagonal of the box: far beyond any cloud (a
#: thunderhead is ~1e4); denser media are opaque and their products overflow.
MAX_OPTICAL_DEPTH = 1e7
#: Optical depth of one voxel (sigma_t x the voxel's shortest side) that light transport sees at
#: most in a medium that absorbs, and the least cap in any (docs/METHOD.md, "Optically thick
#: voxels", Eq. 27): the walk, the diffusion stage and the gathered last bounce solve a medium
#: whose densest voxels are capped at Medium.transport_depth_cap() mean free paths, while the
#: unscattered light and the camera's march see the true density. An optically thick region's
#: reflection depends on its albedo and g, not on its density, and a cell's fields are its mean,
#: which over a voxel many mean free paths deep is far below the light at its lit face.
MAX_TRANSPORT_DEPTH = 2.0
#: A medium that hardly absorbs reflects light from deeper, its diffusion length L_d = 1 /
#: sqrt(3 sigma_a sigma_tr) (sigma_tr = sigma_t (1 - albedo g)): its voxels are capped at this
#: share of it where that is more than MAX_TRANSPORT_DEPTH, so that two capped voxels span it...
DIFFUSION_LENGTH_SHARE = 0.5
#: ... and at most at this many transport mean free paths, 1 / (1 - g) mean free paths: deeper
#: cells darken the walk's fields (a white medium under a uniform sky; docs/METHOD.md).
MAX_REDUCED_DEPTH = 1.0
#: Most parts one voxel side is cut into at method.voxel_depth (Medium.refinement): 27 times the
#: voxels at most. Odd, as every number of parts is (Medium.refinement).
MAX_REFINEMENT = 3
#: Most voxels the finer grid of method.voxel_depth has (Medium.refinement): beyond it the axes
#: whose voxels are thinnest stay uncut, one by one, so that a large medium is rendered on its
#: own voxels rather than refused (each light keeps some ten float32 fields per voxel).
REFINED_VOXELS = 2 ** 25
_FLOAT32_MAX = float(np.finfo(np.float32).max)


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
    # values that depend on the density alone, each with the density array it was made from
    _derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        d = np.asarray(self.density)
        if d.ndim != 3 or min(d.shape) < 1:
            raise PopvolError(f"{self.source}: density must be a 3-D array with every size >= 1, got shape {d.shape}")
        if d.dtype.kind not in "fiub":
            raise PopvolError(f"{self.source}: density must hold real numbers, not {d.dtype} values")
        check_float32_range(d, self.source, "density")
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
        check_box(self.voxel_size, self.origin, d.shape, f"{f}.voxel_size", f"{f}.origin", src)
        self.scale = check.power(self.scale, f"{f}.scale", src, MAX_SCALE)
        if _is_grid(self.albedo):
            self.albedo = _grid(self.albedo, d.shape, f"{f}.albedo", src, 0.0, 1.0, False)
        else:
            self.albedo = check.rgb(self.albedo, f"{f}.albedo", src, 0.0, 1.0)
        if _is_grid(self.g):
            self.g = _grid(self.g, d.shape, f"{f}.g", src, -1.0, 1.0, True)
        else:
            self.g = check.number(self.g, f"{f}.g", src, -1.0, 1.0, open_interval=True)
        tau = self.max_optical_depth()
        if not tau <= MAX_OPTICAL_DEPTH:
            raise PopvolError(f"{src}: {f}.scale = {_fmt3(self.scale)} gives an optical depth (scale x max density "
                              f"{float(d.max()):.3g} x diagonal {self.diagonal:.3g}) of {tau:.3g}, more than "
                              f"{MAX_OPTICAL_DEPTH:g}; lower {f}.scale (or the density, or the size of the medium)")

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

    @property
    def diagonal(self) -> float:
        """Length of the diagonal of the medium's box (world units)."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    @property
    def albedo_min(self) -> float:
        """The smallest albedo of any channel, or of any voxel holding medium (a grid)."""
        if self.albedo_per_voxel:
            held = self.albedo[self.density > 0]
            return float(held.min()) if held.size else 1.0
        return float(np.min(self.albedo))

    def diffusion_length(self) -> float:
        """The diffusion length in mean free paths, L_d = 1 / sqrt(3 (1 - a) (1 - a g)), a and g
        the medium's smallest albedo and g: the depth from which a medium that hardly absorbs
        reflects light (inf where a = 1)."""
        a, g = self.albedo_min, self.g_min
        absorbed = (1.0 - a) * (1.0 - a * g)
        return float(1.0 / np.sqrt(3.0 * absorbed)) if absorbed > 0 else np.inf

    def transport_depth_cap(self) -> float:
        """Most mean free paths across one voxel (its shortest side) that light transport sees
        (:meth:`transport_medium`; docs/METHOD.md Eq. 27): MAX_TRANSPORT_DEPTH, or where more,
        DIFFUSION_LENGTH_SHARE of :meth:`diffusion_length` but at most MAX_REDUCED_DEPTH / (1 -
        g) (one transport mean free path), g the medium's smallest. So 2 where g <= 0.5 or L_d <=
        4 mean free paths (an albedo of 0.9 with g up to 0.88), and 6.7 for a white cloud of g =
        0.85."""
        skin = DIFFUSION_LENGTH_SHARE * self.diffusion_length()
        return float(max(MAX_TRANSPORT_DEPTH, min(MAX_REDUCED_DEPTH / (1.0 - self.g_min), skin)))

    def max_voxel_optical_depth(self) -> float:
        """Largest sigma_t times the voxel's shortest side: mean free paths across one voxel."""
        with np.errstate(over="ignore"):
            return float(self.scale.max() * float(self.density.max()) * float(self.voxel_size.min()))

    def refinement(self, voxel_depth: float) -> tuple[int, int, int]:
        """How many parts each voxel side is cut into so that no voxel is more than
        ``voxel_depth`` mean free paths across any side: per axis a the smallest odd number at
        least sigma_t,max h_a / voxel_depth (sigma_t,max of the densest voxel and channel), at
        most MAX_REFINEMENT; (1, 1, 1) for voxel_depth 0 (method.voxel_depth: off). Where the
        finer grid would have more than REFINED_VOXELS voxels, the axis whose voxels are
        optically thinnest is left uncut, then the next, until it has no more.

        Odd, so that every voxel centre of the medium is a centre of the finer grid too: the
        trilinear density has its kinks at the medium's centres, and a finer grid read
        trilinearly reproduces it exactly only if it has a centre at each of them (tested). An
        even number of parts puts none there; it cuts the density's peaks and fills its valleys,
        and it widens every edge of the medium by a fraction of a voxel, where the camera sees
        a cloud's fringe against the sky."""
        if not voxel_depth:
            return (1, 1, 1)
        with np.errstate(over="ignore"):
            sigma_max = float(self.scale.max()) * float(self.density.max())
        # the least parts, at most MAX_REFINEMENT (odd), rounded up to odd (k | 1)
        parts = [int(min(MAX_REFINEMENT, max(1.0, np.ceil(sigma_max * h / voxel_depth - 1e-9)))) | 1
                 for h in self.voxel_size]
        n = int(np.prod(self.density.shape))
        for axis in np.argsort(self.voxel_size, kind="stable"):     # the thinnest voxel sides first
            if n * int(np.prod(parts)) <= REFINED_VOXELS:
                break
            parts[axis] = 1
        return tuple(parts)

    def refined(self, voxel_depth: float) -> "Medium":
        """The medium light is solved and rendered on at ``method.voxel_depth`` (docs/METHOD.md,
        "Voxels thinner than a mean free path"): each voxel cut into :meth:`refinement` parts
        per side, the density (and a per-voxel albedo or g) trilinear at the finer voxels'
        centres (:func:`refine_grid`), over the same box; this medium itself where no voxel is
        thicker than ``voxel_depth`` or it is 0. Made once per density array and kept, so that
        the solve and every render of it meet the same grid."""
        factors = self.refinement(voxel_depth)
        if factors == (1, 1, 1):
            return self

        def make(density):
            from .domains import check_memory     # domains imports this module
            shape = tuple(n * k for n, k in zip(density.shape, factors))
            check_memory(4 * int(np.prod(shape)) * (1 + self.albedo_per_voxel + self.g_per_voxel), self.source,
                         f"method.voxel_depth = {voxel_depth:g} cuts the medium's voxels into "
                         f"{'x'.join(map(str, factors))} parts: a {'x'.join(map(str, shape))} grid that",
                         "raise method.voxel_depth (0: the medium's own voxels)")
            voxel = self.voxel_size / np.asarray(factors)
            lo, _ = self.bounds
            return replace(self, density=refine_grid(density, factors), voxel_size=voxel, origin=lo + voxel / 2,
                           albedo=refine_grid(self.albedo, factors) if self.albedo_per_voxel else self.albedo,
                           g=refine_grid(self.g, factors) if self.g_per_voxel else self.g)
        return self.derived(f"refined {factors}", make)

    def derived(self, name: str, make):
        """``make(self.density)``: a value that depends on the density alone (the voxels the
        renderer reads, the march's coarse grid), made once per density array and kept with
        the medium, so that every frame of a still medium does not make it again. A medium
        whose ``density`` is replaced by another array makes it anew; densities are never
        changed in place."""
        made = self._derived.get(name)
        if made is None or made[0] is not self.density:
            made = (self.density, make(self.density))
            self._derived[name] = made
        return made[1]

    def capped_scattering_warning(self) -> str | None:
        """One line for the user where light transport caps this medium's voxels
        (:meth:`transport_medium`) below half its diffusion length (held at one transport mean
        free path, or at MAX_TRANSPORT_DEPTH where g <= 0.5): there the capped voxels let the
        scattered light of a medium that hardly absorbs through and the image comes out too dark
        (docs/METHOD.md, "Optically thick voxels"); None elsewhere."""
        tau, cap = self.max_voxel_optical_depth(), self.transport_depth_cap()
        if tau <= cap or cap >= DIFFUSION_LENGTH_SHARE * self.diffusion_length():
            return None
        return (f"{self.source}: the densest voxels are {tau:.3g} mean free paths across (albedo "
                f"{self.albedo_min:.3g}, g {self.g_min:.2f}); light transport caps them at {cap:.3g} mean free "
                "paths, less than the depth this medium reflects light from, so their scattered light leaks through "
                "and the image comes out too dark (a slab of albedo 0.999 and g = 0.85 at 10 mean free paths per "
                "voxel: x0.61 / x0.72 of Monte Carlo at 16 / 32 cells; docs/METHOD.md, \"Optically thick voxels\"); "
                "method.voxel_depth cuts voxels up to 3 times finer")

    def transport_medium(self) -> "Medium":
        """The medium light transport solves (docs/METHOD.md, "Optically thick voxels"): this
        one with its density capped where a voxel would be more than :meth:`transport_depth_cap`
        mean free paths across (sigma_t of the densest channel times the voxel's shortest side),
        albedo and g unchanged; this medium itself where no voxel is."""
        depth = self.transport_depth_cap()
        if self.max_voxel_optical_depth() <= depth:
            return self
        cap = depth / (float(self.scale.max()) * float(self.voxel_size.min()))
        # one capped array per density and cap, so that what is kept for a grid (the renderer's
        # gather state) is found again
        return replace(self, density=self.derived(f"transport density {cap!r}",
                                                  lambda density: np.minimum(density, np.float32(cap))))

    def intact(self) -> bool:
        """Whether its fields still hold what the checks of its construction made of them: the
        types and shapes, the density's least and largest value (finite, >= 0), the optics'
        ranges, the optical depth's bound. Cheap (two passes over the density; an optics grid
        adds two); popvol.scene.checked_scene builds a medium that is not intact again."""
        d, f = self.density, np.isfinite

        def grid_or(value, lo, hi, closed, grey_shape):
            if isinstance(value, np.ndarray) and value.ndim == 3:
                a, b = (value.shape == d.shape and value.dtype == np.float32 and value.flags.c_contiguous
                        and value.size > 0), None
                if a:
                    a, b = float(value.min()), float(value.max())
                    return (lo <= a and b <= hi) if closed else (lo < a and b < hi)
                return False
            v = np.asarray(value)
            return (isinstance(value, (float, np.ndarray)) and v.shape == grey_shape and v.dtype == np.float64
                    and bool(np.all(f(v))) and bool(np.all((lo <= v) & (v <= hi) if closed else (lo < v) & (v < hi))))

        if not (isinstance(d, np.ndarray) and d.dtype == np.float32 and d.ndim == 3 and d.flags.c_contiguous
                and min(d.shape) >= 1):
            return False
        lo, hi = float(d.min()), float(d.max())
        if not (lo >= 0.0 and hi < np.inf):
            return False
        for v in (self.voxel_size, self.origin):
            if not (isinstance(v, np.ndarray) and v.shape == (3,) and v.dtype == np.float64 and np.all(f(v))):
                return False
        s = self.scale
        if not (isinstance(s, np.ndarray) and s.shape == (3,) and s.dtype == np.float64 and np.all(f(s))
                and s.min() >= 0 and s.max() <= MAX_SCALE and np.all(self.voxel_size > 0)):
            return False
        if not (grid_or(self.albedo, 0.0, 1.0, True, (3,)) and grid_or(self.g, -1.0, 1.0, False, ())):
            return False
        return self.max_optical_depth() <= MAX_OPTICAL_DEPTH

    def max_optical_depth(self) -> float:
        """Largest sigma_t times the box's diagonal: a bound on the optical depth of any path
        (checked against MAX_OPTICAL_DEPTH when the medium is made)."""
        with np.errstate(over="ignore"):
            return float(self.scale.max() * float(self.density.max()) * self.diagonal)


def refine_grid(x: np.ndarray, factors: tuple[int, int, int]) -> np.ndarray:
    """float32 (nx kx, ny ky, nz kz): the grid ``x`` (nx, ny, nz), read trilinearly between its
    voxel centres and clamped to the outermost ones (as the renderer reads a grid), at the
    centres of its voxels cut into ``factors`` = (kx, ky, kz) equal parts per side. Fine voxel
    j along an axis of n voxels cut into k has its centre at voxel coordinate (j + 1/2) / k - 1/2."""
    out = np.asarray(x, np.float32)
    for axis, k in enumerate(factors):
        if k == 1:
            continue
        n = out.shape[axis]
        u = np.clip((np.arange(n * k) + 0.5) / k - 0.5, 0.0, n - 1)
        i0 = np.minimum(np.floor(u).astype(np.intp), max(n - 2, 0))
        w = (u - i0).astype(np.float32)
        shape = [1, 1, 1]
        shape[axis] = n * k
        w = w.reshape(shape)
        a = np.take(out, i0, axis=axis)
        b = np.take(out, np.minimum(i0 + 1, n - 1), axis=axis)
        out = a + w * (b - a)
    return np.ascontiguousarray(out, np.float32)


def check_float32_range(values: np.ndarray, source: str, field: str) -> None:
    """Refuse finite values beyond float32's range (they would become inf when stored)."""
    if values.dtype.kind == "f" and values.dtype.itemsize > 4 and values.size:
        with np.errstate(invalid="ignore"):
            big = np.abs(values) > _FLOAT32_MAX
        if big.any():
            first = tuple(int(v) for v in np.argwhere(big)[0])
            raise PopvolError(f"{source}: {field} has {int(big.sum())} values beyond float32's range "
                              f"(+-{_FLOAT32_MAX:.3g}; first at {first}: {float(values[first]):.3g}); divide "
                              "the grid by a constant and multiply medium.scale by it")


def check_box(voxel_size: np.ndarray, origin: np.ndarray, shape, voxel_field: str, origin_field: str,
              source: str) -> None:
    """Refuse a voxel size and origin whose box leaves [-MAX_COORDINATE, MAX_COORDINATE] or
    whose voxels are too fine for float64 world positions there (MIN_RELATIVE_VOXEL)."""
    v, o = np.asarray(voxel_size, np.float64), np.asarray(origin, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        lo = o - 0.5 * v
        hi = o + (np.asarray(shape, np.float64) - 0.5) * v
        reach = float(np.max(np.abs(np.concatenate([lo, hi]))))
    if not np.all(np.abs(o) <= MAX_COORDINATE):
        raise PopvolError(f"{source}: {origin_field} = {_fmt3(o)} must be within +-{MAX_COORDINATE:g} "
                          "(world units) on every axis")
    if not reach <= MAX_COORDINATE:
        raise PopvolError(f"{source}: {origin_field} = {_fmt3(o)} and {voxel_field} = {_fmt3(v)} put the medium's "
                          f"box of {'x'.join(map(str, shape))} voxels at up to {reach:.3g}, beyond "
                          f"+-{MAX_COORDINATE:g} (world units) on some axis")
    least = MIN_RELATIVE_VOXEL * max(1.0, reach)
    if not v.min() >= least:
        raise PopvolError(f"{source}: {voxel_field} = {_fmt3(v)} must be at least {least:.3g} (world units; "
                          f"{MIN_RELATIVE_VOXEL:g} x max(1, the largest |coordinate| of the medium's box))")


def _fmt3(v) -> str:
    v = np.asarray(v, np.float64).ravel()
    return f"{v[0]:g}" if np.all(v == v[0]) else "[" + ", ".join(f"{x:g}" for x in v) + "]"


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
                          f"(first at voxel {at}: {float(a[at]):g})")
    return a
