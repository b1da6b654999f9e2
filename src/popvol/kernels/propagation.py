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
Split table (see hg.split_fractions / conditional_mean_cosines), rows:
  0 front, 1 each side, 2 back share of HG_a;  3, 4, 5 their conditional mean cosines;
  sampled at a = -1 .. 1 (linear interpolation).
Outgoing anisotropy: rule `moment` -> the part's conditional mean cosine times the decay;
rule `paper` -> every part keeps a times the decay.

Budget tallies (float64 (4,)): [reflected (out through the face k = 0, toward the light),
transmitted (out through k = n_d - 1), side (out through the 4 lateral faces), absorbed].
"""
import numba as nb
import numpy as np

FRONT, SIDE, BACK = 0, 1, 2
REFLECTED, TRANSMITTED, SIDE_ESCAPED, ABSORBED = 0, 1, 2, 3


@nb.njit(inline="always", fastmath=True, cache=True)
def lookup(table, row, a):
    """Linear interpolation of ``table[row]`` sampled uniformly on a in [-1, 1]."""
    n = table.shape[1]
    x = (a + 1.0) * 0.5 * (n - 1)
    if x < 0.0:
        x = 0.0
    if x > n - 1.0:
        x = n - 1.0
    i0 = int(x)
    if i0 > n - 2:
        i0 = n - 2
    f = x - i0
    return table[row, i0] + f * (table[row, i0 + 1] - table[row, i0])


@nb.njit(inline="always", fastmath=True, cache=True)
def part(table, w, wa, part_id, moment):
    """Share of packet (w, w*a) sent into one neighbour of kind ``part_id``.

    Returns (energy, energy * outgoing anisotropy) before transmittance and decay.
    """
    a = wa / w
    frac = lookup(table, part_id, a)
    e = w * frac
    if moment:
        return e, e * lookup(table, 3 + part_id, a)
    return e, e * a


@nb.njit(inline="always", cache=True)
def _wrap(i, n):
    if i < 0:
        return i + n
    if i >= n:
        return i - n
    return i


@nb.njit(parallel=True, fastmath=True, cache=True)
def jacobi_step(W, Wa, Th, Dh, table, moment, periodic, inv_area, W_out, Wa_out, phi, phia):
    """One wavefront iteration: accumulate the current wave, then gather the next one.

    Every destination cell gathers from its 6 face neighbours (supplement Eq. 9), so the loop
    is race-free. Returns (energy now in flight, energy absorbed in interior transfers).
    Escapes through the boundary are counted by :func:`boundary_escape` on the same wave.
    """
    n0, n1, n2 = W.shape
    in_flight = 0.0
    absorbed = 0.0
    for kk in nb.prange(n0):
        k = np.int64(kk)   # prange indices are unsigned; k - 1 must stay an integer
        for i in range(n1):
            for j in range(n2):
                w = W[k, i, j]
                if w > 0.0:
                    phi[k, i, j] += w * inv_area
                    phia[k, i, j] += Wa[k, i, j] * inv_area
                thc = Th[k, i, j]
                dhc = Dh[k, i, j]
                e_sum = 0.0
                ea_sum = 0.0
                for nbr in range(6):
                    ks, is_, js = k, i, j
                    pid = SIDE
                    if nbr == 0:
                        ks = k - 1      # the cell behind sends its front part
                        pid = FRONT
                    elif nbr == 1:
                        ks = k + 1      # the cell in front sends its back part
                        pid = BACK
                    elif nbr == 2:
                        is_ = i - 1
                    elif nbr == 3:
                        is_ = i + 1
                    elif nbr == 4:
                        js = j - 1
                    else:
                        js = j + 1
                    if ks < 0 or ks >= n0:
                        continue
                    if periodic:
                        is_ = _wrap(is_, n1)
                        js = _wrap(js, n2)
                    elif is_ < 0 or is_ >= n1 or js < 0 or js >= n2:
                        continue
                    w_src = W[ks, is_, js]
                    if w_src <= 0.0:
                        continue
                    e, ea = part(table, w_src, Wa[ks, is_, js], pid, moment)
                    t = Th[ks, is_, js] * thc
                    e_sum += e * t
                    ea_sum += ea * t * Dh[ks, is_, js] * dhc
                    absorbed += e * (1.0 - t)
                W_out[k, i, j] = e_sum
                Wa_out[k, i, j] = ea_sum
                in_flight += e_sum
    return in_flight, absorbed


@nb.njit(fastmath=True, cache=True)
def boundary_escape(W, Wa, Th, table, moment, periodic, tally):
    """Add to ``tally`` what the wave (W, Wa) sends out of the domain, and what is absorbed on
    the last half cell before the boundary (T = Th of the boundary cell)."""
    n0, n1, n2 = W.shape
    for face in range(2):                       # k = 0 (back part) and k = n0 - 1 (front part)
        k = 0 if face == 0 else n0 - 1
        pid = BACK if face == 0 else FRONT
        slot = REFLECTED if face == 0 else TRANSMITTED
        for i in range(n1):
            for j in range(n2):
                w = W[k, i, j]
                if w > 0.0:
                    e, ea = part(table, w, Wa[k, i, j], pid, moment)
                    tally[slot] += e * Th[k, i, j]
                    tally[ABSORBED] += e * (1.0 - Th[k, i, j])
    if periodic:
        return
    for k in range(n0):
        for i in range(n1):
            if i == 0 or i == n1 - 1:
                for j in range(n2):
                    _escape_sideways(W, Wa, Th, table, moment, k, i, j, tally)
            else:   # interior rows touch the lateral boundary only at j = 0 and j = n2 - 1
                _escape_sideways(W, Wa, Th, table, moment, k, i, 0, tally)
                if n2 > 1:
                    _escape_sideways(W, Wa, Th, table, moment, k, i, n2 - 1, tally)


@nb.njit(inline="always", fastmath=True, cache=True)
def _escape_sideways(W, Wa, Th, table, moment, k, i, j, tally):
    n0, n1, n2 = W.shape
    missing = (i == 0) + (i == n1 - 1) + (j == 0) + (j == n2 - 1)
    w = W[k, i, j]
    if w > 0.0 and missing > 0:
        e, ea = part(table, w, Wa[k, i, j], SIDE, moment)
        tally[SIDE_ESCAPED] += missing * e * Th[k, i, j]
        tally[ABSORBED] += missing * e * (1.0 - Th[k, i, j])


@nb.njit(parallel=True, fastmath=True, cache=True)
def _send_slice(R, Ra, Th, Dh, table, moment, periodic, k, inv_area, phi, phia, S, Sa):
    """Sweep pass 1 on slice k: every cell sends its pending packet. Front and back parts go
    straight into slices k +- 1 (one writer per cell: race-free); side parts are parked in
    (S, Sa) for pass 2. Returns (reflected, transmitted, side escaped, absorbed)."""
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
            thc = Th[k, i, j]
            dhc = Dh[k, i, j]
            # front part -> k + 1
            e, ea = part(table, w, wa, FRONT, moment)
            if k + 1 < n0:
                t = thc * Th[k + 1, i, j]
                R[k + 1, i, j] += e * t
                Ra[k + 1, i, j] += ea * t * dhc * Dh[k + 1, i, j]
                absorbed += e * (1.0 - t)
            else:
                trans += e * thc
                absorbed += e * (1.0 - thc)
            # back part -> k - 1
            e, ea = part(table, w, wa, BACK, moment)
            if k > 0:
                t = thc * Th[k - 1, i, j]
                R[k - 1, i, j] += e * t
                Ra[k - 1, i, j] += ea * t * dhc * Dh[k - 1, i, j]
                absorbed += e * (1.0 - t)
            else:
                refl += e * thc
                absorbed += e * (1.0 - thc)
            # side parts (one per lateral neighbour)
            e, ea = part(table, w, wa, SIDE, moment)
            S[i, j] = e
            Sa[i, j] = ea
            if not periodic:
                missing = (i == 0) + (i == n1 - 1) + (j == 0) + (j == n2 - 1)
                side_out += missing * e * thc
                absorbed += missing * e * (1.0 - thc)
    return refl, trans, side_out, absorbed


@nb.njit(parallel=True, fastmath=True, cache=True)
def _gather_sides(R, Ra, Th, Dh, periodic, k, S, Sa):
    """Sweep pass 2 on slice k: every cell gathers the side parts its 4 lateral neighbours
    parked in pass 1. They stay pending in slice k until its next visit. Returns absorbed."""
    n0, n1, n2 = R.shape
    absorbed = 0.0
    for ii in nb.prange(n1):
        i = np.int64(ii)
        for j in range(n2):
            thc = Th[k, i, j]
            dhc = Dh[k, i, j]
            e_sum = 0.0
            ea_sum = 0.0
            for nbr in range(4):
                is_, js = i, j
                if nbr == 0:
                    is_ = i - 1
                elif nbr == 1:
                    is_ = i + 1
                elif nbr == 2:
                    js = j - 1
                else:
                    js = j + 1
                if periodic:
                    is_ = _wrap(is_, n1)
                    js = _wrap(js, n2)
                elif is_ < 0 or is_ >= n1 or js < 0 or js >= n2:
                    continue
                s = S[is_, js]
                if s <= 0.0:
                    continue
                t = Th[k, is_, js] * thc
                e_sum += s * t
                ea_sum += Sa[is_, js] * t * Dh[k, is_, js] * dhc
                absorbed += s * (1.0 - t)
            if e_sum > 0.0:
                R[k, i, j] += e_sum
                Ra[k, i, j] += ea_sum
    return absorbed


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
        refl, trans, side_out, absorbed = _send_slice(R, Ra, Th, Dh, table, moment, periodic, k,
                                                      inv_area, phi, phia, S, Sa)
        absorbed += _gather_sides(R, Ra, Th, Dh, periodic, k, S, Sa)
        tally[REFLECTED] += refl
        tally[TRANSMITTED] += trans
        tally[SIDE_ESCAPED] += side_out
        tally[ABSORBED] += absorbed
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
