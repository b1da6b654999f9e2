"""Rectilinear light-aligned grids: a sun's domain and every diffusion grid (docs/METHOD.md,
"Walk"), the medium's optics sampled at their cells, and the memory check before allocating.

A directional light gets a rectilinear grid of cubic cells whose first axis is the light's
direction of travel d (its principal ordinate); the other two axes u, v complete a right-handed
frame. The grid's lattice covers the medium's world AABB (the AABB, in the (d, u, v) frame, of
its 8 corners), and the grid is that lattice cropped to the cells the medium's non-empty voxels
reach (:func:`crop_to_medium`): light walks only where it can meet the medium. Slice 0 (index
k = 0) faces the light.

Index convention: cell (k, i, j) has its centre at
``origin + ((k + 1/2) d + (i + 1/2) u + (j + 1/2) v) * h`` where ``origin`` is the world
position of the domain's corner. Continuous index coordinates put cell centres at integers.
"""
from __future__ import annotations

import contextlib
import importlib
import os
from dataclasses import dataclass

import numpy as np

from .errors import PopvolError
from .kernels.sampling import cells_read, resample
from .medium import Medium

#: Working-set bytes per domain cell (float32 arrays): the solvers hold Th, Dh, in-flight W and
#: W*a, accumulated phi and phi*a; Jacobi adds its six outgoing parts (the sweep only small
#: halos). sigma_t, sigma_s and g exist while Th and Dh are computed. Sized for Jacobi.
BYTES_PER_DOMAIN_CELL = 4 * 14

#: Peak bytes per image pixel while an image is rendered and written: the float32 image and
#: the float64 temporaries of tone mapping it for the PNG (io/images.py).
BYTES_PER_PIXEL = 160


def check_image_memory(width: int, height: int, field: str) -> None:
    """Refuse, before any work, an image of width x height pixels that would not fit in memory."""
    check_memory(int(width) * int(height) * BYTES_PER_PIXEL, field, f"a {width}x{height} image")


def light_frame(direction: np.ndarray) -> np.ndarray:
    """float64 (3, 3), rows d, u, v: orthonormal, right-handed (v = d x u), d = direction."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    return np.stack([d, u, v])


def frame_to_world(frame, F: np.ndarray) -> np.ndarray:
    """A vector field F (3, ...) whose components lie along the rows of ``frame`` (3, 3; a
    domain's axes d, u, v) in the world frame: component c is the sum over the axes a of
    frame[a, c] F[a], in F's dtype. By elementwise products, not np.tensordot or @: those are
    BLAS calls, after which OpenBLAS's threads spin for milliseconds and take the second core
    from the Numba kernels that follow (the first sweep of the next walk took 25-80 ms instead
    of 17 on two cores)."""
    f = np.asarray(frame, F.dtype)
    return np.stack([f[0, c] * F[0] + f[1, c] * F[1] + f[2, c] * F[2] for c in range(3)])


@dataclass
class DirectionalDomain:
    """A rectilinear domain aligned with a directional light.

    Attributes:
        frame: float64 (3, 3), rows d, u, v (world space).
        origin: float64 (3,), world position of the corner of cell (0, 0, 0).
        h: cell size in world units (cells are cubes).
        shape: (n_d, n_u, n_v) cells.
        block: the crop starts at a multiple of ``block`` cells of the medium box's lattice
            along each axis, so blocks of block^3 cells (a coarser diffusion grid) are the same
            cells whatever the crop.
    """

    frame: np.ndarray
    origin: np.ndarray
    h: float
    shape: tuple[int, int, int]
    block: int = 1

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def cell_size(self) -> float:
        return self.h

    def world_to_index(self, x: np.ndarray) -> np.ndarray:
        """Continuous cell index (centres at integers) of world points x (..., 3)."""
        return (np.asarray(x) - self.origin) @ self.frame.T / self.h - 0.5

    def index_to_world(self, q: np.ndarray) -> np.ndarray:
        """World position of continuous cell index q (..., 3)."""
        return self.origin + (np.asarray(q) + 0.5) * self.h @ self.frame

    def cells_read(self, medium: Medium, seen: np.ndarray) -> np.ndarray:
        """bool (the domain's shape): the cells whose fields are read when they are mapped onto
        the ``seen`` voxels (bool, the medium's shape: pipeline.voxels_seen) of ``medium``,
        the corners of those voxels' trilinear stencils (kernels.sampling.cells_read)."""
        out = np.zeros(self.shape, np.bool_)
        cells_read(seen, np.asarray(self.frame, np.float64), np.asarray(self.origin, np.float64), float(self.h),
                   np.asarray(medium.origin, np.float64), np.asarray(medium.voxel_size, np.float64), out)
        return out


def directional_domain(medium: Medium, direction: np.ndarray, resolution: int, block: int = 1,
                       crop: bool = True, field: str | None = None) -> DirectionalDomain:
    """The domain for light travelling along ``direction``: a lattice of cubic cells with
    ``resolution`` cells along the longest side of the medium's box in the light's frame (the
    other sides rounded up to whole cells), cropped to the medium (:func:`crop_to_medium`, the
    crop aligned to ``block`` cells) unless ``crop`` is False. ``field``: how a message about its
    memory names the resolution (default: the medium's source and ``method.resolution``;
    popvol.method.knob_field)."""
    frame = light_frame(direction)
    lo, hi = medium.bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    local = corners @ frame.T                     # (8, 3) coordinates along d, u, v
    lmin, lmax = local.min(axis=0), local.max(axis=0)
    extent = lmax - lmin
    h = float(extent.max() / resolution)
    shape = tuple(int(max(1, np.ceil(e / h - 1e-9))) for e in extent)
    # centre the (slightly larger) grid on the medium's box
    pad = (np.asarray(shape) * h - extent) / 2
    origin = (lmin - pad) @ frame
    dom = DirectionalDomain(frame, origin, h, shape, block)
    if crop:
        dom = crop_to_medium(dom, medium)
    check_memory(dom.n_cells * BYTES_PER_DOMAIN_CELL, field or f"{medium.source}: method.resolution = {resolution}",
                 f"a light domain of {dom.shape[0]}x{dom.shape[1]}x{dom.shape[2]} cells")
    return dom


def grow(mask: np.ndarray) -> np.ndarray:
    """bool, ``mask``'s shape: ``mask`` and the 26 neighbours of each cell set in it (a
    separable 3x3x3 dilation)."""
    m = np.asarray(mask, np.bool_)
    for axis in range(3):
        d = m.copy()
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        d[tuple(lo)] |= m[tuple(hi)]
        d[tuple(hi)] |= m[tuple(lo)]
        m = d
    return m


_OCCUPIED: list = []      # one entry: (density array, its column ends), see occupied_ends


def occupied_ends(density: np.ndarray) -> np.ndarray:
    """float64 (M, 3): voxel indices of the first and the last non-empty voxel of every column
    along the first axis that has one. Every non-empty voxel lies between two of them, so a
    linear function's extremes over the non-empty voxels are its extremes over these points.
    The last density's answer is kept (one light after another asks for it)."""
    if _OCCUPIED and _OCCUPIED[0][0] is density:
        return _OCCUPIED[0][1]
    m = density > 0
    any_ = m.any(axis=0)
    j, k = np.nonzero(any_)
    first = np.argmax(m, axis=0)[j, k]
    last = m.shape[0] - 1 - np.argmax(m[::-1], axis=0)[j, k]
    ends = np.concatenate([np.stack([first, j, k], 1), np.stack([last, j, k], 1)]).astype(np.float64)
    _OCCUPIED[:] = [(density, ends)]
    return ends


def medium_extent(medium: Medium, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(lo, hi) float64 (3,): the extent along the rows of ``frame`` of the voxel cells that
    the renderer reads fields at (the non-empty voxels and their neighbours, see
    pipeline.voxels_seen); None if the medium is empty."""
    ends = occupied_ends(medium.density)
    if len(ends) == 0:
        return None
    axes = np.asarray(frame, np.float64) * medium.voxel_size[None, :]    # a voxel step, per row
    p = ends @ axes.T
    # a voxel centre to its cell's far corner, plus one voxel for the neighbours
    margin = 1.5 * np.abs(axes).sum(axis=1)
    base = np.asarray(medium.origin, np.float64) @ np.asarray(frame, np.float64).T
    return base + p.min(axis=0) - margin, base + p.max(axis=0) + margin


def crop_to_medium(dom: DirectionalDomain, medium: Medium) -> DirectionalDomain:
    """The cells of ``dom``'s lattice that overlap :func:`medium_extent`, the first one at a
    multiple of ``dom.block`` along each axis. Light outside them never meets the medium again
    along a straight line (the extent is a convex box), so walking it would only let the walk's
    six-direction steps carry it back by a random walk through vacuum; on the demo at dusk
    (sun and an 8-direction sky) the domains shrink 6x and the image moves by relMSE 5e-4."""
    ext = medium_extent(medium, dom.frame)
    if ext is None:
        return dom
    corner = np.asarray(dom.origin) @ dom.frame.T          # lattice corner along d, u, v
    n = np.asarray(dom.shape)
    a = np.clip(np.floor((ext[0] - corner) / dom.h).astype(np.int64), 0, n - 1)
    a = a // dom.block * dom.block
    b = np.clip(np.ceil((ext[1] - corner) / dom.h).astype(np.int64), a + 1, n)
    origin = (corner + a * dom.h) @ dom.frame
    return DirectionalDomain(dom.frame, origin, dom.h, tuple(int(x) for x in b - a), dom.block)


def optics(medium: Medium, grid, shape, channel: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sigma_t, sigma_s, g (float32 ``shape``) of colour ``channel`` at a domain's cells, where
    ``grid(values, clamp)`` samples a world voxel grid at those cells (0 outside the grid, or
    clamped to its edge if ``clamp``: per-voxel albedo and g, where the density is 0 anyway)."""
    sigma_t = grid(medium.density, False) * np.float32(medium.scale[channel])
    if medium.albedo_per_voxel:
        sigma_s = sigma_t * grid(medium.albedo, True)
    else:
        sigma_s = sigma_t * np.float32(medium.albedo[channel])
    g = grid(medium.g, True) if medium.g_per_voxel else np.full(shape, medium.g, np.float32)
    return sigma_t, sigma_s, g


def resample_medium(medium: Medium, domain: DirectionalDomain, channel: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sigma_t, sigma_s, g of colour ``channel`` at a rectilinear domain's cell centres,
    float32 (n_d, n_u, n_v) each."""
    def grid(values, clamp):
        out = np.empty(domain.shape, np.float32)
        resample(values, 1.0 / medium.voxel_size, medium.origin, domain.frame, domain.origin,
                 domain.h, domain.shape, clamp, out)
        return out
    return optics(medium, grid, domain.shape, channel)


def available_memory() -> int:
    """Bytes of memory available to this process now (MemAvailable, else total physical)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(nbytes: int, field: str, what: str, remedy: str = "lower it") -> None:
    """Raise a PopvolError before allocating ``nbytes`` if it exceeds 80 % of available memory:
    "{field}: {what} needs about N GiB, but only M GiB of memory is available; {remedy}"."""
    avail = available_memory()
    if nbytes > 0.8 * avail:
        raise PopvolError(f"{field}: {what} needs about {nbytes / 2**30:.1f} GiB, but only "
                          f"{avail / 2**30:.1f} GiB of memory is available; {remedy}")


@contextlib.contextmanager
def small_pages():
    """Allocate NumPy arrays inside the block without asking Linux for transparent huge pages.

    NumPy advises the kernel to back every array of 4 MiB or more with 2 MiB pages. For the
    solution's world fields (zeros, written only where the renderer reads them, a few hundred
    MB with many lights) that costs more than it saves: on kernels whose THP ``defrag`` is
    ``madvise`` (Debian's default) the first write into each 2 MiB region can stall while the
    kernel compacts memory, and each touched region is resident whole. Measured by ``popvol
    bench`` on the WDAS cloud under sun + sky (9 lights): the fields stage took 0.18-0.74 s with
    huge pages and 0.20-0.31 s without. Dense arrays that are read at random (the domains, a point
    light's spherical block) keep them: there they save TLB misses. The previous setting is
    restored on leaving; without NumPy's switch the block runs unchanged."""
    switch = hugepage_switch()
    if switch is None:
        yield
        return
    before = switch(False)
    try:
        yield
    finally:
        switch(before)


def hugepage_switch():
    """NumPy's ``_set_madvise_hugepage(enabled) -> previous`` (numpy._core in NumPy 2,
    numpy.core in NumPy 1), or None where this NumPy has none."""
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            return getattr(importlib.import_module(module), "_set_madvise_hugepage")
        except (ImportError, AttributeError):
            continue
    return None
