"""Numba kernels: the per-cell arrays of a light's rectilinear domain (n_d, n_u, n_v) that the
walk reads and leaves, each made in one pass over the cells and written into arrays the
caller allocates, so that a domain of millions of cells costs no temporaries (the NumPy
expressions they replace made five to ten domain-sized float64 temporaries each).

- :func:`rates`: a cell's absorption and decay rates, which the others and the spherical
  domain's faces (kernels/spherical.py) build on;
- :func:`medium_factors`: the half-step transmittance and anisotropy decay (see
  kernels/propagation.py; supplement Sec. 1.3 and Eq. 12);
- :func:`handover_factor`: the share of a lobe's first moment a cell removes (docs/METHOD.md,
  "Hand-over", Eq. 17);
- :func:`direct_fluence`: the unscattered light of a sun at the cell centres (Eq. 22);
- :func:`edge_factors`: a half step's factors over an edge of the cube lattice, sqrt 2 cells
  long (the eighteen-ordinate walk, kernels/ordinates18.py);
- :func:`hand_over_pending`: the packets still pending in the diffusion region when the walk
  stops go to the diffusion stage;
- :func:`face_neighbour`, :func:`cell_along`: the cell across one of a cell's six faces (the
  diffusion stage's stencil and the six-ordinate walk's steps), or m cells that way (the
  six-ordinate walk's crossing of a run of skipped cells);
- :func:`skip_runs`: those runs.

The arithmetic is float64, the arrays float32. NumPy twins: tests/twins.py (medium_factors,
handover_factor, direct_fluence, hand_over_pending); :func:`edge_factors`'s is ``np.power``.
"""
import math

import numba as nb
import numpy as np

from .reduction import ordered_sum


#: the decay rate standing for g <= 0 with the ``paper`` decay (g^x = 0 for any x > 0)
STOPPED = 1e30


@nb.njit(inline="always", cache=True)
def cell_along(k, i, j, n, m):
    """The cell ``m`` cells from cell (k, i, j) across its face ``n``, faces in the order +k,
    -k, +i, -i, +j, -j (a rectilinear domain's +d, -d, +u, -u, +v, -v); it may lie outside the
    grid."""
    step = m * (1 - 2 * (n % 2))
    if n < 2:
        return k + step, i, j
    if n < 4:
        return k, i + step, j
    return k, i, j + step


@nb.njit(inline="always", cache=True)
def face_neighbour(k, i, j, n):
    """The cell across face ``n`` of cell (k, i, j) (:func:`cell_along`, one cell)."""
    return cell_along(k, i, j, n, 1)


@nb.njit(inline="always", fastmath=True, cache=True)
def rates(sigma_t, sigma_s, g, k, i, j, paper):
    """Cell (k, i, j)'s absorption and decay rates per unit length (a, d), so that a half step
    of length s has T = exp(-a s / 2) and D = exp(-d s / 2): a = sigma_a = max(sigma_t -
    sigma_s, 0), d = sigma_s (1 - g) (the ``poisson`` decay: E[g^n], n ~ Poisson(sigma_s s)), or
    with the ``paper`` decay (D = g^(sigma_s s / 2), supplement Eq. 12) d = -sigma_s ln g,
    STOPPED for g <= 0. With the poisson decay a + d is sigma_tr, the rate at which a lobe's
    first moment is lost. Shared by the rectilinear domains' kernels here and the spherical
    domain's faces (kernels/spherical.py)."""
    st = np.float64(sigma_t[k, i, j])
    ss = np.float64(sigma_s[k, i, j])
    if ss == 0.0:
        return max(st, 0.0), 0.0
    gg = np.float64(g[k, i, j])
    if paper:
        return max(st - ss, 0.0), (-ss * math.log(gg) if gg > 0.0 else STOPPED)
    return max(st - ss, 0.0), ss * (1.0 - gg)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def medium_factors(sigma_t, sigma_s, g, h, paper, Th, Dh):
    """Th = exp(-a h / 2) and Dh = exp(-d h / 2) per cell, (a, d) its :func:`rates` (so Dh =
    g^(sigma_s h / 2) with the ``paper`` decay, exp(-sigma_s h (1 - g) / 2) with the
    ``poisson`` one), of float32 (n_d, n_u, n_v) sigma_t, sigma_s and g, into Th and Dh of that
    shape; h: the step length. A rate of 0 (an empty cell) gives 1 without an exp."""
    n0, n1, n2 = sigma_t.shape
    for k in nb.prange(n0):
        for i in range(n1):
            for j in range(n2):
                a, d = rates(sigma_t, sigma_s, g, k, i, j, paper)
                Th[k, i, j] = math.exp(-0.5 * h * a) if a > 0.0 else 1.0
                Dh[k, i, j] = math.exp(-0.5 * h * d) if d > 0.0 else 1.0


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def handover_factor(sigma_t, sigma_s, g, s, out):
    """out = 1 - exp(-sigma_tr s), sigma_tr = a + d of the poisson :func:`rates` (sigma_a +
    sigma_s (1 - g)), per cell of float32 (n_d, n_u, n_v) sigma_t, sigma_s and g (s: the
    cell's step length); 0 outside the diffusion region (sigma_s = 0 or sigma_t = 0)."""
    n0, n1, n2 = sigma_t.shape
    for k in nb.prange(n0):
        for i in range(n1):
            for j in range(n2):
                out[k, i, j] = 0.0
                if sigma_s[k, i, j] > 0.0 and sigma_t[k, i, j] > 0.0:
                    a, d = rates(sigma_t, sigma_s, g, k, i, j, False)
                    out[k, i, j] = -math.expm1(-(a + d) * s)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def direct_fluence(sigma_t, h, out):
    """out = exp(-tau) per cell of float32 (n_d, n_u, n_v) sigma_t, tau = h (sum over j < k of
    sigma_t,j + sigma_t,k / 2) from the face k = 0 to the centre of cell k (Eq. 22; sigma_t
    piecewise constant, cells of length h along the light). Each row u is one thread's, its
    depths summed along k in order."""
    n0, n1, n2 = sigma_t.shape
    for i in nb.prange(n1):
        cum = np.zeros(n2)                  # sum over the cells before k of sigma_t h / 2
        for k in range(n0):
            for j in range(n2):
                half = np.float64(sigma_t[k, i, j]) * (0.5 * h)
                c = cum[j] + half
                out[k, i, j] = math.exp(-(2.0 * c - half))
                cum[j] = c


@nb.njit(parallel=True, cache=True, nogil=True)
def edge_factors(x, e, out):
    """out = x ** e elementwise, float32 (any shape, C-ordered, as ``x``), e float32: a
    half step's factor over a path e times as long (T^e, with T = exp(-c h / 2)); where x is 1
    (a cell without medium, most of a domain) so is out, without the power. The C library's
    powf (``np.power(x, e)``'s bits where NumPy calls it; NumPy's AVX-512 loop can differ from
    it by one float32 ulp)."""
    xf = x.ravel()
    of = out.ravel()
    for i in nb.prange(xf.size):
        v = xf[i]
        of[i] = v if v == 1.0 else v ** e


@nb.njit(parallel=True, cache=True, nogil=True)
def hand_over_pending(W, Wa, Th, Dh, diffusive, Q):
    """When the sweeps stop, each packet (W, Wa) pending where ``diffusive`` > 0 takes its cell's
    half step (power W Th, moment Wa Th Dh), is added to Q[0], Q[1] and is zeroed; float32
    (n_d, n_u, n_v) arrays, Q (2, n_d, n_u, n_v). Returns the power the half steps absorbed,
    sum of W (1 - Th), summed per slice k and then in order (kernels/reduction.py). Not
    fastmath: Q gets the products in the twin's order."""
    n0, n1, n2 = W.shape
    part = np.zeros(n0)
    for k in nb.prange(n0):
        absorbed = 0.0
        for i in range(n1):
            for j in range(n2):
                if diffusive[k, i, j] > 0.0:
                    w = np.float64(W[k, i, j])
                    th = np.float64(Th[k, i, j])
                    Q[0, k, i, j] += np.float32(w * th)
                    Q[1, k, i, j] += np.float32(np.float64(Wa[k, i, j]) * th * np.float64(Dh[k, i, j]))
                    W[k, i, j] = 0.0
                    Wa[k, i, j] = 0.0
                    absorbed += w * (1.0 - th)
        part[k] = absorbed
    return ordered_sum(part)


#: the longest run an entry of :func:`skip_runs` can hold (int16): no domain axis may be longer
MAX_RUN = 32767


@nb.njit(cache=True)
def _runs_along(skip, ahead, behind):
    """Along one line of cells (1-D views): ahead[x], behind[x] = how many cells in a row from x
    toward higher, lower x are skipped (``skip``), x included; 0 if x is not."""
    n = skip.shape[0]
    r = 0
    for x in range(n - 1, -1, -1):
        r = r + 1 if skip[x] else 0
        ahead[x] = r
    r = 0
    for x in range(n):
        r = r + 1 if skip[x] else 0
        behind[x] = r


@nb.njit(parallel=True, cache=True, nogil=True)
def skip_runs(skip, runs):
    """runs int16 (6, n_d, n_u, n_v): at a cell where ``skip`` (bool (n_d, n_u, n_v)), how
    many cells in a row from it across face o (o in :func:`cell_along`'s order, itself
    included) are skipped; 0 where it is not skipped. No axis may be longer than MAX_RUN.
    Lines along d are the threads' by row u, lines along u and v by slice k."""
    n0, n1, n2 = skip.shape
    for i in nb.prange(n1):
        for j in range(n2):
            _runs_along(skip[:, i, j], runs[0, :, i, j], runs[1, :, i, j])
    for k in nb.prange(n0):
        for j in range(n2):
            _runs_along(skip[k, :, j], runs[2, k, :, j], runs[3, k, :, j])
        for i in range(n1):
            _runs_along(skip[k, i, :], runs[4, k, i, :], runs[5, k, i, :])
