"""Numba kernels of the propagation step (supplement Eq. 4, 7, 9, 12; docs/METHOD.md, "Walk").

State per domain cell (k along the light, i, j across it):
  W   in-flight power [W] (a "packet"), Wa = W * a its energy-weighted anisotropy, so that the
      energy-weighted merge at a destination is a plain sum;
  phi accumulated fluence [W/m^2] (phi += W / h^2 per visit: a packet crossing a cubic cell
      of size h travels h, so phi += W h / h^3), phia = sum of W a / h^2.
Per-cell medium factors, precomputed (see walk.medium_factors):
  Th = exp(-sigma_a h / 2): half-step transmittance, so T(src->dst) = Th[src] Th[dst] is
       exp(-sigma_a s) with sigma_a averaged over the two cells (supplement Sec. 1.3);
  Dh = half-step anisotropy decay: g^(sigma_s h / 2) (`paper`, Eq. 12) or
       exp(-sigma_s h (1 - g) / 2) (`poisson`); the decay src->dst is Dh[src] Dh[dst].
Split table (float64 (n, 8), see walk.split_table), columns:
  0 front share, 1 share of EACH side, 2 back share of HG_a; 3, 4, 5 their conditional mean
  cosines; sampled at a = linspace(-1, 1, n), interpolated linearly. The kernels take the back
  share as 1 - front - 4 side, so the six shares sum to 1 to rounding (supplement Eq. 8).
Outgoing anisotropy: rule `moment` -> the part's conditional mean cosine times the decay;
rule `paper` -> every part keeps a times the decay.

Each transfer is split in two halves: the sender applies its own Th (and Dh) when it sends, the
receiver its own when it gathers. What leaves the domain crosses only the sender's half cell.
Budget tallies (float64 (4,)): [reflected (out through the face k = 0, toward the light),
transmitted (out through k = n_d - 1), side (out through the 4 lateral faces), absorbed].

NumPy twins (exact HG splits, no table): tests/twins.py (jacobi_step, sweep, hand_over).
"""
import numba as nb
import numpy as np

from . import ON_ITS_OWN
from .reduction import add_parts, ordered_sum, row_sum

REFLECTED, TRANSMITTED, SIDE_ESCAPED, ABSORBED = 0, 1, 2, 3


@nb.njit(inline="always", fastmath=True, cache=True)
def split(table, w, wa, moment):
    """Split packet (w, w*a) into its parts (supplement Eq. 4, 7).

    Returns (front, front*a', side, side*a', back, back*a'): ``side`` is the share of ONE
    lateral neighbour, a' each part's outgoing anisotropy before decay. With float32 packets and
    a float32 table (walk.split_table32, what the walk passes) the arithmetic stays in float32,
    20 % faster than mixing in float64, and the shares still sum to 1 exactly (back = 1 - front
    - 4 side).
    """
    a = wa / w
    n = table.shape[0]
    x = (a + np.float32(1.0)) * np.float32(0.5 * (n - 1))
    x = min(max(x, np.float32(0.0)), np.float32(n - 1.0))
    i0 = min(int(x), n - 2)
    f = x - np.float32(i0)
    ef = w * (table[i0, 0] + f * (table[i0 + 1, 0] - table[i0, 0]))
    es = w * (table[i0, 1] + f * (table[i0 + 1, 1] - table[i0, 1]))
    eb = w - ef - np.float32(4.0) * es
    if moment:
        mf = table[i0, 3] + f * (table[i0 + 1, 3] - table[i0, 3])
        ms = table[i0, 4] + f * (table[i0 + 1, 4] - table[i0, 4])
        mb = table[i0, 5] + f * (table[i0 + 1, 5] - table[i0, 5])
        return ef, ef * mf, es, es * ms, eb, eb * mb
    return ef, ef * a, es, es * a, eb, eb * a


@nb.njit(inline="always", cache=True)
def _hands_over(handover, diffusive, Q, k, i, j, w, wa):
    """The hand-over to the diffusion stage (docs/METHOD.md, "Hand-over"): a packet at a cell
    centre whose lobe has spread below |a| < handover * diffusive[k, i, j] (the cell's threshold
    factor, see walk.handover_factor; 0 outside the diffusion region) leaves the walk:
    its power and first moment go to Q[0], Q[1] (the diffusion source, see diffusion.py).
    ``handover`` <= 0 turns this off (``diffusive`` and ``Q`` are then not read)."""
    if handover > 0.0 and abs(wa) < handover * diffusive[k, i, j] * w:
        Q[0, k, i, j] += w
        Q[1, k, i, j] += wa
        return True
    return False


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

@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def jacobi_send(W, Wa, Th, Dh, table, moment, periodic, inv_area, phi, phia, out, tally,
                handover, diffusive, Q):
    """Accumulate the current wave into (phi, phia) and split every packet.

    ``out`` float32 (6, n_d, n_u, n_v) receives the parts after the sender's half step:
    0 front, 1 front*a', 2 side (each), 3 side*a', 4 back, 5 back*a'. Parts that leave the
    domain are tallied; so is what the sender's half step absorbs. With ``handover`` > 0, a
    packet whose |a| < handover * diffusive[cell] (the cell's threshold factor) leaves the walk
    into Q (see :func:`_hands_over`).
    """
    n0, n1, n2 = W.shape
    part = np.zeros((4, n0))            # the tallies per slice (kernels/reduction.py)
    for kk in nb.prange(n0):
        k = np.int64(kk)   # prange indices are unsigned; keep k - 1 an integer
        refl = 0.0
        trans = 0.0
        side_out = 0.0
        absorbed = 0.0
        for i in range(n1):
            for j in range(n2):
                w = W[k, i, j]
                if w <= 0.0:
                    for p in range(6):
                        out[p, k, i, j] = 0.0
                    continue
                wa = Wa[k, i, j]
                if _hands_over(handover, diffusive, Q, k, i, j, w, wa):
                    for p in range(6):
                        out[p, k, i, j] = 0.0
                    continue
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
        part[REFLECTED, k] = refl
        part[TRANSMITTED, k] = trans
        part[SIDE_ESCAPED, k] = side_out
        part[ABSORBED, k] = absorbed
    add_parts(part, tally)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def jacobi_gather(parts, Th, Dh, periodic, W_out, Wa_out, tally):
    """Every cell gathers the parts its 6 neighbours sent toward it (supplement Eq. 9) and
    applies its own half step. Race-free (each cell writes only itself). Returns the energy
    now in flight."""
    _, n0, n1, n2 = parts.shape
    part = np.zeros((2, n0))            # in flight, absorbed per slice (kernels/reduction.py)
    for kk in nb.prange(n0):
        k = np.int64(kk)
        in_flight = 0.0
        absorbed = 0.0
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
        part[0, k] = in_flight
        part[1, k] = absorbed
    tally[ABSORBED] += ordered_sum(part[1])
    return ordered_sum(part[0])


# ---------------------------------------------------------------------------------------------
# Gauss-Seidel sweeps: slice by slice along +d or -d, cell by cell within a slice.
# ---------------------------------------------------------------------------------------------
#
# Pending state of a sweep: (R, Ra) hold what has ARRIVED at a cell since its last visit, before
# the receiver's half step; the receiver applies its Th (and Dh) when it next sends. Deposits are
# then plain additions (no factor lookups at the destination); the fixed point is the same as
# Jacobi's, which applies the receiver's half step at once.
#
# Parallelism without races or barriers: the lateral axis u is cut into bands of BAND_ROWS rows,
# one thread per band for the whole sweep. A side part that crosses into another band is parked
# in ``halo`` and delivered after the sweep (it waits one sweep, like every pending packet);
# everything else is deposited in place, so light can cross a whole band or the whole domain
# along the sweep direction in one sweep. Band edges do not depend on the thread count, so
# the result is the same on every machine. Where the light is, some bands have far more work
# than others, so the bands are not split among the threads in order (Numba's prange gives
# each thread one contiguous block of its range): the caller deals them out to lanes, one lane
# per thread, by the work each did in the previous sweep (:func:`band_lanes`).

BAND_ROWS = 16
#: a band's work is taken as its cells that sent plus its cells visited / VISIT_COST (a visit
#: that finds too little pending is a load and a comparison; a send moves six parts)
VISIT_COST = 8.0


def band_edges(n_u: int) -> np.ndarray:
    """int64 (n_bands + 1,): row edges of the bands of the lateral axis u (the last may be
    shorter; a band of one row is merged into its neighbour)."""
    edges = list(range(0, n_u, BAND_ROWS)) + [n_u]
    if len(edges) > 2 and edges[-1] - edges[-2] < 2:
        edges.pop(-2)
    return np.asarray(edges, np.int64)


def band_lanes(sent: np.ndarray, visited: np.ndarray, lanes: int) -> np.ndarray:
    """int64 (n_bands,): the lane (0 .. lanes - 1, one per thread) that sweeps each band,
    balancing the bands' work (cells that sent, ``sent``, plus ``visited`` / VISIT_COST, e.g.
    from the previous sweep; float (n_bands,)) by the longest-first greedy rule: the bands, most
    work first, each to the lane with the least so far. Equal work deals them out in turn. Which
    lane sweeps a band does not change the result, only the time."""
    # Python lists: a handful of bands, dealt once per sweep (NumPy's calls cost 50 us here)
    work = [float(s) + float(v) / VISIT_COST for s, v in zip(sent, visited)]
    load = [0.0] * max(int(lanes), 1)
    lane = [0] * len(work)
    for b in sorted(range(len(work)), key=lambda b: -work[b]):     # stable: equal work in order
        lane[b] = load.index(min(load))
        load[lane[b]] += work[b]
    return np.array(lane, np.int64)


@nb.njit(inline="always", cache=True)
def lanes_of(band_lane):
    """How many lanes ``band_lane`` (:func:`band_lanes`) deals the bands to."""
    n = 0
    for b in range(band_lane.shape[0]):
        n = max(n, band_lane[b] + 1)
    return n


@nb.njit(cache=True, nogil=True)
def bands_of(band_lane, lane):
    """int64: the bands ``band_lane`` deals to ``lane``, in order."""
    return np.flatnonzero(band_lane == np.int64(lane))


@nb.njit(inline="always", cache=True)
def _add(R, Ra, k, i, j, e, ea):
    R[k, i, j] += e
    Ra[k, i, j] += ea


@nb.njit(**ON_ITS_OWN)
def _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia, halo, handover,
          diffusive, Q, b, lo, hi, k, i, j, tallies, a_stream):
    """Cell (k, i, j) of band b (rows lo .. hi - 1) sends what has arrived, if it exceeds w_min:
    its half step, the hand-over or the visit to (phi, phia), then the split to its six
    neighbours, side parts into another band parked in ``halo``; in an empty cell a packet with
    a >= ``a_stream`` goes on whole to the front neighbour instead (docs/METHOD.md, "Streaming
    through empty cells"). ``tallies`` = (reflected, transmitted, side escaped, absorbed, cells
    that sent) so far; returns them updated."""
    refl, trans, side_out, absorbed, sent = tallies
    n0, n1, n2 = R.shape
    w = R[k, i, j]
    if w <= w_min:
        return tallies
    th = Th[k, i, j]                    # the receiver's half step ...
    thd = th * Dh[k, i, j]
    wa = Ra[k, i, j] * thd
    absorbed += w * (np.float32(1.0) - th)
    w *= th
    R[k, i, j] = 0.0
    Ra[k, i, j] = 0.0
    sent += 1
    if w <= 0.0:      # all absorbed: Th underflows to 0 where sigma_a h / 2 > ~100
        return refl, trans, side_out, absorbed, sent
    if _hands_over(handover, diffusive, Q, k, i, j, w, wa):
        return refl, trans, side_out, absorbed, sent
    phi[k, i, j] += w * inv_area
    phia[k, i, j] += wa * inv_area
    if wa >= a_stream * w and thd == 1.0:
        # an empty cell (nothing absorbs or scatters) and a lobe at least as narrow as the
        # light's own (a_stream = its a0; 1 for a sun, whose collimated light the split would
        # send all to the front anyway): it streams on unsplit, keeping its a
        if k + 1 < n0:
            _add(R, Ra, k + 1, i, j, w, wa)
        else:
            trans += w
        return refl, trans, side_out, absorbed, sent
    ef, efa, es, esa, eb, eba = split(table, w, wa, moment)
    absorbed += w * (1.0 - th)          # ... and the sender's
    if k + 1 < n0:
        _add(R, Ra, k + 1, i, j, ef * th, efa * thd)
    else:
        trans += ef * th
    if k > 0:
        _add(R, Ra, k - 1, i, j, eb * th, eba * thd)
    else:
        refl += eb * th
    es *= th
    esa *= thd
    for jj in (j - 1, j + 1):           # neighbours along v: same band
        if jj < 0 or jj >= n2:
            if not periodic:
                side_out += es
                continue
            jj = _wrap(jj, n2)
        _add(R, Ra, k, i, jj, es, esa)
    for side in range(2):               # neighbours along u
        ii = i - 1 + 2 * side
        if ii >= lo and ii < hi:
            _add(R, Ra, k, ii, j, es, esa)
        elif not periodic and (ii < 0 or ii >= n1):
            side_out += es
        else:
            halo[b, side, 0, k, j] += es
            halo[b, side, 1, k, j] += esa
    return refl, trans, side_out, absorbed, sent


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def sweep_bands(R, Ra, Th, Dh, table, moment, periodic, forward, flip, w_min, inv_area, phi,
                phia, bands, band_lane, halo, tally_b, handover, diffusive, Q, a_stream):
    """One sweep over all slices (``forward``: k = 0, 1, ...), each band by one thread, the
    lanes of ``band_lane`` (int64 (n_bands,), :func:`band_lanes`) in parallel;
    within a slice rows and columns run in increasing order, or decreasing if ``flip``.
    A cell sends only if its pending energy exceeds ``w_min`` (below it the energy stays pending,
    counted as in flight, and is sent once more has arrived: thresholded Gauss-Seidel, as in
    Southwell relaxation or progressive radiosity). In an empty cell a packet with a >=
    ``a_stream`` (float32: the light's a0) streams on unsplit to the front neighbour.

    Rows go two at a time, the second one column behind the first: cell (i + 1, j - 1) runs
    beside (i, j), after everything that row order puts before it (its row's cell j - 2, and
    (i, j - 1), the row before's last deposit into it), so every cell sees the same packets in
    the same order as row by row and the fields are bitwise the same; the two chains of
    dependent cells overlap in the processor (docs/SPEED.md: 10-25 % faster). Only the tallies
    are summed in another order. One cell's send is :func:`_send`.

    halo float32 (n_bands, 2, 2, n_d, n_v): [band, 0 = toward row lo - 1 | 1 = toward row hi,
    0 = energy | 1 = energy * a, k, j]. tally_b float64 (n_bands, 5): the four tallies and the
    number of cells that sent.
    """
    n0, n1, n2 = R.shape
    for lane in nb.prange(lanes_of(band_lane)):
        for b in bands_of(band_lane, lane):
            lo = bands[b]
            hi = bands[b + 1]
            # the tallies of the first and second row of a pair; np.int64(0), not a constant 0, which
            # Numba would type as a literal and so compile _send a second time for the first call
            first = (0.0, 0.0, 0.0, 0.0, np.int64(0))
            second = (0.0, 0.0, 0.0, 0.0, np.int64(0))
            for step in range(n0):
                k = step if forward else n0 - 1 - step
                for si in range(0, hi - lo, 2):
                    i = hi - 1 - si if flip else lo + si
                    if si + 1 == hi - lo:               # an odd band's last row alone
                        for sj in range(n2):
                            j = n2 - 1 - sj if flip else sj
                            first = _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia,
                                          halo, handover, diffusive, Q, b, lo, hi, k, i, j, first, a_stream)
                        continue
                    i2 = i - 1 if flip else i + 1         # the second row, one column behind
                    j = n2 - 1 if flip else 0
                    first = _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia,
                                  halo, handover, diffusive, Q, b, lo, hi, k, i, j, first, a_stream)
                    for sj in range(1, n2):
                        j = n2 - 1 - sj if flip else sj
                        j2 = j + 1 if flip else j - 1
                        first = _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia,
                                      halo, handover, diffusive, Q, b, lo, hi, k, i, j, first, a_stream)
                        second = _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia,
                                       halo, handover, diffusive, Q, b, lo, hi, k, i2, j2, second, a_stream)
                    j = 0 if flip else n2 - 1
                    second = _send(R, Ra, Th, Dh, table, moment, periodic, w_min, inv_area, phi, phia,
                                   halo, handover, diffusive, Q, b, lo, hi, k, i2, j, second, a_stream)
            tally_b[b, REFLECTED] += first[0] + second[0]
            tally_b[b, TRANSMITTED] += first[1] + second[1]
            tally_b[b, SIDE_ESCAPED] += first[2] + second[2]
            tally_b[b, ABSORBED] += first[3] + second[3]
            tally_b[b, 4] += first[4] + second[4]


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def deliver_halo(R, Ra, bands, halo):
    """Move the side parts parked in ``halo`` into the neighbouring bands' edge rows (wrapping
    around the lateral faces when periodic; what left the domain never entered the halo).
    Race-free: band b writes only row lo - 1 (owned by band b - 1, written by no other band)
    and row hi (band b + 1's first row), as every band has >= 2 rows."""
    n0, n1, n2 = R.shape
    for bb in nb.prange(bands.shape[0] - 1):
        b = np.int64(bb)
        for side in range(2):
            ii = _wrap(bands[b] - 1 if side == 0 else bands[b + 1], n1)
            for k in range(n0):
                for j in range(n2):
                    e = halo[b, side, 0, k, j]
                    if e != 0.0:
                        _add(R, Ra, k, ii, j, e, halo[b, side, 1, k, j])
                        halo[b, side, 0, k, j] = 0.0
                        halo[b, side, 1, k, j] = 0.0


@nb.njit(fastmath=True, cache=True, nogil=True)
def sweep(R, Ra, Th, Dh, table, moment, periodic, forward, flip, w_min, inv_area, phi, phia,
          bands, band_lane, halo, tally_b, tally, handover, diffusive, Q, a_stream):
    """One Gauss-Seidel sweep (see above), the bands dealt to lanes by ``band_lane``
    (:func:`band_lanes`); adds the sweep's tallies to ``tally`` and returns the energy still
    pending (arrived, before the receivers' half steps). tally_b[:, 4] then holds how many
    cells sent, per band. ``a_stream``: packets at least this anisotropic stream through
    empty cells unsplit (the light's a0; 1, a sun's, only collimated light)."""
    tally_b[:] = 0.0
    sweep_bands(R, Ra, Th, Dh, table, moment, periodic, forward, flip, w_min, inv_area, phi,
                phia, bands, band_lane, halo, tally_b, handover, diffusive, Q, a_stream)
    deliver_halo(R, Ra, bands, halo)
    for b in range(tally_b.shape[0]):
        for c in range(4):
            tally[c] += tally_b[b, c]
    return total_energy(R)


@nb.njit(parallel=True, fastmath=False, cache=True, nogil=True)
def total_energy(x):
    """Sum of a 3-D float32 array in float64 (parallel over the first axis; the same bits with
    any number of threads and in compiled or cached code, kernels/reduction.py)."""
    part = np.empty(x.shape[0])
    for kk in nb.prange(x.shape[0]):
        k = np.int64(kk)
        s = 0.0
        for i in range(x.shape[1]):
            s += row_sum(x, k, i)
        part[k] = s
    return ordered_sum(part)
