"""Numba kernel of the eighteen-ordinate walk (docs/METHOD.md, "Eighteen ordinates";
experimental.ordinates = 18, the default for a sun's and an environment's light): the
six-ordinate walk of kernels/ordinates.py with a direction per face and per edge of the cube
lattice.

A cell holds one pending packet per ordinate o = 0..17, a lobe HG_a about its direction e_o
(walk.ORDINATES18: the six faces +-d, +-u, +-v, then the twelve edges (+-1, +-1, 0) / sqrt 2 and
their permutations, offsets in cells ``offs``):

  W, Wa  float32 (m, 18): power [W] pending in ordinate o at the centre of each cell that is
         not skipped (below; cell (k, i, j) at row cell[k, i, j], int32 (n_d, n_u, n_v), -1
         where skipped), after the receiver's half step, and power times the lobe's anisotropy
         about e_o.

A packet crosses one transfer to the neighbour at offset offs[o], a path of L = h (a face) or
sqrt(2) h (an edge), so every factor of a cell is taken to the power L / h: the half-step
transmittance Th (absorption), no-scatter transmittance Sh and anisotropy decay Dh (``Th2``,
``Sh2``, ``Dh2`` are those of an edge). As in the six-ordinate walk, the share S = Sh[s] Sh[c]
crosses unscattered and keeps its lobe; the rest scatters, with the anisotropy a_s = a (D - S) /
(1 - S) (D = Dh[s] Dh[c]: the whole's mean cosine decays as Eq. 12). The share 1 - Sh[s] of what
is sent scatters in the sender's half of the way and leaves from the sender, the share Sh[s] (1 -
Sh[c]) in the receiver's half and leaves from the receiver. Where it leaves from it is split by
the partition of the sphere among the 18 directions (each direction takes the directions nearer
to it than to any other: walk.ordinate18_table): the part that falls in ordinate n's cell of the
sphere goes into ordinate n with that part's mean cosine about e_n. From the sender the parts go
to its neighbours (offs[n]); from the receiver into its own ordinates at once. So light that
scatters 45 degrees off its way goes on diagonally, not sideways at 90 degrees as with six
ordinates.

Fields (per unit area, accumulated at every visit, Eq. 14): phi float32 (n_d, n_u, n_v), the
fluence (a visit adds W L / h^3: a packet on an edge crosses sqrt 2 h between centres), and F
float32 (3, n_d, n_u, n_v), its first moment (the sum of W L a e_o / h^3) in the domain's frame.
Tallies (float64 (4,)): reflected, transmitted, side escaped, absorbed.

The sweep visits the cells in order of k, then i, then j (each increasing or decreasing), cell by
cell in place (a Gauss-Seidel sweep), and only the rows marked ``pending`` (uint8 (n_d, n_u)):
a row's mark is cleared when it is swept and set by every packet that arrives in it or stays
pending there. Its rows are cut into groups that sweep as a pipeline: group g sweeps slice s
while group g - 1 sweeps slice s + 3. A cell reads its own packets only, and sends to its
neighbours, in the slices next to its own: the two groups' deliveries never meet (slices s - 1
.. s + 1 against s + 2 .. s + 4). What a group sends into the rows of the group ahead of it
arrives after that group has swept them and waits for the next sweep. (For the parts that
cross runs of skipped cells, below: along +-d or a (d, v) edge a part stays in its group's own
rows, along u, v or a (u, v) edge in its slice, where no other group is; along a (d, u) edge it
is held to the sweep's end.) The cut is the callers' (walk.row_groups), not the thread count's, so the
fields are the same bits on one thread or two.

Empty space (docs/METHOD.md, "Skipping empty space", as the six-ordinate walk's): a skipped
cell (empty, with no medium among its 26 neighbours, its fields read by no one:
walk.skipped_cells) holds no packet and has no row in W. A part sent into one goes on along its
ordinate, unchanged, across the run of skipped cells to the cell after it or out of the domain;
their phi and F stay 0. A part that crosses such a run along an edge of the (d, u) plane lands
in another slice and may land in the other group's rows, in the slice that group is sweeping:
so it is held, with the group's other such parts, and delivered after the sweep, the groups'
held parts in the order of the groups (it then waits for the next sweep, as it would if it had
landed behind the sweep). So the bits stay those of the groups, whatever the threads.

NumPy twin: tests/twins.py (ordinates18_sweep).
"""
import math

import numba as nb
import numpy as np

from .reduction import add_row_parts

#: ordinates of the eighteen-ordinate walk
M18 = 18


#: ``landing`` codes (:func:`_landing`): not yet found, and the three ways out of the domain
UNKNOWN, REFLECTED, TRANSMITTED, SIDE = -4, -1, -2, -3


@nb.njit(inline="always", cache=True)
def _landing(cell, offs, landing, c, n, k, i, j):
    """The cell a part sent along ordinate n from cell c lands in, given its neighbour (k, i, j)
    along it: (k, i, j) itself, or, where that is skipped, the first cell not skipped along
    offs[n] after it, or the first position outside the domain. The run of skipped cells is
    walked once per (c, n) and remembered in ``landing`` (int32 (m, 18): the landing cell's
    position (k n_u + i) n_v + j, or REFLECTED, TRANSMITTED or SIDE where the part leaves through
    the face k = 0, the far face or a lateral one, UNKNOWN until walked; row c is written by
    the group that sweeps c only)."""
    n0, n1, n2 = cell.shape
    if not (0 <= k < n0 and 0 <= i < n1 and 0 <= j < n2 and cell[k, i, j] < 0):
        return k, i, j
    p = landing[c, n]
    if p == UNKNOWN:
        while 0 <= k < n0 and 0 <= i < n1 and 0 <= j < n2 and cell[k, i, j] < 0:
            k += offs[n, 0]
            i += offs[n, 1]
            j += offs[n, 2]
        if k < 0:
            p = REFLECTED
        elif k >= n0:
            p = TRANSMITTED
        elif i < 0 or i >= n1 or j < 0 or j >= n2:
            p = SIDE
        else:
            p = (k * n1 + i) * n2 + j
        landing[c, n] = p
        return k, i, j
    if p == REFLECTED:
        return -1, 0, 0
    if p == TRANSMITTED:
        return n0, 0, 0
    if p == SIDE:
        return 0, -1, 0
    return p // (n1 * n2), (p // n2) % n1, p % n2


@nb.njit(fastmath=True, error_model="numpy", forceinline=True, _nrt=False, cache=True)
def _send(W, Wa, Th, Dh, Sh, Th2, Dh2, Sh2, offs, table, inv_area, phi, F, w_min, cell, landing, pending, k, i, j,
          scratch, g, held_n, held_at, held, tallies, ahead):
    """Cell (k, i, j) sends its packets above ``w_min`` (module docstring). Row g of
    ``scratch`` (float32 (groups, 128)) is the caller's: what leaves for each neighbour (power,
    then power times anisotropy) in columns 0-35 (indexed, not sliced: a view made per cell
    costs every thread an atomic update of the array's reference count); held_n[g, 0] (int64
    (groups, 16)) counts the parts its group holds (module docstring) in ``held_at`` (int64
    (groups, capacity, 3): the landing cell's row of W, the ordinate, the landing row k n_u + i)
    and ``held`` (float64 (groups, capacity, 2): power and power times anisotropy, after the
    landing cell's half step). A packet's split is computed in float32, as its power is stored.
    Only the ordinates marked ``ahead`` (bool (18,)) are sent. ``tallies`` = (reflected,
    transmitted, side escaped, absorbed, packets sent) so far; returns them updated. A skipped
    cell (``cell`` < 0) holds none."""
    c = cell[k, i, j]
    if c < 0:
        return tallies
    refl, trans, side_out, absorbed, sent_packets = tallies
    n0, n1, n2 = Th.shape
    na = table.shape[1]
    sq2 = math.sqrt(2.0)
    one = np.float32(1.0)
    sending = False
    for o in range(M18):
        w = W[c, o]
        if w <= w_min or not ahead[o]:
            if w > 0.0 and pending[k, i] == 0:
                pending[k, i] = 1
            continue
        if not sending:
            for n in range(2 * M18):
                scratch[g, n] = np.float32(0.0)
            sending = True
        wa = Wa[c, o]
        W[c, o] = 0.0
        Wa[c, o] = 0.0
        sent_packets += 1
        edge = o >= 6
        L = sq2 if edge else 1.0
        phi[k, i, j] += w * L * inv_area
        # e_o = offs[o] / L, so W L a e_o = W a offs[o]
        F[0, k, i, j] += wa * offs[o, 0] * inv_area
        F[1, k, i, j] += wa * offs[o, 1] * inv_area
        F[2, k, i, j] += wa * offs[o, 2] * inv_area
        a = wa / w
        if edge:
            th, sh, dh = Th2[k, i, j], Sh2[k, i, j], Dh2[k, i, j]
        else:
            th, sh, dh = Th[k, i, j], Sh[k, i, j], Dh[k, i, j]
        sent = w * th
        absorbed += w - sent
        k2, i2, j2 = k + offs[o, 0], i + offs[o, 1], j + offs[o, 2]
        inside = 0 <= k2 < n0 and 0 <= i2 < n1 and 0 <= j2 < n2
        shc = one
        D = dh
        if inside:
            shc = Sh2[k2, i2, j2] if edge else Sh[k2, i2, j2]
            D = dh * (Dh2[k2, i2, j2] if edge else Dh[k2, i2, j2])
        S = sh * shc
        # the part that crosses unscattered keeps its lobe
        scratch[g, o] += sent * S
        scratch[g, M18 + o] += sent * S * a
        if S >= 1.0:
            continue
        a_s = a * (D - S) / (one - S)
        x = min(max((a_s + one) * np.float32(0.5 * (na - 1)), np.float32(0.0)), np.float32(na - 1))
        t = min(int(x), na - 2)
        lam = x - np.float32(t)
        # what scatters in the sender's half is split here, to the sender's neighbours; what
        # scatters in the receiver's half crosses into the receiver (its half step) and is split
        # there, into the receiver's own ordinates
        es = sent * (one - sh)
        er = np.float32(0.0)
        c2 = -1
        if inside and shc < 1.0:         # the receiver holds medium, so it is not skipped
            c2 = cell[k2, i2, j2]
            thc = Th2[k2, i2, j2] if edge else Th[k2, i2, j2]
            er = sent * sh * (one - shc)
            absorbed += er * (one - thc)
            er *= thc
            if pending[k2, i2] == 0:     # written once a sweep: the other group reads this line
                pending[k2, i2] = 1
        # the lobe's 18 shares and moments, each a contiguous row of the table (the loops
        # vectorise), added where they go in one pass
        if c2 >= 0:
            for n in range(M18):
                share = table[o, t, 0, n] + lam * (table[o, t + 1, 0, n] - table[o, t, 0, n])
                moment = table[o, t, 1, n] + lam * (table[o, t + 1, 1, n] - table[o, t, 1, n])
                scratch[g, n] += es * share
                scratch[g, M18 + n] += es * moment
                W[c2, n] += er * share
                Wa[c2, n] += er * moment
        else:
            for n in range(M18):
                share = table[o, t, 0, n] + lam * (table[o, t + 1, 0, n] - table[o, t, 0, n])
                moment = table[o, t, 1, n] + lam * (table[o, t + 1, 1, n] - table[o, t, 1, n])
                scratch[g, n] += es * share
                scratch[g, M18 + n] += es * moment
    if sending:
        # what leaves for each neighbour, after the neighbour's half step
        for n in range(M18):
            e = scratch[g, n]
            if e <= 0.0:
                continue
            k3, i3, j3 = _landing(cell, offs, landing, c, n, k + offs[n, 0], i + offs[n, 1], j + offs[n, 2])
            if k3 < 0:
                refl += e
            elif k3 >= n0:
                trans += e
            elif i3 < 0 or i3 >= n1 or j3 < 0 or j3 >= n2:
                side_out += e
            else:
                th3 = Th2[k3, i3, j3] if n >= 6 else Th[k3, i3, j3]
                absorbed += e * (1.0 - th3)
                c3 = cell[k3, i3, j3]
                if offs[n, 0] != 0 and offs[n, 1] != 0 and k3 != k + offs[n, 0]:
                    # across skipped cells along a (d, u) edge: held until the sweep's end
                    q = held_n[g, 0]
                    held_at[g, q, 0] = c3
                    held_at[g, q, 1] = n
                    held_at[g, q, 2] = k3 * n1 + i3
                    held[g, q, 0] = e * th3
                    held[g, q, 1] = scratch[g, M18 + n] * th3
                    held_n[g, 0] += 1
                else:
                    W[c3, n] += e * th3
                    Wa[c3, n] += scratch[g, M18 + n] * th3
                    if pending[k3, i3] == 0:
                        pending[k3, i3] = 1
    return refl, trans, side_out, absorbed, sent_packets


#: slices between the pipeline's groups (module docstring)
LAG = 3


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def ordinates18_sweep(W, Wa, Th, Dh, Sh, Th2, Dh2, Sh2, offs, table, inv_area, phi, F, w_min, forward_d,
                      forward_u, forward_v, tally, cell, landing, pending, edges, row_work, held_at, held, ahead):
    """One Gauss-Seidel sweep (module docstring): at each cell of a pending row, ordinate by
    ordinate, a packet above ``w_min`` is taken, its visit accumulated into (phi, F) and sent;
    packets at or below it stay pending, and so do those of the ordinates not marked ``ahead`` (bool
    (18,); an upwind sweep marks the 9 that point ahead in its order, walk.ordinates_ahead): they
    wait, gathering what else arrives, for a sweep in which they point ahead. ``table`` float32 (18, n_a, 2, 18):
    for a lobe HG_a about e_o at a = linspace(-1, 1, n_a), the share that falls in ordinate n's part
    of the sphere and that share times its mean cosine about e_n (walk.ordinate18_table);
    interpolated linearly in a. ``offs`` int64 (18, 3). ``cell``: each cell's row of W, -1 where
    skipped; ``landing`` int32 (m, 18), where each cell's parts land across the runs of skipped
    cells (:func:`_landing`; UNKNOWN at first, kept from sweep to sweep). ``edges`` int64 (groups +
    1,): the groups' rows, as positions in the sweep's order from 0 to n_u (one group: row by row).
    ``row_work`` float64 (n_u,) receives the packets each row sent, for the next sweep's cut.
    ``held_at`` int64 (groups, capacity, 3) and ``held`` float64 (groups, capacity, 2): room for the
    parts held to the sweep's end (module docstring; capacity 4 m is enough: at most one per (d, u)
    edge ordinate and cell visit, with the neighbour along it skipped). Returns (packets sent, parts
    held)."""
    n0, n1, n2 = Th.shape
    groups = edges.shape[0] - 1
    # each group's scratch (_send's) and count of parts held in rows of their own, 512 and 128
    # bytes apart: no two groups share a cache line
    scratch = np.zeros((groups, 128), np.float32)
    held_n = np.zeros((groups, 16), np.int64)
    part = np.zeros((5, n0 * n1))
    for step in range(n0 + LAG * (groups - 1)):
        for g in nb.prange(groups):
            s = step - LAG * g
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
                        t = _send(W, Wa, Th, Dh, Sh, Th2, Dh2, Sh2, offs, table, inv_area, phi, F, w_min, cell,
                                  landing, pending, k, i, j, scratch, g, held_n, held_at, held, t, ahead)
                    row = k * n1 + i
                    part[0, row], part[1, row], part[2, row], part[3, row] = t[0], t[1], t[2], t[3]
                    part[4, row] = t[4]
    for g in range(groups):             # the held parts, group by group, in the order held
        for q in range(held_n[g, 0]):
            c3, n, row = held_at[g, q, 0], held_at[g, q, 1], held_at[g, q, 2]
            W[c3, n] += held[g, q, 0]
            Wa[c3, n] += held[g, q, 1]
            pending[row // n1, row % n1] = 1
    held_parts = 0
    for g in range(groups):
        held_parts += held_n[g, 0]
    return add_row_parts(part, tally, row_work), held_parts


@nb.njit(parallel=True, cache=True, nogil=True)
def held_blocks(W, cell, pending, factor, held):
    """Mark in ``held`` uint8 (b_d, b_u, b_v) the blocks of factor^3 cells (b = ceil(n_cells /
    factor) per axis) where some cell holds a packet: a row of W float32 (m, n) (one per cell
    not skipped: ``cell``, int32 (n_d, n_u, n_v)) with a power above 0. Rows (k, i) not marked
    ``pending`` (uint8 (n_d, n_u)) hold none and are not read. One slab of blocks per thread.
    NumPy twin: tests/twins.py (pending_blocks: the blocks whose sums are above 0)."""
    n0, n1, n2 = cell.shape
    n = W.shape[1]
    for kb in nb.prange(held.shape[0]):
        for k in range(kb * factor, min((kb + 1) * factor, n0)):
            for i in range(n1):
                if not pending[k, i]:
                    continue
                for j in range(n2):
                    r = cell[k, i, j]
                    if r >= 0:
                        for o in range(n):
                            if W[r, o] > 0.0:
                                held[kb, i // factor, j // factor] = 1
                                break


@nb.njit(parallel=True, cache=True, nogil=True)
def pending_blocks(W, Wa, cell, pending, factor, slot, P, M):
    """Add to P, M float32 (k, n) the power and moment pending in each ordinate, W, Wa float32
    (m, n) (one row per cell not skipped: ``cell``, int32 (n_d, n_u, n_v)), summed over the
    cells of each block of factor^3 cells in the order of the cells (k, i, j) into the row
    slot[block] (int32 (b_d, b_u, b_v), b = ceil(n_cells / factor) per axis; -1 for a block
    that holds no packet: :func:`held_blocks`): the packets an ordinates walk holds, moved to
    the blocks that hold them (walk.walk_tail). Rows (k, i) not marked ``pending`` (uint8 (n_d,
    n_u)) hold none and are not read. One slab of blocks per thread, so the bits do not depend
    on the threads. NumPy twin: tests/twins.py (pending_blocks)."""
    n0, n1, n2 = cell.shape
    n = W.shape[1]
    for kb in nb.prange(slot.shape[0]):
        for k in range(kb * factor, min((kb + 1) * factor, n0)):
            for i in range(n1):
                if not pending[k, i]:
                    continue
                for j in range(n2):
                    r = cell[k, i, j]
                    if r >= 0:
                        b = slot[kb, i // factor, j // factor]
                        if b >= 0:
                            for o in range(n):
                                P[b, o] += W[r, o]
                                M[b, o] += Wa[r, o]


@nb.njit(parallel=True, cache=True, nogil=True)
def nearest_ordinate_bands(mu, ring, e, axes, frac, cos):
    """The partition of the sphere among ``axes`` (float64 (n, 3) unit vectors, each taking the
    directions nearer to it than to any other) by bands of cosine about the unit axis e (float64
    (3,)): for band b the directions w = mu[b] e + sqrt(1 - mu[b]^2) ring[z] (mu float64 (n_mu,),
    ring float64 (n_azimuth, 3), unit vectors normal to e), each given to the axis n with the
    largest w . axes[n] (the first on a tie); frac[b, n] (float64 (n_mu, n)) the share of band
    b's directions given to n, cos[b, n] their sum of w . axes[n] over n_azimuth (walk.
    ordinate18_table). One band per iteration, its sums in order of z, so the bits do not
    depend on the threads. NumPy twin: tests/twins.py (nearest_ordinate_bands)."""
    n_azimuth = ring.shape[0]
    n = axes.shape[0]
    for b in nb.prange(mu.shape[0]):
        m = mu[b]
        s = math.sqrt(1.0 - m * m)
        count = np.zeros(n)
        total = np.zeros(n)
        for z in range(n_azimuth):
            w0 = m * e[0] + s * ring[z, 0]
            w1 = m * e[1] + s * ring[z, 1]
            w2 = m * e[2] + s * ring[z, 2]
            best = -math.inf
            nearest = 0
            for o in range(n):
                dot = w0 * axes[o, 0] + w1 * axes[o, 1] + w2 * axes[o, 2]
                if dot > best:
                    best = dot
                    nearest = o
            count[nearest] += 1.0
            total[nearest] += best
        for o in range(n):
            frac[b, o] = count[o] / n_azimuth
            cos[b, o] = total[o] / n_azimuth
