"""Numba kernels of the binned wavefront: a walk that is linear in the light (docs/METHOD.md,
"The schedule" and "The merge itself"; experimental.solver = "binned").

The sweeps and the Jacobi wavefront (kernels/propagation.py) merge every packet that meets in a
cell into one lobe of energy-weighted anisotropy (supplement Eq. 12), which is not additive:
the answer depends on which packets meet, i.e. on the schedule. Here a cell holds its pending
power in fixed anisotropy bins a_b (walk.anisotropy_bins: n_b values evenly spaced over
[-1, 1], a = 0 and a = 1 among them) instead:

  W   float32 (n_b, n_d, n_u, n_v): power [W] pending in bin b of each cell, at its centre
      (after the receiver's half step, as the Jacobi wave holds it).

A cell sends each bin's power as the lobe HG_{a_b} splits it (front, 4 sides, back: supplement
Eq. 2, 4, 7; shares and each part's outgoing anisotropy are constants per bin, walk.bin_shares).
A part crossing from cell s to its neighbour c arrives with energy e = w share Th[s] Th[c] and
anisotropy a' = m Dh[s] Dh[c] (m: the part's conditional mean cosine, rule "moment", or a_b,
rule "paper"), and is split between the two bins around a' with weights (1 - l, l),
l = (a' - a_t) / (a_{t+1} - a_t), so that its energy and first moment are kept exactly. Every
step is linear in W: two lights walked apart add up to the two walked together, and the fixed
point does not depend on the order in which cells send.

Hand-over (docs/METHOD.md, "Hand-over"): an arriving part with |a'| < handover * diffusive[c]
goes to Q[0], Q[1] (power, power * a') instead of a bin. Tallies (float64 (4,)) as in
kernels/propagation.py: reflected, transmitted, side escaped, absorbed.

NumPy twin: tests/twins.py (binned_step).
"""
import numba as nb
import numpy as np

from .propagation import ABSORBED, REFLECTED, SIDE_ESCAPED, TRANSMITTED, _wrap
from .reduction import add_parts, ordered_sum


@nb.njit(inline="always", cache=True)
def rebin(W, ab, k, i, j, e, a):
    """Add energy e of anisotropy a (in [-1, 1]) to the two bins of cell (k, i, j) around a,
    keeping e and e a (bins evenly spaced: ab[t] = -1 + 2 t / (n_b - 1))."""
    n = ab.shape[0]
    x = (a + 1.0) * (0.5 * (n - 1))
    x = min(max(x, 0.0), n - 1.0)
    t = min(int(x), n - 2)
    lam = x - t
    W[t, k, i, j] += e * (1.0 - lam)
    W[t + 1, k, i, j] += e * lam


@nb.njit(inline="always", cache=True)
def arrive(W, ab, k, i, j, e, a, handover, diffusive, Q):
    """A part of energy e and anisotropy a arrives at the centre of cell (k, i, j): it is handed
    over (|a| < handover * diffusive[k, i, j]: added to Q[0], Q[1]) or binned into W (:func:`rebin`).
    Returns True if it was binned (it stays in flight)."""
    if handover > 0.0 and abs(a) < handover * diffusive[k, i, j]:
        Q[0, k, i, j] += e
        Q[1, k, i, j] += e * a
        return False
    rebin(W, ab, k, i, j, e, a)
    return True


@nb.njit(cache=True, nogil=True)
def inject(W, ab, e, a, handover, diffusive, Q):
    """The light injected through the face k = 0 arrives at the centres of slice 0: energy
    e[i, j], anisotropy a[i, j] (float64 (n_u, n_v)), each part as :func:`arrive` says."""
    for i in range(e.shape[0]):
        for j in range(e.shape[1]):
            if e[i, j] > 0.0:
                arrive(W, ab, 0, i, j, e[i, j], a[i, j], handover, diffusive, Q)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def binned_send(W, ab, shares, Th, periodic, inv_area, phi, phia, tally):
    """Accumulate the wave into (phi, phia) and tally what the senders' half steps absorb and
    what leaves the domain (it crosses only the sender's half cell). ``shares`` float64 (n_b, 6):
    front, side (each), back share, then the three parts' outgoing anisotropy before decay."""
    n_b, n0, n1, n2 = W.shape
    part = np.zeros((4, n0))            # the tallies per slice (kernels/reduction.py)
    for kk in nb.prange(n0):
        k = np.int64(kk)
        for i in range(n1):
            for j in range(n2):
                th = Th[k, i, j]
                missing = 0
                if not periodic:
                    missing = (i == 0) + (i == n1 - 1) + (j == 0) + (j == n2 - 1)
                for b in range(n_b):
                    w = W[b, k, i, j]
                    if w <= 0.0:
                        continue
                    phi[k, i, j] += w * inv_area
                    phia[k, i, j] += w * ab[b] * inv_area
                    sent = w * th               # what the sender's half step leaves
                    part[ABSORBED, k] += w - sent
                    if k == n0 - 1:
                        part[TRANSMITTED, k] += sent * shares[b, 0]
                    if k == 0:
                        part[REFLECTED, k] += sent * shares[b, 2]
                    part[SIDE_ESCAPED, k] += missing * sent * shares[b, 1]
    add_parts(part, tally)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def binned_gather(W, ab, shares, Th, Dh, periodic, handover, diffusive, Q, W_out, tally):
    """Every cell gathers, bin by bin, the parts its 6 neighbours send toward it (module
    docstring), hands over those below its threshold and bins the rest into ``W_out`` (zeroed
    here). Race-free: each cell writes only itself. Returns the energy now in flight."""
    n_b, n0, n1, n2 = W.shape
    part = np.zeros((2, n0))            # in flight, absorbed per slice (kernels/reduction.py)
    for kk in nb.prange(n0):
        k = np.int64(kk)
        in_flight = 0.0
        absorbed = 0.0
        for i in range(n1):
            for j in range(n2):
                for b in range(n_b):
                    W_out[b, k, i, j] = 0.0
                th = Th[k, i, j]
                dh = Dh[k, i, j]
                for nbr in range(6):
                    # 0: the cell behind sends its front part; 1: the cell ahead its back part;
                    # 2-5: the lateral neighbours their side parts
                    ks, is_, js = k, i, j
                    p = 1
                    if nbr == 0:
                        ks, p = k - 1, 0
                        if ks < 0:
                            continue
                    elif nbr == 1:
                        ks, p = k + 1, 2
                        if ks >= n0:
                            continue
                    else:
                        is_ = i + (nbr == 2) - (nbr == 3)
                        js = j + (nbr == 4) - (nbr == 5)
                        if periodic:
                            is_ = _wrap(is_, n1)
                            js = _wrap(js, n2)
                        elif is_ < 0 or is_ >= n1 or js < 0 or js >= n2:
                            continue
                    t_src = Th[ks, is_, js]
                    d = Dh[ks, is_, js] * dh
                    for b in range(n_b):
                        w = W[b, ks, is_, js]
                        if w <= 0.0:
                            continue
                        e = w * shares[b, p] * t_src          # after the sender's half step
                        absorbed += e * (1.0 - th)
                        e *= th
                        if arrive(W_out, ab, k, i, j, e, shares[b, 3 + p] * d, handover, diffusive, Q):
                            in_flight += e
        part[0, k] = in_flight
        part[1, k] = absorbed
    tally[ABSORBED] += ordered_sum(part[1])
    return ordered_sum(part[0])
