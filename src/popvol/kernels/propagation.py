"""Numba kernels of the propagation step (supplement Eq. 4, 7, 9, 12; METHOD.md step 4).

State per domain cell (k along the light, i, j across it):
  W   in-flight power [W] (a "packet"), Wa = W * a its energy-weighted anisotropy, so that the
      energy-weighted merge at a destination is a plain sum;
  phi accumulated fluence [W/m^2] (phi += W / h^2 per visit: a packet crossing a cubic cell
      of size h travels h, so phi += W h / h^3), phia = sum of W a / h^2.
Per-cell medium factors, precomputed (see propagate.py):
  Th = exp(-sigma_a h / 2): half-step transmittance, so T(src->dst) = Th[src] Th[dst] is
       exp(-sigma_a s) with sigma_a averaged over the two cells (supplement Sec. 1.3);
  Dh = half-step anisotropy decay: g^(sigma_s h / 2) (`paper`, Eq. 12) or
       exp(-sigma_s h (1 - g) / 2) (`poisson`); the decay src->dst is Dh[src] Dh[dst].
Split table (float64 (n, 8), see propagate.split_table), columns:
  0 front share, 1 share of EACH side, 2 back share of HG_a; 3, 4, 5 their conditional mean
  cosines; sampled at a = linspace(-1, 1, n), interpolated linearly. The kernels take the back
  share as 1 - front - 4 side, so the six shares sum to 1 to rounding (supplement Eq. 8).
Outgoing anisotropy: rule `moment` -> the part's conditional mean cosine times the decay;
rule `paper` -> every part keeps a times the decay.

Each transfer is split in two halves: the sender applies its own Th (and Dh) when it sends, the
receiver its own when it gathers. What leaves the domain crosses only the sender's half cell.
Budget tallies (float64 (4,)): [reflected (out through the face k = 0, toward the light),
transmitted (out through k = n_d - 1), side (out through the 4 lateral faces), absorbed].
"""
import numba as nb
import numpy as np

REFLECTED, TRANSMITTED, SIDE_ESCAPED, ABSORBED = 0, 1, 2, 3


@nb.njit(inline="always", fastmath=True, cache=True)
def split(table, w, wa, moment):
    """Split packet (w, w*a) into its parts (supplement Eq. 4, 7).

    Returns (front, front*a', side, side*a', back, back*a'): ``side`` is the share of ONE
    lateral neighbour, a' each part's outgoing anisotropy before decay.
    """
    a = wa / w
    n = table.shape[0]
    x = (a + 1.0) * 0.5 * (n - 1)
    x = min(max(x, 0.0), n - 1.0)
    i0 = min(int(x), n - 2)
    f = x - i0
    ef = w * (table[i0, 0] + f * (table[i0 + 1, 0] - table[i0, 0]))
    es = w * (table[i0, 1] + f * (table[i0 + 1, 1] - table[i0, 1]))
    eb = w - ef - 4.0 * es
    if moment:
        mf = table[i0, 3] + f * (table[i0 + 1, 3] - table[i0, 3])
        ms = table[i0, 4] + f * (table[i0 + 1, 4] - table[i0, 4])
        mb = table[i0, 5] + f * (table[i0 + 1, 5] - table[i0, 5])
        return ef, ef * mf, es, es * ms, eb, eb * mb
    return ef, ef * a, es, es * a, eb, eb * a


@nb.njit(inline="always", cache=True)
def _wrap(i, n):
    if i < 0:
        return i + n
    if i >= n:
        return i - n
    return i


# ---------------------------------------------------------------------------------------------
# Jacobi wavefront: every iteration moves every packet by exactly one cell.
# ---------------------------------------------------------------------------------------------

@nb.njit(parallel=True, fastmath=True, cache=True)
def jacobi_send(W, Wa, Th, Dh, table, moment, periodic, inv_area, phi, phia, out, tally):
    """Accumulate the current wave into (phi, phia) and split every packet.

    ``out`` float32 (6, n_d, n_u, n_v) receives the parts after the sender's half step:
    0 front, 1 front*a', 2 side (each), 3 side*a', 4 back, 5 back*a'. Parts that leave the
    domain are tallied; so is what the sender's half step absorbs.
    """
    n0, n1, n2 = W.shape
    refl = 0.0
    trans = 0.0
    side_out = 0.0
    absorbed = 0.0
    for kk in nb.prange(n0):
        k = np.int64(kk)   # prange indices are unsigned; keep k - 1 an integer
        for i in range(n1):
            for j in range(n2):
                w = W[k, i, j]
                if w <= 0.0:
                    for p in range(6):
                        out[p, k, i, j] = 0.0
                    continue
                wa = Wa[k, i, j]
                phi[k, i, j] += w * inv_area
                phia[k, i, j] += wa * inv_area
                ef, efa, es, esa, eb, eba = split(table, w, wa, moment)
                th = Th[k, i, j]
                thd = th * Dh[k, i, j]
                absorbed += w * (1.0 - th)
                out[0, k, i, j] = ef * th
                out[1, k, i, j] = efa * thd
                out[2, k, i, j] = es * th
                out[3, k, i, j] = esa * thd
                out[4, k, i, j] = eb * th
                out[5, k, i, j] = eba * thd
                if k == n0 - 1:
                    trans += ef * th
                if k == 0:
                    refl += eb * th
                if not periodic:
                    missing = (i == 0) + (i == n1 - 1) + (j == 0) + (j == n2 - 1)
                    side_out += missing * es * th
    tally[REFLECTED] += refl
    tally[TRANSMITTED] += trans
    tally[SIDE_ESCAPED] += side_out
    tally[ABSORBED] += absorbed


@nb.njit(parallel=True, fastmath=True, cache=True)
def jacobi_gather(parts, Th, Dh, periodic, W_out, Wa_out, tally):
    """Every cell gathers the parts its 6 neighbours sent toward it (supplement Eq. 9) and
    applies its own half step. Race-free (each cell writes only itself). Returns the energy
    now in flight."""
    _, n0, n1, n2 = parts.shape
    in_flight = 0.0
    absorbed = 0.0
    for kk in nb.prange(n0):
        k = np.int64(kk)
        for i in range(n1):
            for j in range(n2):
                e = 0.0
                ea = 0.0
                if k > 0:                       # the cell behind sends its front part
                    e += parts[0, k - 1, i, j]
                    ea += parts[1, k - 1, i, j]
                if k < n0 - 1:                  # the cell ahead sends its back part
                    e += parts[4, k + 1, i, j]
                    ea += parts[5, k + 1, i, j]
                for nbr in range(4):            # lateral neighbours send side parts
                    ii = i + (nbr == 0) - (nbr == 1)
                    jj = j + (nbr == 2) - (nbr == 3)
                    if periodic:
                        ii = _wrap(ii, n1)
                        jj = _wrap(jj, n2)
                    elif ii < 0 or ii >= n1 or jj < 0 or jj >= n2:
                        continue
                    e += parts[2, k, ii, jj]
                    ea += parts[3, k, ii, jj]
                th = Th[k, i, j]
                W_out[k, i, j] = e * th
                Wa_out[k, i, j] = ea * th * Dh[k, i, j]
                absorbed += e * (1.0 - th)
                in_flight += e * th
    tally[ABSORBED] += absorbed
    return in_flight


# ---------------------------------------------------------------------------------------------
# Gauss-Seidel sweeps: slice by slice along +d or -d.
# ---------------------------------------------------------------------------------------------

@nb.njit(parallel=True, fastmath=True, cache=True)
def _send_slice(R, Ra, Th, Dh, table, moment, periodic, k, inv_area, phi, phia, S, Sa, tally):
    """Sweep pass 1 on slice k: every cell sends its pending packet. Front and back parts go
    straight into slices k +- 1 (one writer per cell: race-free); side parts, after the
    sender's half step, are parked in (S, Sa) for pass 2."""
    n0, n1, n2 = R.shape
    refl = 0.0
    trans = 0.0
    side_out = 0.0
    absorbed = 0.0
    for ii in nb.prange(n1):
        i = np.int64(ii)
        for j in range(n2):
            w = R[k, i, j]
            if w <= 0.0:
                S[i, j] = 0.0
                Sa[i, j] = 0.0
                continue
            wa = Ra[k, i, j]
            R[k, i, j] = 0.0
            Ra[k, i, j] = 0.0
            phi[k, i, j] += w * inv_area
            phia[k, i, j] += wa * inv_area
            ef, efa, es, esa, eb, eba = split(table, w, wa, moment)
            th = Th[k, i, j]
            thd = th * Dh[k, i, j]
            absorbed += w * (1.0 - th)
            if k + 1 < n0:                      # front part -> slice k + 1
                t = Th[k + 1, i, j]
                R[k + 1, i, j] += ef * th * t
                Ra[k + 1, i, j] += efa * thd * t * Dh[k + 1, i, j]
                absorbed += ef * th * (1.0 - t)
            else:
                trans += ef * th
            if k > 0:                           # back part -> slice k - 1
                t = Th[k - 1, i, j]
                R[k - 1, i, j] += eb * th * t
                Ra[k - 1, i, j] += eba * thd * t * Dh[k - 1, i, j]
                absorbed += eb * th * (1.0 - t)
            else:
                refl += eb * th
            S[i, j] = es * th
            Sa[i, j] = esa * thd
            if not periodic:
                missing = (i == 0) + (i == n1 - 1) + (j == 0) + (j == n2 - 1)
                side_out += missing * es * th
    tally[REFLECTED] += refl
    tally[TRANSMITTED] += trans
    tally[SIDE_ESCAPED] += side_out
    tally[ABSORBED] += absorbed


@nb.njit(parallel=True, fastmath=True, cache=True)
def _gather_sides(R, Ra, Th, Dh, periodic, k, S, Sa, tally):
    """Sweep pass 2 on slice k: every cell gathers the side parts its 4 lateral neighbours
    parked in pass 1. They stay pending in slice k until its next visit."""
    n0, n1, n2 = R.shape
    absorbed = 0.0
    for ii in nb.prange(n1):
        i = np.int64(ii)
        for j in range(n2):
            e = 0.0
            ea = 0.0
            for nbr in range(4):
                is_ = i + (nbr == 0) - (nbr == 1)
                js = j + (nbr == 2) - (nbr == 3)
                if periodic:
                    is_ = _wrap(is_, n1)
                    js = _wrap(js, n2)
                elif is_ < 0 or is_ >= n1 or js < 0 or js >= n2:
                    continue
                e += S[is_, js]
                ea += Sa[is_, js]
            if e > 0.0:
                th = Th[k, i, j]
                R[k, i, j] += e * th
                Ra[k, i, j] += ea * th * Dh[k, i, j]
                absorbed += e * (1.0 - th)
    tally[ABSORBED] += absorbed


@nb.njit(fastmath=True, cache=True)
def sweep(R, Ra, Th, Dh, table, moment, periodic, forward, inv_area, phi, phia, S, Sa, tally):
    """One Gauss-Seidel sweep over the slices, along +d (``forward``) or -d.

    Pending packets (R, Ra) are sent slice by slice; a packet sent toward the slice visited
    next is sent again in the same sweep, so the direct light crosses the domain in one sweep.
    Energy is conserved exactly: every packet is sent once and only absorption and the
    boundary remove energy. Returns the energy still pending (in flight).
    """
    n0 = R.shape[0]
    for step in range(n0):
        k = step if forward else n0 - 1 - step
        _send_slice(R, Ra, Th, Dh, table, moment, periodic, k, inv_area, phi, phia, S, Sa, tally)
        _gather_sides(R, Ra, Th, Dh, periodic, k, S, Sa, tally)
    return total_energy(R)


@nb.njit(parallel=True, fastmath=True, cache=True)
def total_energy(x):
    """Sum of a 3-D float32 array in float64 (parallel over the first axis)."""
    total = 0.0
    for k in nb.prange(x.shape[0]):
        s = 0.0
        for i in range(x.shape[1]):
            for j in range(x.shape[2]):
                s += x[k, i, j]
        total += s
    return total
