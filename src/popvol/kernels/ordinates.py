"""Numba kernel of the six-ordinate walk (docs/METHOD.md, "Six ordinates"; experimental.solver =
"ordinates" with experimental.ordinates = 6; the eighteen-ordinate walk of kernels/ordinates18.py
is built on it).

The sweeps, the Jacobi and the binned wavefronts hold one lobe per cell about the domain's axis
d: a part sent sideways is merged back into a lobe about d at the next cell, so light that moves
sideways forgets it and lateral transport is a random walk of step h, however thin the medium
(docs/ACCURACY_NOTES.md, the narrow beam). Here a cell holds one pending packet per lattice
direction e_o (o = 0..5: +d, -d, +u, -u, +v, -v; o ^ 1 is the opposite of o):

  W, Wa  float32 (m, 12): power [W] pending in ordinate o of each cell that is not skipped
         (below; cell (k, i, j) at row cell[k, i, j], int32 (n_d, n_u, n_v), -1 where
         skipped, its 12 slots side by side), at its centre (after the receiver's half step),
         and power times the lobe's anisotropy about e_o; then, in slot 6 + o, the light that
         scattered in the cell's half of its way in along e_o, and its power times a_s (below).

A packet is sent across one transfer to the neighbour c along its own e_o (docs/METHOD.md, "Six
ordinates"). The share S = Sh[s] Sh[c] of it that crosses unscattered (Sh = exp(-sigma_s h / 2),
the half-step no-scatter transmittance of sender s and receiver c) goes on in ordinate o and
keeps its lobe: only scattering changes a direction, so a lobe is not split again at every
cell. The rest has the anisotropy a_s = a (D - S) / (1 - S) (D = Dh[s] Dh[c], so the mean
cosine of the whole decays as Eq. 12). Its share 1 - Sh[s] scatters in the sender's half and
leaves from there; the share Sh[s] (1 - Sh[c]) scatters in the receiver's half, crosses into
it (Th[c]) and waits in its slot 6 + o until c is visited, then leaves from c. Where it
leaves from, it splits by the cone partition about e_o (supplement Eq. 2, 4, 7; the shares of
docs/METHOD.md Eq. 6): its front part goes on along e_o
in ordinate o with anisotropy m_front (Eq. 8), its back part into ordinate o ^ 1 with
|m_back|, and the side part toward e_n into ordinate n with the mean cosine, about e_n, of the
side wedge of HG_a_s about e_o (``table`` column MJ); from the sender to its neighbours, from
the receiver into its own ordinates. The side part's drift along e_o (m_side) is not carried.
Every transfer is attenuated by the half steps Th of both cells (Eq. 11). So light keeps its
direction until it scatters, light that scatters sideways keeps going sideways, and light
that scatters just inside a lit face leaves from the face's first cell. Each slot is written
by one neighbour only (c's slot 6 + o by c - e_o). Every order of scattering is walked: there is
no hand-over to a diffusion stage.

The packets are sent by thresholded Gauss-Seidel sweeps (:func:`ordinates_sweep`), cell by
cell in place, as the one-lobe walk's sweeps are (kernels/propagation.py): a part sent to a
cell later in the sweep's order is sent on in the same sweep, so light crosses the domain along
every ordinate that the sweep's order follows in one sweep. One cell's send is :func:`_send`;
the sweep runs it on threads as a pipeline of row groups that gives the bits of one thread.

Empty space (docs/METHOD.md, "Skipping empty space"): a skipped cell (empty, with no medium
among its 26 neighbours, its fields read by no one: walk.skipped_cells) holds no packet and has
no row in W. A part sent into one crosses the whole run of skipped cells ahead of it along
its ordinate at once (``runs``, int16 (6, n_d, n_u, n_v), kernels.cells.skip_runs), unchanged
(nothing scatters or is absorbed there), into the cell after the run or out of the domain;
their phi and F stay 0. ``pending`` (uint8 (n_d, n_u)) marks the rows that hold a packet; a
sweep visits only those, which changes no bit.

Fields (per unit area, accumulated at every visit, Eq. 14): phi float32 (n_d, n_u, n_v) the
fluence, F float32 (3, n_d, n_u, n_v) its first moment (the sum over ordinates of W a e_o) in
the domain's frame. Tallies (float64 (4,)): reflected, transmitted, side escaped, absorbed.

NumPy twin: tests/twins.py (ordinates_sweep).
"""
import numba as nb
import numpy as np

from . import ON_ITS_OWN
from .cells import cell_along, face_neighbour
from .propagation import ABSORBED, REFLECTED, SIDE_ESCAPED, TRANSMITTED
from .reduction import add_row_parts

#: columns of the ordinates' table (walk.ordinate_table): front share, side share (each),
#: back share, the three parts' conditional mean cosines about e_o, and the side wedge's mean
#: cosine about its own axis
PF, PS, PB, MF, MS, MB, MJ = range(7)


@nb.njit(inline="always", cache=True)
def _deliver(W, Wa, Th, cell, runs, pending, q, k2, i2, j2, e, a, refl, trans, side_out, absorbed):
    """Part ``e`` (anisotropy ``a``) into ordinate q (0..5) of cell (k2, i2, j2), after that
    cell's half step, its row marked ``pending``; where that cell is skipped, across its run
    of skipped cells along e_q (``runs``) to the cell after it. Tallied where it leaves the
    domain: through the face k = 0 (reflected), the far face (transmitted) or a lateral face
    (side). Returns the four tallies."""
    n0, n1, n2 = Th.shape
    if 0 <= k2 < n0 and 0 <= i2 < n1 and 0 <= j2 < n2 and cell[k2, i2, j2] < 0:
        k2, i2, j2 = cell_along(k2, i2, j2, q, runs[q, k2, i2, j2])
    if k2 < 0:
        refl += e
    elif k2 >= n0:
        trans += e
    elif i2 < 0 or i2 >= n1 or j2 < 0 or j2 >= n2:
        side_out += e
    else:
        th2 = Th[k2, i2, j2]
        absorbed += e * (1.0 - th2)
        e *= th2
        c = cell[k2, i2, j2]
        W[c, q] += e
        Wa[c, q] += e * a
        if pending[k2, i2] == 0:         # written once a sweep: the other thread reads this line
            pending[k2, i2] = 1
    return refl, trans, side_out, absorbed


@nb.njit(inline="always", cache=True)
def _cone(table, a):
    """The cone partition of HG_a about its axis, interpolated in ``table`` (walk.ordinate_table):
    (front share, side share (each), back share, m_front, m_back, m_wedge)."""
    nt = table.shape[0]
    x = (a + 1.0) * 0.5 * (nt - 1)
    x = min(max(x, 0.0), nt - 1.0)
    t = min(int(x), nt - 2)
    lam = x - t
    pf = table[t, PF] + lam * (table[t + 1, PF] - table[t, PF])
    ps = table[t, PS] + lam * (table[t + 1, PS] - table[t, PS])
    pb = max(1.0 - pf - 4.0 * ps, 0.0)
    mf = table[t, MF] + lam * (table[t + 1, MF] - table[t, MF])
    mb = table[t, MB] + lam * (table[t + 1, MB] - table[t, MB])
    mj = table[t, MJ] + lam * (table[t + 1, MJ] - table[t, MJ])
    return pf, ps, pb, mf, mb, mj


@nb.njit(inline="always", cache=True)
def _part(o, n, cone):
    """(share, outgoing anisotropy) of the part of a lobe about e_o that goes into ordinate n,
    from its cone partition ``cone`` (:func:`_cone`): the front part on in o with m_front, the
    back part into o ^ 1 with -m_back, each side part into its own ordinate with m_wedge."""
    pf, ps, pb, mf, mb, mj = cone
    if n == o:
        return pf, mf
    if n == (o ^ 1):
        return pb, -mb
    return ps, mj


@nb.njit(**ON_ITS_OWN)
def _send(W, Wa, Th, Dh, Sh, table, inv_area, phi, F, w_min, cell, runs, pending, k, i, j, tallies, out, ahead):
    """Cell (k, i, j) sends its pending packets above ``w_min``, ordinate by ordinate (module
    docstring; :func:`ordinates_sweep`); a skipped cell (``cell`` < 0) holds none. A packet
    left pending marks its row in ``pending``. What all its packets send to one neighbour (in
    that neighbour's ordinate n) is summed in ``out`` (float64, 12 or more, scratch: power, then
    power times anisotropy) and delivered once, a merge that changes the fields only by
    rounding. Only the ordinates marked ``ahead`` (bool (6,)) are sent. ``tallies`` =
    (reflected, transmitted, side escaped, absorbed, packets sent) so far; returns them
    updated."""
    c = cell[k, i, j]
    if c < 0:
        return tallies
    refl, trans, side_out, absorbed, sent_packets = tallies
    n0, n1, n2 = Th.shape
    th = Th[k, i, j]
    dh = Dh[k, i, j]
    sh = Sh[k, i, j]
    for o in range(6):
        # light that scattered in this cell's half of its way in along e_o (slot 6 + o): split
        # by the cone partition about e_o into this cell's ordinates
        x = W[c, 6 + o]
        if x <= 0.0:
            continue
        xa = Wa[c, 6 + o]
        W[c, 6 + o] = 0.0
        Wa[c, 6 + o] = 0.0
        cone = _cone(table, xa / x)
        for n in range(6):
            share, m = _part(o, n, cone)
            W[c, n] += x * share
            Wa[c, n] += x * share * m
    # what leaves this cell for its neighbour along e_n, into ordinate n, summed over the packets
    # sent: power in out[n], power times anisotropy in out[6 + n] (one delivery per neighbour)
    out[:] = 0.0
    for o in range(6):
        w = W[c, o]
        if w <= w_min or not ahead[o]:
            if w > 0.0 and pending[k, i] == 0:
                pending[k, i] = 1
            continue
        wa = Wa[c, o]
        W[c, o] = 0.0
        Wa[c, o] = 0.0
        sent_packets += 1
        sign = 1.0 - 2.0 * (o % 2)
        phi[k, i, j] += w * inv_area
        F[o // 2, k, i, j] += sign * wa * inv_area
        a = wa / w
        sent = w * th                    # what the sender's half step leaves
        absorbed += w - sent
        # the part that crosses to the next cell along e_o unscattered keeps its lobe
        k2, i2, j2 = face_neighbour(k, i, j, o)
        inside = k2 >= 0 and k2 < n0 and i2 >= 0 and i2 < n1 and j2 >= 0 and j2 < n2
        S = sh * Sh[k2, i2, j2] if inside else sh
        D = dh * Dh[k2, i2, j2] if inside else dh
        out[o] += sent * S
        out[6 + o] += sent * S * a
        if S >= 1.0:                     # nothing scatters on the way
            continue
        # the part that scatters: its lobe's mean cosine a_s = a (D - S) / (1 - S), so that the
        # whole decays by D (Eq. 12) while the unscattered part keeps a
        a_s = a * (D - S) / (1.0 - S)
        # it scatters in the sender's half (1 - Sh[s]) and is split from here by the cone
        # partition about e_o: front on along e_o, back into o ^ 1, each side part along its e_n
        # (:func:`_part`'s shares written out: a sweep 11 % faster than a loop over _part) ...
        es = sent * (1.0 - sh)
        if es > 0.0:
            pf, ps, pb, mf, mb, mj = _cone(table, a_s)
            out[o] += es * pf
            out[6 + o] += es * pf * mf
            out[o ^ 1] += es * pb
            out[6 + (o ^ 1)] -= es * pb * mb
            for n in range(6):
                if n // 2 != o // 2:
                    out[n] += es * ps
                    out[6 + n] += es * ps * mj
        # ... or in the receiver's (Sh[s] (1 - Sh[c])): it crosses into the receiver and waits
        # there in slot 6 + o, which only this cell writes (a receiver with medium, or next to
        # this cell's, is never skipped)
        if inside:
            thc = Th[k2, i2, j2]
            es = sent * sh * (1.0 - Sh[k2, i2, j2])
            absorbed += es * (1.0 - thc)
            es *= thc
            c2 = cell[k2, i2, j2]
            W[c2, 6 + o] += es
            Wa[c2, 6 + o] += es * a_s
            if pending[k2, i2] == 0:
                pending[k2, i2] = 1
    for n in range(6):
        e = out[n]
        if e > 0.0:
            k3, i3, j3 = face_neighbour(k, i, j, n)
            refl, trans, side_out, absorbed = _deliver(W, Wa, Th, cell, runs, pending, n, k3, i3, j3, e,
                                                       out[6 + n] / e, refl, trans, side_out, absorbed)
    return refl, trans, side_out, absorbed, sent_packets


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def ordinates_sweep(W, Wa, Th, Dh, Sh, table, inv_area, phi, F, w_min, forward_d, forward_u, forward_v, tally,
                    edges, row_work, cell, runs, pending, ahead):
    """One Gauss-Seidel sweep (module docstring): the cells in order of k, then i, then j,
    each increasing if its ``forward_*``, else decreasing; at each cell, ordinate by ordinate,
    a pending packet above ``w_min`` is taken, its visit accumulated into (phi, F), and sent,
    in place: what crosses to the next cell along its ordinate unscattered keeps its lobe, what
    scatters on the way is split to the six neighbours (module docstring). What leaves the
    domain is tallied (``tally``), as what the half steps absorb. Packets at or below ``w_min``
    stay pending, and so do those of the ordinates not marked ``ahead`` (bool (6,); an upwind
    sweep marks those that point ahead in its order, walk.ordinates_ahead): the others wait,
    gathering what else arrives, for a sweep in their own direction, in which they cross the
    domain at once rather than one cell.
    Returns the number of packets sent.

    On threads as a pipeline: the rows, in the sweep's order, are cut into groups at ``edges``
    (int64 (groups + 1,), row positions in that order from 0 to n_u, one group per thread: see
    walk.row_groups), and group g sweeps slice s while group g - 1 sweeps slice s + 1. A cell's
    pending packets come from its six neighbours, each into its own ordinate; every cell a group
    reads or writes in a step is one that the row-by-row order has already given all it gives
    before that cell's turn (the group before has swept the slice, the slice before is done),
    and no two groups write one ordinate of one cell in a step. So the fields are bitwise those
    of one thread sweeping row by row, whatever the groups; the tallies are summed per row in a
    fixed order (kernels/reduction.py). ``row_work`` (float64 (n_u,)) receives the packets each
    row i sent, for the next sweep's groups.

    A part crossing a run of skipped cells (``cell``, ``runs``: module docstring) lands in a cell
    that only the row-by-row order's cells before it write in this step: along d in its own row
    (its group's), along u or v in its own slice, which no other group touches in the step.
    So the bits stay those of one thread. A row not marked ``pending`` (uint8 (n_d, n_u)) holds
    no packet and is passed over; a row's mark is cleared when it is swept and set again by
    every packet that arrives in it or stays pending there; the callers mark the rows of
    their initial packets."""
    n0, n1, n2 = Th.shape
    groups = edges.shape[0] - 1
    part = np.zeros((5, n0 * n1))
    # each group's parts leaving a cell (_send), 12 of 24 slots: no two groups share a cache line
    out = np.zeros((groups, 24))
    for step in range(n0 + groups - 1):
        for g in nb.prange(groups):
            s = step - g
            if s >= 0 and s < n0:
                k = s if forward_d else n0 - 1 - s
                for r in range(edges[g], edges[g + 1]):
                    i = r if forward_u else n1 - 1 - r
                    if pending[k, i] == 0:
                        continue
                    pending[k, i] = 0
                    t = (0.0, 0.0, 0.0, 0.0, np.int64(0))
                    for jj in range(n2):
                        j = jj if forward_v else n2 - 1 - jj
                        t = _send(W, Wa, Th, Dh, Sh, table, inv_area, phi, F, w_min, cell, runs, pending, k, i, j, t,
                                  out[g], ahead)
                    row = k * n1 + i
                    part[0, row], part[1, row], part[2, row], part[3, row] = t[0], t[1], t[2], t[3]
                    part[4, row] = t[4]
    return add_row_parts(part, tally, row_work)
