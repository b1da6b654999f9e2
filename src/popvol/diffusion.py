"""The isotropic stage as a diffusion solve (docs/METHOD.md, "Diffusion stage").

Why: once a cell's lobe has spread (|a| small), POP's six-neighbour walk moves it like a random
walk whose step is the cell size, so its diffusion length follows the grid, not the transport
mean free path, and the answer does not converge under refinement (docs/ACCURACY_NOTES.md).
Light in that state is handed to the steady diffusion equation instead, whose coefficient is
physical:

    -div(D grad phi_d) + sigma_a phi_d = q0 - div(3 D q1),     D = 1 / (3 sigma_tr),
    sigma_tr = sigma_a + sigma_s (1 - g)  (similarity: the transport coefficient),

with q0 the handed-over power per volume and q1 its first moment (power * a along the light's
axis, per volume): the standard P1 source of an anisotropic emitter, which keeps light that was
still drifting forward from being re-emitted backward. Marshak boundaries (no light enters) at
the domain faces and where the region ends, through the area of the region's smooth surface:
the region's boundary is a staircase of cell faces whose area is |n_x| + |n_y| + |n_z| (the L1
norm of the unit normal, 1 to sqrt(3)) times the surface's, so each boundary face of a cell
leaks with the weight 1 / |n|_1, n the normal of the smoothed region mask there
(:func:`boundary_weight`); without it the diffuse light leaks through up to sqrt(3) times the
true area (about 1.4x on the WDAS cloud). On a homogeneous sphere whose fluence is set by its
leak, the absorbed share comes out 4-6 % high with the weight and 5-15 % low without it
(tests/test_diffusion.py, against the analytic solution). Solved by conjugate gradients
(Jacobi preconditioner) in kernels/diffusion.py.

The region: cells with sigma_tr > 0; D is capped at L / 3 (L: the domain's longest side), a
transport mean free path as long as the domain, so the thinnest fringes stay finite.

Rendering: the diffuse light is a second lobe beside the walk's, phi_d * HG(w . J/|J|; A) with
J = -D grad phi_d the diffusion flux and A = min(|J| / phi_d, 1/2): the same fluence and first
moment as the P1 radiance (phi_d + 3 J . w) / 4 pi up to |J| = phi_d / 2, the Marshak value at
the region's boundary (where the light that the camera sees leaves), and never negative. The cap
is 1/2 rather than 1/3 (where P1 itself stays >= 0), which would darken sunlit faces, and not 1,
which makes speckles where the fluence is spiky near hand-over cells. The lobe's axis is J's own
direction, not the light's axis as for the walk's lobe: light leaving a cloud sideways to the
sun is seen leaving sideways, and faces lit at grazing angles keep their brightness.

Biases (documented in the README): diffusion is wrong where the medium is thin on the scale of
a transport mean free path (fringes, thin wisps) and near the lit faces; light leaking out of the
region into empty cells of the domain is not propagated further (it is tallied as escaped).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .domains import check_memory, frame_to_world
from .kernels import diffusion as K
from .kernels.sampling import NO_BLOCKS, block_sums


@dataclass
class DiffusionResult:
    phi: np.ndarray          # float32 (grid shape): fluence of the diffuse light [W/m^2]
    flux: np.ndarray         # float32 (3,) + grid shape: its flux J [W/m^2] along d, u, v
    iterations: int
    residual: float          # final ||r|| / ||b||
    absorbed: float          # [W]
    leaked: tuple            # [W]: (face toward the light, far face, lateral faces, into empty cells)
    source: float            # [W]: handed-over power
    h: float = 0.0           # cell size of the diffusion grid (the domain's times ``factor``)
    factor: int = 1          # the diffusion grid's cells are factor^3 domain cells


def coarsen(x, factor: int, how: str = "sum") -> np.ndarray:
    """Blocks of factor^3 cells (the grid padded with zeros to a multiple of factor): their sum
    (powers) or mean (coefficients), float64."""
    if factor == 1:
        return np.asarray(x, np.float64)
    b = np.empty(tuple(-(-s // factor) for s in x.shape), np.float64)
    block_sums(np.ascontiguousarray(x)[None], factor, False, b[None], NO_BLOCKS)
    return b if how == "sum" else b / factor ** 3


def coarse_optics(sigma_t, sigma_s, g, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sigma_t, sigma_s and g of blocks of factor^3 cells, float64: sigma_t and sigma_s averaged,
    g averaged weighted by sigma_s (0 where a block does not scatter)."""
    ss = coarsen(sigma_s, factor, "mean")
    g = np.divide(coarsen(sigma_s * g, factor, "mean"), ss, out=np.zeros_like(ss), where=ss > 0)
    return coarsen(sigma_t, factor, "mean"), ss, g


def coefficients(sigma_t, sigma_s, g, h):
    """D [world units], sigma_a h^3, and the region mask, from the domain's medium."""
    sigma_t, sigma_s, g = (np.asarray(a, np.float64) for a in (sigma_t, sigma_s, g))
    sigma_a = np.maximum(sigma_t - sigma_s, 0.0)
    sigma_tr = sigma_a + sigma_s * (1.0 - g)
    mask = sigma_tr > 0
    L = h * max(sigma_t.shape)
    with np.errstate(divide="ignore", over="ignore"):
        D = np.where(mask, np.minimum(1.0 / (3.0 * sigma_tr), L / 3.0), 1.0).astype(np.float32)
    return D, (sigma_a * h ** 3).astype(np.float32), mask


def source(Q0, Q1, D, mask, h):
    """Right-hand side b [W]: q0 h^3 minus the divergence of 3 D q1 (along the light axis k),
    face values of q1 averaged, D harmonic; no dipole flux through the region's boundary."""
    b = Q0.astype(np.float64)
    m = Q1.astype(np.float64)                  # power * a per cell [W]
    Df = np.zeros((D.shape[0] + 1,) + D.shape[1:])
    both = mask[1:] & mask[:-1]
    Df[1:-1] = np.where(both, 2.0 * D[1:] * D[:-1] / np.maximum(D[1:] + D[:-1], 1e-30), 0.0)
    mf = np.zeros_like(Df)
    mf[1:-1] = m[1:] + m[:-1]
    flux = Df * mf * (3.0 / (2.0 * h))         # 3 D q1 . n h^2 through face k - 1/2, toward +k
    b -= flux[1:] - flux[:-1]
    return b


def solve_diffusion(Q0, Q1, sigma_t, sigma_s, g, h, rtol=1e-4, max_iterations=0,
                    factor: int = 1, x0=None) -> DiffusionResult:
    """Diffuse light of a domain from its handed-over power Q0 and moment Q1 (float32, [W]).

    ``factor`` > 1 solves on a grid of factor^3-cell blocks (powers summed, sigma_t, sigma_s
    averaged, g averaged weighted by sigma_s): diffuse light is smooth, and the cost falls by
    about factor^4 (factor^3 cells, factor times fewer conjugate-gradient iterations).
    ``x0``: an initial guess of phi on the (coarsened) grid, e.g. the previous frame's
    (:func:`warm_guess`); None starts from 0. The answer does not depend on it beyond the
    tolerance (see :func:`pcg`).
    """
    if factor > 1:
        sigma_t, sigma_s, g = coarse_optics(sigma_t, sigma_s, g, factor)
        Q0, Q1 = coarsen(Q0, factor), coarsen(Q1, factor)
        h = h * factor
    D, sah3, mask = coefficients(sigma_t, sigma_s, g, h)
    b = source(Q0, Q1, D, mask, h)
    b[~mask] = 0.0
    bw = boundary_weight(mask)
    x, it, res = pcg(D, sah3, mask, h, b, rtol, max_iterations or 20 * max(b.shape) + 200, bw, x0)
    leaked = K.leaks(x, D, mask, h, bw)
    absorbed = float(np.sum(sah3 * x))
    # P1 flux J = -D grad phi (the source's own moment 3 D q1 is left out: it is spiky where
    # packets cross the hand-over threshold, and makes no measurable difference to the images)
    J = np.zeros((3,) + x.shape, np.float32)
    for axis in range(3):
        grad = np.gradient(x, h, axis=axis) if x.shape[axis] > 1 else np.zeros_like(x)
        J[axis] = np.where(mask, -D * grad, 0.0)
    return DiffusionResult(x.astype(np.float32), J, it, res, absorbed,
                           tuple(float(v) for v in leaked), float(Q0.sum(dtype=np.float64)), h, factor)


def boundary_weight(mask) -> np.ndarray:
    """float32 (mask's shape): 1 / |n|_1 = |grad m|_2 / |grad m|_1 (in [1/sqrt(3), 1]), with m the
    region mask smoothed by a binomial filter [1 4 6 4 1] / 16 along each axis (a Gaussian of
    one cell; zero outside the grid): the factor by which a boundary cell's faces overstate the
    area of the smooth surface through it. 1 where the smoothed mask is flat or outside the
    region. Where the region is cut by the grid's own faces, its edges and corners get the
    weight of a rounded edge (0.71, 0.58) though the staircase is exact there (about 1 % on a
    filled cube). (kernels/diffusion.boundary_weight; NumPy twin in tests/twins.py.)"""
    out = np.empty(mask.shape, np.float32)
    K.boundary_weight(np.ascontiguousarray(mask, np.bool_), out)
    return out


#: the conjugate gradients' vectors are (rows, 1, ROW_LENGTH) arrays over the region's cells
#: (RowSpace), so that the kernels' fixed-order sums run over rows in parallel
ROW_LENGTH = 256


class RowSpace:
    """The region's cells as the conjugate gradients' unknowns: ``cells`` int64 (n,), their flat
    C-order indices in the grid, and A's rows there (kernels/diffusion.py, region_rows: ``nbr``,
    ``G``, ``diag``). A vector is an array (rows, 1, ROW_LENGTH) whose first n entries in C order
    are the cells' values and the rest padding kept at 0 (the sums and products of the CG
    kernels then run as on a grid)."""

    def __init__(self, D, sah3, mask, h, bw):
        self.shape = mask.shape
        self.cells = np.flatnonzero(mask)
        n = len(self.cells)
        # per region cell: its index, 6 neighbours (int32), 6 conductances and the diagonal
        # (float64); the grid's map to rows (int32)
        check_memory(n * (8 + 6 * 4 + 7 * 8) + mask.size * 4, "method.diffusion_resolution",
                     f"the diffusion solve's {n} region cells")
        index = np.full(mask.shape, -1, np.int32)
        index.reshape(-1)[self.cells] = np.arange(n)
        self.nbr = np.empty((n, 6), np.int32)
        self.G = np.empty((n, 6))
        self.diag = np.empty(n)
        K.region_rows(D, sah3, mask, h, bw, self.cells, index, self.nbr, self.G, self.diag)
        self.rows = max(1, -(-n // ROW_LENGTH))

    def vector(self, dtype, padding: float = 0.0) -> np.ndarray:
        """A vector of zeros, its padding set to ``padding``."""
        return np.full((self.rows, 1, ROW_LENGTH), padding, dtype) if padding else \
            np.zeros((self.rows, 1, ROW_LENGTH), dtype)

    def pack(self, grid, dtype) -> np.ndarray:
        """The vector of ``grid``'s values at the region's cells."""
        v = self.vector(dtype)
        v.reshape(-1)[:len(self.cells)] = grid.reshape(-1)[self.cells]
        return v

    def unpack(self, v) -> np.ndarray:
        """The grid (the mask's shape, v's dtype) of the vector v: 0 outside the region."""
        grid = np.zeros(self.shape, v.dtype)
        grid.reshape(-1)[self.cells] = v.reshape(-1)[:len(self.cells)]
        return grid

    def apply(self, x, out) -> None:
        """out = A x (vectors)."""
        K.apply_rows(x, self.nbr, self.G, self.diag, out)


def pcg(D, sah3, mask, h, b, rtol, max_iterations, bw=None, x0=None):
    """Jacobi-preconditioned conjugate gradients for A x = b. Returns (x, iterations, ||r||/||b||).
    Vectors are float32 when rtol >= 1e-6 (half the memory traffic; sums stay float64), float64
    for tighter tolerances, and hold the region's cells alone (:class:`RowSpace`); x is returned
    on the grid, 0 outside the region (where b is not read). ``bw``: the boundary weights (None:
    1, the staircase's own area).

    ``x0``: an initial guess (warm start; None: x = 0). Its zeros in the region are filled from
    their neighbours (:func:`fill_gaps`), then it is scaled by the Galerkin factor
    s = x0.b / x0.A x0, the s that minimises the A-norm of the error ||s x0 - x||_A over s, so a
    warm start never begins farther from the answer (in the norm CG minimises) than a cold one,
    however unlike x0 is (a guess unrelated to b is scaled toward 0). The stopping rule is the same
    residual ||b - A x|| <= rtol ||b||, relative to ||b|| and not to the start, so the answer
    depends on x0 only within the tolerance; with x0 the residual is also recomputed as b - A x
    when the recursion says it has converged (the float32 recursion may drift from it), and CG
    restarts from x if the true residual is above the tolerance.
    """
    if bw is None:
        bw = np.ones(b.shape, np.float32)
    dtype = np.float32 if rtol >= 1e-6 else np.float64
    space = RowSpace(D, sah3, mask, h, bw)
    bv = space.pack(b, b.dtype)
    x = space.vector(dtype)
    bn = math.sqrt(K.dot(bv, bv))
    if bn == 0.0:
        return space.unpack(x), 0, 0.0
    M = space.vector(dtype, padding=1.0)          # the diagonal; 1 in the padding, divided by
    M.reshape(-1)[:len(space.cells)] = space.diag
    Ap = space.vector(dtype)
    if x0 is None:
        r = bv.astype(dtype)
    else:
        x = space.pack(fill_gaps(x0, mask), dtype)
        space.apply(x, Ap)
        xAx = K.dot(x, Ap)
        s = K.dot(x, bv) / xAx if xAx > 0.0 else 0.0
        s = s if math.isfinite(s) else 0.0
        x *= dtype(s)
        r = (bv - s * Ap.astype(np.float64)).astype(dtype)
    z = r / M
    p = z.copy()
    rz = K.dot(r, z)
    rr = K.dot(r, r)
    it = 0
    while True:
        while math.sqrt(rr) > rtol * bn and it < max_iterations:
            space.apply(p, Ap)
            alpha = rz / K.dot(p, Ap)
            rz_new, rr = K.cg_update(x, r, p, Ap, M, alpha, z)
            K.cg_direction(p, z, rz_new / rz)
            rz = rz_new
            it += 1
        if x0 is None:
            break
        # warm start: the true residual decides, not the recursion
        space.apply(x, Ap)
        r = (bv - Ap.astype(np.float64)).astype(dtype)
        rr = K.dot(r, r)
        if math.sqrt(rr) <= rtol * bn or it >= max_iterations:
            break
        z = r / M
        p = z.copy()
        rz = K.dot(r, z)
    return space.unpack(x), it, math.sqrt(rr) / bn


def grid_geometry(grid, factor: int = 1) -> tuple:
    """(frame, origin, cell size, shape) of a rectilinear diffusion grid coarsened by ``factor``
    (blocks of factor^3 cells, the last padded: :func:`coarsen`)."""
    shape = tuple(-(-int(n) // factor) for n in grid.shape)
    return np.asarray(grid.frame, np.float64), np.asarray(grid.origin, np.float64), float(grid.h) * factor, shape


def warm_guess(prev, prev_grid, grid, factor: int) -> tuple[np.ndarray | None, str]:
    """An initial guess for the diffusion solve on ``grid`` (coarsened by ``factor``) from an
    earlier solve ``prev`` (a DiffusionResult) on ``prev_grid``: (phi or None, why).

    The same geometry (frame, origin, cell size, shape): prev.phi itself. A moved or resized
    grid (the light turned, the medium moved or grew, so its domain's crop changed): prev.phi
    resampled trilinearly at the new cell centres (clamped to its edge value within its outer
    half cell, 0 outside), O(cells) in NumPy. Any guess gives the same answer within the
    tolerance (:func:`pcg`); a poor one only costs iterations."""
    if prev is None or prev_grid is None:
        return None, "cold: no previous diffusion solve for this light"
    frame, origin, H, shape = grid_geometry(grid, factor)
    pframe, porigin, pH, _ = grid_geometry(prev_grid, prev.factor)
    if (tuple(prev.phi.shape) == shape and np.array_equal(frame, pframe) and np.array_equal(origin, porigin)
            and H == pH):
        return prev.phi, "warm"
    return resample_grid(prev.phi, pframe, porigin, pH, frame, origin, H, shape), "warm: resampled (grid moved or resized)"


def fill_gaps(x, mask, rounds: int = 8) -> np.ndarray:
    """float32 copy of the guess ``x`` with its zeros in the region ``mask`` (cells that joined
    the region since the guess was solved: there the previous solve left 0) set, layer by layer
    from their known neighbours inwards, to the mean of their region neighbours already known
    (at most ``rounds`` layers; cells farther in stay 0), and 0 outside the region. A cell
    that joins a region of fluence phi with 0 in it makes a residual of about G phi in every
    neighbour, far above ||b|| where D is large; with the gap filled, the sun's domain of the
    procedural cumulus (64 cells) a 24th of a second later needs 46 conjugate-gradient
    iterations instead of 63 (cold: 67). Only a guess: the answer does not depend on it."""
    x = np.where(mask, x, 0.0).astype(np.float32)
    unknown = mask & (x == 0.0)
    for _ in range(rounds):
        if not unknown.any():
            break
        known = mask & ~unknown
        total = np.zeros(x.shape, np.float64)
        count = np.zeros(x.shape, np.int32)
        for axis in range(3):
            n = x.shape[axis]
            if n < 2:
                continue
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[axis], hi[axis] = slice(0, n - 1), slice(1, n)
            lo, hi = tuple(lo), tuple(hi)
            total[lo] += np.where(known[hi], x[hi], 0.0)      # the neighbour at +1
            count[lo] += known[hi]
            total[hi] += np.where(known[lo], x[lo], 0.0)      # the neighbour at -1
            count[hi] += known[lo]
        new = unknown & (count > 0)
        if not new.any():
            break
        x[new] = (total[new] / count[new]).astype(np.float32)
        unknown &= ~new
    return x


def resample_grid(src, src_frame, src_origin, src_h, frame, origin, h, shape) -> np.ndarray:
    """float32 ``shape``: the field ``src`` of a rectilinear grid (rows of ``src_frame`` its
    axes, corner ``src_origin``, cells ``src_h``) sampled trilinearly at the cell centres of
    another (centres at integer index; clamped to the edge value within the outer half cell, 0
    outside, as kernels/sampling.trilinear)."""
    # continuous index in src of each centre: (q + 0.5) h frame, less src_origin, along src_frame
    # over src_h (no BLAS call on the cells: domains.frame_to_world)
    src_frame = np.asarray(src_frame, np.float64)
    M = np.asarray(frame, np.float64) @ src_frame.T * (h / src_h)
    b = (np.asarray(origin, np.float64) - src_origin) @ src_frame.T / src_h - 0.5
    q = np.indices(shape, np.float64).reshape(3, -1)
    x = (frame_to_world(M, q + 0.5) + b[:, None]).T
    n = np.array(src.shape)
    inside = np.all((x >= -0.5) & (x <= n - 0.5), axis=1)
    x = np.clip(x, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(x).astype(np.int64), np.maximum(n - 2, 0))
    f = x - i0
    i1 = np.minimum(i0 + 1, n - 1)
    out = np.zeros(len(x))
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                w = ((f[:, 0] if cx else 1 - f[:, 0]) * (f[:, 1] if cy else 1 - f[:, 1])
                     * (f[:, 2] if cz else 1 - f[:, 2]))
                out += w * src[(i1 if cx else i0)[:, 0], (i1 if cy else i0)[:, 1], (i1 if cz else i0)[:, 2]]
    return np.where(inside, out, 0.0).reshape(shape).astype(np.float32)
