"""Numba kernels of the diffusion stage (see popvol/diffusion.py for the equations).

Finite volumes on a light domain (cells of size h). Unknown: fluence phi [W/m^2] in the cells of
the diffusion region (``mask``). Balance of cell p, in watts:

    sum_q G_pq (phi_p - phi_q) + sum_b G_b phi_p + sigma_a h^3 phi_p = b_p

G_pq = h * 2 D_p D_q / (D_p + D_q) between two region cells (face area h^2 over distance h,
harmonic mean of D = 1 / (3 sigma_tr)); G_b = bw_p * h^2 * 2 D_p / (4 D_p + h) through a face to
the outside of the region (domain boundary or a cell outside the region): the Marshak condition
J = phi_face / 2 (no light enters) with Fick's law over the half cell to the face. bw_p (<= 1,
see diffusion.boundary_weight) makes the staircase of cell faces leak through the area of the
smooth surface it approximates, not through its own (up to sqrt(3) times larger) area.
The matrix is symmetric positive definite. The conjugate gradients run on the region's cells
alone (diffusion.RowSpace): :func:`region_rows` stores each region cell's diagonal, its six
neighbours' rows and the faces' conductances once per solve, and :func:`apply_rows` applies A
from them (often a fifth of the domain's cells are in the region, and no conductance is
computed again per product).

NumPy twin of boundary_weight: tests/twins.py; A itself is checked against an assembled sparse
matrix and a direct solve (tests/test_diffusion.py).
"""
import math

import numba as nb
import numpy as np

from .cells import face_neighbour
from .reduction import ordered_sum, row_dot


@nb.njit(inline="always", fastmath=True, cache=True)
def g_face(Dp, Dq, h):
    return h * 2.0 * Dp * Dq / (Dp + Dq)


@nb.njit(inline="always", fastmath=True, cache=True)
def g_boundary(Dp, h):
    return h * h * 2.0 * Dp / (4.0 * Dp + h)


@nb.njit(fastmath=True, cache=True, nogil=True)
def region_rows(D, sah3, mask, h, bw, cells, index, nbr, G, diag):
    """The rows of A at the region's cells, for :func:`apply_rows`: row m is cell cells[m] (a
    flat C-order index of the grid); ``index`` int32 (grid shape) holds each region cell's row
    (-1 elsewhere). Writes nbr int32 (n, 6), the row of the region neighbour across each face
    (in :func:`cells.face_neighbour`'s order; -1 where the neighbour is outside the grid or the region),
    G float64 (n, 6), that face's conductance (0 where there is none), and diag float64 (n,),
    A's diagonal: sigma_a h^3, then face by face G_pq or the boundary's w_p G_b (docs/METHOD.md
    Eq. 19). Once per solve."""
    n0, n1, n2 = D.shape
    for m in range(cells.shape[0]):
        c = cells[m]
        k = c // (n1 * n2)
        i = (c // n2) % n1
        j = c % n2
        Dp = D[k, i, j]
        d = np.float64(sah3[k, i, j])
        for nbh in range(6):
            kq, iq, jq = face_neighbour(k, i, j, nbh)
            if 0 <= kq < n0 and 0 <= iq < n1 and 0 <= jq < n2 and mask[kq, iq, jq]:
                g = g_face(Dp, D[kq, iq, jq], h)
                d += g
                nbr[m, nbh] = index[kq, iq, jq]
                G[m, nbh] = g
            else:
                d += g_boundary(Dp, h) * bw[k, i, j]
                nbr[m, nbh] = -1
                G[m, nbh] = 0.0
        diag[m] = d


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def apply_rows(x, nbr, G, diag, out):
    """out = A x on the region's rows (:func:`region_rows`): x, out float32/64 vectors
    (rows, 1, L) whose first n entries in C order are the rows (the rest padding, left as they
    are); per row diag x_p - the sum over its region neighbours q of G_pq x_q, in face order
    (docs/METHOD.md Eq. 19)."""
    xf = x.reshape(-1)
    of = out.reshape(-1)
    for m in nb.prange(diag.shape[0]):
        acc = 0.0
        for f in range(6):
            q = nbr[m, f]
            if q >= 0:
                acc += G[m, f] * xf[q]
        of[m] = diag[m] * xf[m] - acc


@nb.njit(parallel=True, fastmath=False, cache=True, nogil=True)
def dot(a, b):
    """a . b of two 3-D arrays, in float64, summed in a fixed order (kernels/reduction.py; not
    fastmath, so that compiled and cached code agree)."""
    part = np.empty(a.shape[0])
    for kk in nb.prange(a.shape[0]):
        k = np.int64(kk)
        s = 0.0
        for i in range(a.shape[1]):
            s += row_dot(a, b, k, i)
        part[k] = s
    return ordered_sum(part)


@nb.njit(parallel=True, fastmath=False, cache=True, nogil=True)
def cg_update(x, r, p, Ap, M, alpha, z):
    """x += alpha p; r -= alpha Ap; z = r / M. Returns (r . z, r . r), summed as :func:`dot`."""
    part = np.empty((2, x.shape[0]))
    for kk in nb.prange(x.shape[0]):
        k = np.int64(kk)
        rz = 0.0
        rr = 0.0
        for i in range(x.shape[1]):
            for j in range(x.shape[2]):
                x[k, i, j] += alpha * p[k, i, j]
                rv = r[k, i, j] - alpha * Ap[k, i, j]
                r[k, i, j] = rv
                z[k, i, j] = rv / M[k, i, j]
            rz += row_dot(r, z, k, i)
            rr += row_dot(r, r, k, i)
        part[0, k] = rz
        part[1, k] = rr
    return ordered_sum(part[0]), ordered_sum(part[1])


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def cg_direction(p, z, beta):
    """p = z + beta p."""
    for kk in nb.prange(p.shape[0]):
        k = np.int64(kk)
        for i in range(p.shape[1]):
            for j in range(p.shape[2]):
                p[k, i, j] = z[k, i, j] + beta * p[k, i, j]


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def leaks(phi, D, mask, h, bw):
    """Power [W] leaving the region: (through face k = 0, through k = n_d - 1, through the 4
    lateral faces of the domain, into cells outside the region)."""
    n0, n1, n2 = phi.shape
    part = np.zeros((4, n0))
    for kk in nb.prange(n0):
        k = np.int64(kk)
        r = 0.0
        t = 0.0
        s = 0.0
        o = 0.0
        for i in range(n1):
            for j in range(n2):
                if not mask[k, i, j]:
                    continue
                g = g_boundary(D[k, i, j], h) * bw[k, i, j] * phi[k, i, j]
                for nbh in range(6):
                    kq, iq, jq = face_neighbour(k, i, j, nbh)
                    if kq < 0:
                        r += g
                    elif kq >= n0:
                        t += g
                    elif iq < 0 or iq >= n1 or jq < 0 or jq >= n2:
                        s += g
                    elif not mask[kq, iq, jq]:
                        o += g
        part[0, k] = r
        part[1, k] = t
        part[2, k] = s
        part[3, k] = o
    return ordered_sum(part[0]), ordered_sum(part[1]), ordered_sum(part[2]), ordered_sum(part[3])


BINOMIAL = (0.0625, 0.25, 0.375, 0.25, 0.0625)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _binomial(src, dst, axis):
    """dst = src filtered by [1 4 6 4 1] / 16 along ``axis`` (zero outside the grid)."""
    n0, n1, n2 = src.shape
    n = src.shape[axis]
    for kk in nb.prange(n0):
        k = np.int64(kk)
        for i in range(n1):
            for j in range(n2):
                c = k if axis == 0 else (i if axis == 1 else j)
                acc = 0.0
                for t in range(5):
                    q = c + t - 2
                    if q < 0 or q >= n:
                        continue
                    if axis == 0:
                        acc += BINOMIAL[t] * src[q, i, j]
                    elif axis == 1:
                        acc += BINOMIAL[t] * src[k, q, j]
                    else:
                        acc += BINOMIAL[t] * src[k, i, q]
                dst[k, i, j] = acc


@nb.njit(inline="always", fastmath=True, cache=True)
def _gradient(m, k, i, j, axis):
    """np.gradient of m along axis at (k, i, j): central inside, one-sided at the edges."""
    n = m.shape[axis]
    if n < 2:
        return 0.0
    c = k if axis == 0 else (i if axis == 1 else j)
    lo = max(c - 1, 0)
    hi = min(c + 1, n - 1)
    if axis == 0:
        d = m[hi, i, j] - m[lo, i, j]
    elif axis == 1:
        d = m[k, hi, j] - m[k, lo, j]
    else:
        d = m[k, i, hi] - m[k, i, lo]
    return d / (hi - lo)


@nb.njit(fastmath=True, cache=True, nogil=True)
def boundary_weight(mask, out):
    """out float32 = 1 / |n|_1 of the region's smoothed surface in region cells (see
    diffusion.boundary_weight), 1 elsewhere."""
    src = mask.astype(np.float32)
    dst = np.empty_like(src)
    for axis in range(3):           # a variable axis: _binomial is compiled once, not per axis
        _binomial(src, dst, axis)
        src, dst = dst, src
    _weights(mask, src, out)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _weights(mask, m, out):
    n0, n1, n2 = m.shape
    for kk in nb.prange(n0):
        k = np.int64(kk)
        for i in range(n1):
            for j in range(n2):
                out[k, i, j] = 1.0
                if not mask[k, i, j]:
                    continue
                gx = _gradient(m, k, i, j, 0)
                gy = _gradient(m, k, i, j, 1)
                gz = _gradient(m, k, i, j, 2)
                l2 = math.sqrt(gx * gx + gy * gy + gz * gz)
                if l2 > 1e-6:
                    out[k, i, j] = l2 / (abs(gx) + abs(gy) + abs(gz))
