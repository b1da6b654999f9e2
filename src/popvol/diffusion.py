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

from .kernels import diffusion as K


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
    n = [-(-s // factor) * factor for s in x.shape]
    pad = np.zeros(n)
    pad[: x.shape[0], : x.shape[1], : x.shape[2]] = x
    b = pad.reshape(n[0] // factor, factor, n[1] // factor, factor, n[2] // factor, factor).sum(axis=(1, 3, 5))
    return b if how == "sum" else b / factor ** 3


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
                    factor: int = 1) -> DiffusionResult:
    """Diffuse light of a domain from its handed-over power Q0 and moment Q1 (float32, [W]).

    ``factor`` > 1 solves on a grid of factor^3-cell blocks (powers summed, sigma_t, sigma_s
    averaged, g averaged weighted by sigma_s): diffuse light is smooth, and the cost falls by
    about factor^4 (factor^3 cells, factor times fewer conjugate-gradient iterations).
    """
    if factor > 1:
        ss = coarsen(sigma_s, factor, "mean")
        g = np.divide(coarsen(sigma_s * g, factor, "mean"), ss, out=np.zeros_like(ss), where=ss > 0)
        sigma_t, sigma_s = coarsen(sigma_t, factor, "mean"), ss
        Q0, Q1 = coarsen(Q0, factor), coarsen(Q1, factor)
        h = h * factor
    D, sah3, mask = coefficients(sigma_t, sigma_s, g, h)
    b = source(Q0, Q1, D, mask, h)
    b[~mask] = 0.0
    bw = boundary_weight(mask)
    x, it, res = pcg(D, sah3, mask, h, b, rtol, max_iterations or 20 * max(b.shape) + 200, bw)
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


def pcg(D, sah3, mask, h, b, rtol, max_iterations, bw=None):
    """Jacobi-preconditioned conjugate gradients for A x = b. Returns (x, iterations, ||r||/||b||).
    Vectors are float32 when rtol >= 1e-6 (half the memory traffic; sums stay float64), float64
    for tighter tolerances. ``bw``: the boundary weights (None: 1, the staircase's own area)."""
    if bw is None:
        bw = np.ones(b.shape, np.float32)
    dtype = np.float32 if rtol >= 1e-6 else np.float64
    x = np.zeros(b.shape, dtype)
    bn = math.sqrt(K.dot(b, b))
    if bn == 0.0:
        return x, 0, 0.0
    M = np.empty(b.shape, dtype)
    K.diagonal(D, sah3, mask, h, M, bw)
    r = b.astype(dtype)
    z = r / M
    p = z.copy()
    Ap = np.empty(b.shape, dtype)
    rz = K.dot(r, z)
    rr = K.dot(r, r)
    it = 0
    while math.sqrt(rr) > rtol * bn and it < max_iterations:
        K.apply(p, D, sah3, mask, h, Ap, bw)
        alpha = rz / K.dot(p, Ap)
        rz_new, rr = K.cg_update(x, r, p, Ap, M, alpha, z)
        K.cg_direction(p, z, rz_new / rz)
        rz = rz_new
        it += 1
    return x, it, math.sqrt(rr) / bn
