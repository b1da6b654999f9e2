"""Slow, readable NumPy twins of the Numba kernels in ``popvol.kernels``, used by the tests on
small grids (tests import this file as ``twins``, beside ``montecarlo`` and ``brute``).

They implement the same equations with whole-array operations and the exact HG formulas of
``popvol.hg`` (no lookup table), so a disagreement points at the kernel's indexing, races or
table, not at the physics. Tallies: [reflected, transmitted, side escaped, absorbed].
"""
from __future__ import annotations

import numpy as np

from popvol import hg

REFLECTED, TRANSMITTED, SIDE_ESCAPED, ABSORBED = 0, 1, 2, 3


def split_exact(W, Wa, rule):
    """Per cell: ((front energy, its a'), (energy to EACH side, a'), (back energy, a')),
    a' before decay: conditional mean cosine (`moment`) or the cell's a (`paper`)."""
    W = np.asarray(W, np.float64)
    a = np.clip(np.divide(Wa, W, out=np.zeros(W.shape), where=W > 0), -1.0, 1.0)
    fr, sd, bk = hg.split_fractions(a)
    mf, ms, mb = hg.conditional_mean_cosines(a) if rule == "moment" else (a, a, a)
    return (W * fr, mf), (W * sd, ms), (W * bk, mb)


def _shift(x, axis, step, periodic):
    """Move x by one cell along ``axis`` (+1 or -1): returns (arrived, fell off). ``arrived``
    is in destination coordinates; ``fell off`` (source coordinates) is what left the grid."""
    if periodic:
        return np.roll(x, step, axis=axis), np.zeros_like(x)
    arrived, lost = np.zeros_like(x), np.zeros_like(x)
    src, dst, edge = [slice(None)] * x.ndim, [slice(None)] * x.ndim, [slice(None)] * x.ndim
    if step == 1:
        src[axis], dst[axis], edge[axis] = slice(0, -1), slice(1, None), slice(-1, None)
    else:
        src[axis], dst[axis], edge[axis] = slice(1, None), slice(0, -1), slice(0, 1)
    arrived[tuple(dst)] = x[tuple(src)]
    lost[tuple(edge)] = x[tuple(edge)]
    return arrived, lost


def _move(e, m, Th, Dh, axis, step, periodic, tally, slot):
    """Send energy e (anisotropy m) one cell along axis. Transmittance Th[src] Th[dst], decay
    Dh[src] Dh[dst]; what leaves the grid crosses half a cell (Th[src]) and is tallied in
    ``slot``. Returns (energy, energy * a) arriving at each destination."""
    e_in, e_out = _shift(e, axis, step, periodic)
    ea_in, _ = _shift(e * m * Dh, axis, step, periodic)
    T = _shift(Th, axis, step, periodic)[0] * Th          # zero where nothing can arrive
    tally[ABSORBED] += np.sum(e_in * (1 - T)) + np.sum(e_out * (1 - Th))
    tally[slot] += np.sum(e_out * Th)
    return e_in * T, ea_in * T * Dh


def hand_over(W, Wa, handover, diffusive, Q):
    """The isotropic stage's hand-over (twin of propagation._hands_over), whole arrays: packets
    with |a| < handover * diffusive (the cells' threshold factors, 0 outside the diffusion
    region) move into Q[0], Q[1]; returns what stays."""
    if handover <= 0:
        return W, Wa
    leave = np.abs(Wa) < handover * diffusive * W
    Q[0] += np.where(leave, W, 0.0)
    Q[1] += np.where(leave, Wa, 0.0)
    return np.where(leave, 0.0, W), np.where(leave, 0.0, Wa)


def jacobi_step(W, Wa, Th, Dh, rule, periodic, inv_area, phi, phia, tally, handover=-1.0,
                diffusive=None, Q=None):
    """One wavefront iteration (twin of kernels.propagation.jacobi_send + jacobi_gather):
    accumulate the wave into phi/phia, send every cell's packet to its 6 neighbours.
    Returns the next wave (W, Wa), float64."""
    Th, Dh = Th.astype(np.float64), Dh.astype(np.float64)
    W, Wa = hand_over(np.asarray(W, np.float64), np.asarray(Wa, np.float64), handover, diffusive, Q)
    phi += W * inv_area
    phia += Wa * inv_area
    (ef, mf), (es, ms), (eb, mb) = split_exact(W, Wa, rule)
    moves = [(0, +1, ef, mf, TRANSMITTED, False), (0, -1, eb, mb, REFLECTED, False)]
    moves += [(axis, step, es, ms, SIDE_ESCAPED, periodic) for axis in (1, 2) for step in (1, -1)]
    W_new, Wa_new = np.zeros(W.shape), np.zeros(W.shape)
    for axis, step, e, m, slot, wrap in moves:
        e_in, ea_in = _move(e, m, Th, Dh, axis, step, wrap, tally, slot)
        W_new += e_in
        Wa_new += ea_in
    return W_new, Wa_new


def binned_step(W, ab, shares, Th, Dh, periodic, inv_area, phi, phia, tally, handover=-1.0,
                diffusive=None, Q=None):
    """One iteration of the binned wavefront (twin of kernels.binned.binned_send + binned_gather):
    W (n_b, n_d, n_u, n_v) holds each cell's power in the anisotropy bins ``ab``; every bin's
    power is split by its row of ``shares`` (front, side, back, and their outgoing
    anisotropies), moved one cell (Th, Dh of sender and receiver) and its energy and first
    moment split between the two bins around its new anisotropy. Returns the next W, float64."""
    Th, Dh = Th.astype(np.float64), Dh.astype(np.float64)
    W = np.asarray(W, np.float64)
    phi += W.sum(axis=0) * inv_area
    phia += np.tensordot(ab, W, axes=1) * inv_area
    W_new = np.zeros(W.shape)
    moves = [(0, +1, 0, TRANSMITTED, False), (0, -1, 2, REFLECTED, False)]
    moves += [(axis, step, 1, SIDE_ESCAPED, periodic) for axis in (1, 2) for step in (1, -1)]
    n = len(ab)
    for b in range(n):
        for axis, step, p, slot, wrap in moves:
            e_in, ea_in = _move(W[b] * shares[b, p], np.full(W[b].shape, shares[b, 3 + p]), Th, Dh,
                                axis, step, wrap, tally, slot)
            a = np.divide(ea_in, e_in, out=np.zeros(e_in.shape), where=e_in > 0)
            if handover > 0:
                leave = (e_in > 0) & (np.abs(a) < handover * diffusive)
                Q[0] += np.where(leave, e_in, 0.0)
                Q[1] += np.where(leave, ea_in, 0.0)
                e_in = np.where(leave, 0.0, e_in)
            lower = np.clip(np.floor((a + 1.0) * (n - 1) / 2), 0, n - 2).astype(int)
            lam = (a - ab[lower]) / (ab[lower + 1] - ab[lower])
            for t in range(n - 1):
                at = lower == t
                W_new[t] += np.where(at, e_in * (1.0 - lam), 0.0)
                W_new[t + 1] += np.where(at, e_in * lam, 0.0)
    return W_new


def _ahead(x, axis, step):
    """x at each cell's neighbour one cell along ``axis`` (``step`` +1 or -1), in the cell's own
    coordinates; 1 where the neighbour is outside the grid."""
    pad = [(0, 0)] * x.ndim
    pad[axis] = (0, 1) if step > 0 else (1, 0)
    padded = np.pad(x, pad, constant_values=1.0)
    idx = [slice(None)] * x.ndim
    idx[axis] = slice(1, None) if step > 0 else slice(0, -1)
    return padded[tuple(idx)]


def _escaped(tally, shape, dst, e) -> bool:
    """Whether cell ``dst`` (a tuple) lies outside a grid of ``shape``; if so ``e`` is tallied
    where it left: through the face k = 0 (reflected), the far face (transmitted) or a lateral
    face (side)."""
    if dst[0] < 0:
        tally[REFLECTED] += e
    elif dst[0] >= shape[0]:
        tally[TRANSMITTED] += e
    elif not all(0 <= c < n for c, n in zip(dst[1:], shape[1:])):
        tally[SIDE_ESCAPED] += e
    else:
        return False
    return True


def _scattered_lobe(a, S, D):
    """(a_s, the cone partition of HG_a_s about e_o): a_s = a (D - S) / (1 - S), the anisotropy
    of the part of a packet that scatters on a transfer whose no-scatter share is S and whose
    decay is D; the partition as (front share, side share (each), back share, m_front, m_back,
    m_wedge) of popvol.hg (float64 arrays)."""
    scattered = 1.0 - S
    a_s = np.clip(np.divide(a * (D - S), scattered, out=np.zeros(np.shape(a)), where=scattered > 0), -1.0, 1.0)
    return a_s, _cone_lobe(a_s)


def _cone_parts(o, cone):
    """[(ordinate n, share, outgoing anisotropy)] of the cone partition about e_o (front on in
    o with m_front, back into o ^ 1 with -m_back, each side into its own ordinate n with the
    wedge's mean cosine)."""
    fr, sd, bk, mf, mb, mj = cone
    return [(n,) + ((fr, mf) if n == o else (bk, -mb) if n == o ^ 1 else (sd, mj)) for n in range(6)]


def _scattered_in(W, Wa, o, cone, at=None):
    """Light that scattered on its way into a cell along e_o (slot 6 + o of W, Wa), split by the
    cone partition about e_o (``cone``, of its a_s) into the cell's own ordinates. Whole arrays,
    or the one cell ``at`` (a tuple); in place."""
    idx = (slice(None),) * 3 if at is None else at
    x = W[(6 + o,) + idx].copy()
    W[(6 + o,) + idx] = 0.0
    Wa[(6 + o,) + idx] = 0.0
    for n, share, m in _cone_parts(o, cone):
        W[(n,) + idx] += x * share
        Wa[(n,) + idx] += x * share * m


def ordinates_step(W, Wa, Th, Sh, Dh, inv_area, phi, F, tally):
    """One iteration of the six-ordinate Jacobi wavefront, every pending packet sent one cell:
    the fixed point that the kernel's sweeps (kernels.ordinates.ordinates_sweep) reach but for
    the order in which packets merge (tests/test_ordinates.py).
    W, Wa (12, n_d, n_u, n_v): power and power times anisotropy pending in ordinate o = 0..5
    (+d, -d, +u, -u, +v, -v) of each cell, at its centre, then (slot 6 + o) the light that
    scattered in the cell on its way in along e_o, with its a_s. First that light splits by the
    cone partition about e_o into the cell's ordinates. Then a packet of lobe HG_a about e_o leaves through its sender's half
    step Th[src]; of that, Sh[src] Sh[dst] crosses to the neighbour dst along e_o unscattered
    (Th[dst]) and keeps a; 1 - Sh[src] scatters in the sender's half and splits from there (parts moved one cell, Th of sender and neighbour); Sh[src] (1 - Sh[dst])
    scatters in the receiver's half and crosses into it (Th[dst]), into its slot 6 + o; both
    with a_s = a (D - S) / (1 - S) (D = Dh[src] Dh[dst], S = Sh[src] Sh[dst]). Accumulates phi
    and F (3, ...), the first moment in the domain's frame. Returns the next (W, Wa), float64."""
    Th, Sh, Dh = (x.astype(np.float64) for x in (Th, Sh, Dh))
    W, Wa = np.array(W, np.float64), np.array(Wa, np.float64)
    for o in range(6):
        a_s = np.clip(np.divide(Wa[6 + o], W[6 + o], out=np.zeros(Th.shape), where=W[6 + o] > 0), -1.0, 1.0)
        _scattered_in(W, Wa, o, _cone_lobe(a_s))
    W_new, Wa_new = np.zeros(W.shape), np.zeros(W.shape)
    ones = np.ones(Th.shape)
    for o in range(6):
        axis, step = o // 2, 1 - 2 * (o % 2)
        sign = float(step)
        phi += W[o] * inv_area
        F[axis] += sign * Wa[o] * inv_area
        a = np.clip(np.divide(Wa[o], W[o], out=np.zeros(W[o].shape), where=W[o] > 0), -1.0, 1.0)
        Sh_dst = _ahead(Sh, axis, step)
        S = Sh * Sh_dst
        a_s, cone = _scattered_lobe(a, S, Dh * _ahead(Dh, axis, step))

        def send(e, m, n, q):
            ax, st = n // 2, 1 - 2 * (n % 2)
            slot = (TRANSMITTED if st > 0 else REFLECTED) if ax == 0 else SIDE_ESCAPED
            e_in, ea_in = _move(e, m, Th, ones, ax, st, False, tally, slot)
            W_new[q] += e_in
            Wa_new[q] += ea_in

        send(W[o] * S, a, o, o)                                   # unscattered, on along e_o
        e1 = W[o] * (1.0 - Sh)                                    # scattered in the sender's half
        for n, share, m in _cone_parts(o, cone):
            send(e1 * share, m, n, n)
        # scattered in the receiver's half: into it (both half steps), its slot 6 + o
        send(W[o] * Sh * (1.0 - Sh_dst), a_s, o, 6 + o)
    return W_new, Wa_new


def _cone_lobe(a_s):
    """The cone partition of HG_a_s (:func:`_scattered_lobe`'s second value)."""
    fr, sd, bk = hg.split_fractions(a_s)
    mf, _, mb = hg.conditional_mean_cosines(a_s)
    return fr, sd, bk, mf, mb, hg.side_wedge_mean_cosine(a_s)


def sends_ahead(offset, forward_d, forward_u, forward_v) -> bool:
    """Whether the cell at ``offset`` (3 ints) from a cell comes after it in a sweep's order
    (k, then i, then j, each increasing if its ``forward_*``): the ordinates an upwind sweep
    sends."""
    a, b, c = (x if f else -x for x, f in zip(offset, (forward_d, forward_u, forward_v)))
    return a > 0 or (a == 0 and (b > 0 or (b == 0 and c > 0)))


def ordinates_sweep(W, Wa, Th, Sh, Dh, inv_area, phi, F, w_min, forward_d, forward_u, forward_v, tally,
                    runs=None, upwind=False):
    """One Gauss-Seidel sweep of the six-ordinate walk (twin of kernels.ordinates.ordinates_sweep),
    cell by cell, in place, in float64. Cells in order of k, i, j (each increasing if its
    ``forward_*``); at each cell first the light that scattered on its way in (slots 6..11, as
    ordinates_step's), then the ordinates o = 0..5 (+d, -d, +u, -u, +v, -v) in turn: a packet
    above ``w_min`` is taken, visits (phi, F) and is sent as ordinates_step's (exact HG shares):
    its parts moved into their pending slots, what leaves the grid tallied; a part sent into a
    skipped cell (``runs[q]`` > 0 there, :func:`skip_runs`; None: none) crosses the run of them
    ahead along its ordinate q to the cell after it. With ``upwind`` only the ordinates toward
    cells later in the order are sent (:func:`sends_ahead`); the others stay pending. Returns
    the number of packets sent."""
    n0, n1, n2 = Th.shape
    Th, Sh, Dh = (x.astype(np.float64) for x in (Th, Sh, Dh))
    sent_packets = 0

    def inside(c):
        return 0 <= c[0] < n0 and 0 <= c[1] < n1 and 0 <= c[2] < n2

    def neighbour(c, n):
        c = list(c)
        c[n // 2] += 1 - 2 * (n % 2)
        return tuple(c)

    def deliver(e, m, q, dst):
        if runs is not None and q < 6 and inside(dst) and runs[(q,) + dst] > 0:
            c = list(dst)                                  # a skipped cell: across its run
            c[q // 2] += (1 - 2 * (q % 2)) * int(runs[(q,) + dst])
            dst = tuple(c)
        if not _escaped(tally, Th.shape, dst, e):
            th2 = Th[dst]
            tally[ABSORBED] += e * (1.0 - th2)
            W[(q,) + dst] += e * th2
            Wa[(q,) + dst] += e * th2 * m

    for k in (range(n0) if forward_d else range(n0 - 1, -1, -1)):
        for i in (range(n1) if forward_u else range(n1 - 1, -1, -1)):
            for j in (range(n2) if forward_v else range(n2 - 1, -1, -1)):
                for o in range(6):
                    x = float(W[6 + o, k, i, j])
                    if x > 0.0:
                        a_s = np.array(np.clip(Wa[6 + o, k, i, j] / x, -1.0, 1.0))
                        _scattered_in(W, Wa, o, _cone_lobe(a_s), at=(k, i, j))
                for o in range(6):
                    w = float(W[o, k, i, j])
                    if w <= w_min or (upwind and not sends_ahead(neighbour((0, 0, 0), o), forward_d, forward_u,
                                                                  forward_v)):
                        continue
                    wa = float(Wa[o, k, i, j])
                    W[o, k, i, j] = Wa[o, k, i, j] = 0.0
                    sent_packets += 1
                    sign = 1.0 - 2.0 * (o % 2)
                    phi[k, i, j] += w * inv_area
                    F[o // 2, k, i, j] += sign * wa * inv_area
                    ahead = neighbour((k, i, j), o)
                    sh, sh2 = Sh[k, i, j], (Sh[ahead] if inside(ahead) else 1.0)
                    D = Dh[k, i, j] * (Dh[ahead] if inside(ahead) else 1.0)
                    a = np.clip(wa / w, -1.0, 1.0)
                    sent = w * Th[k, i, j]
                    tally[ABSORBED] += w - sent
                    deliver(sent * sh * sh2, a, o, ahead)
                    a_s, cone = _scattered_lobe(np.array([a]), np.array([sh * sh2]), np.array([D]))
                    a_s = float(a_s[0])
                    e = sent * (1.0 - sh)                      # scattered in the sender's half
                    if e > 0.0:
                        for n, share, m in _cone_parts(o, cone):
                            deliver(e * float(np.ravel(share)[0]), float(np.ravel(m)[0]), n,
                                    neighbour((k, i, j), n))
                    if inside(ahead):                          # scattered in the receiver's half
                        deliver(sent * sh * (1.0 - sh2), a_s, 6 + o, ahead)
    return sent_packets


def lattice18_partition(a: float, o: int, n_points: int = 60_000) -> tuple[np.ndarray, np.ndarray]:
    """(share float64 (18,), mean cosine float64 (18,)): the lobe HG_a about ordinate o's
    direction split among the 18 ordinates of the eighteen-ordinate walk (popvol.walk.ORDINATES18),
    each taking the directions nearer to it than to any other, with each part's mean cosine
    about its own ordinate. By an independent quadrature of the whole sphere (a Fibonacci
    spiral of ``n_points`` directions, the exact HG density), not the kernel's table."""
    from popvol.walk import ORDINATES18
    axes = ORDINATES18 / np.linalg.norm(ORDINATES18, axis=1)[:, None]
    dirs, nearest, own = _fibonacci_bins(n_points)
    if abs(a) >= 1.0:                       # a delta along +-e_o
        q = o if a > 0 else int(np.flatnonzero((ORDINATES18 == -ORDINATES18[o]).all(axis=1))[0])
        share, mean = np.zeros(18), np.zeros(18)
        share[q], mean[q] = 1.0, 1.0
        return share, mean
    w = hg.f_hg(dirs @ axes[o], a)
    share = np.bincount(nearest, w, 18)
    mean = np.divide(np.bincount(nearest, w * own, 18), share, out=np.zeros(18), where=share > 0)
    return share / share.sum(), mean


_FIBONACCI = {}


def _fibonacci_bins(n):
    """(directions (n, 3), the ordinate nearest each, its cosine to that ordinate), cached."""
    if n not in _FIBONACCI:
        from popvol.walk import ORDINATES18
        axes = ORDINATES18 / np.linalg.norm(ORDINATES18, axis=1)[:, None]
        i = np.arange(n) + 0.5
        z = 1.0 - 2.0 * i / n
        t = i * np.pi * (3.0 - np.sqrt(5.0))
        r = np.sqrt(1.0 - z * z)
        dirs = np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)
        dots = dirs @ axes.T
        nearest = np.argmax(dots, axis=1)
        _FIBONACCI[n] = (dirs, nearest, dots[np.arange(n), nearest])
    return _FIBONACCI[n]


def nearest_ordinate_bands(mu, ring, e, axes) -> tuple[np.ndarray, np.ndarray]:
    """(frac, cos) float64 (n_mu, n): kernels.ordinates18.nearest_ordinate_bands by whole
    arrays: every direction w = mu[b] e + sqrt(1 - mu[b]^2) ring[z] given to the axis with the
    largest w . axes[n], counted and its cosine summed per band, over n_azimuth."""
    dirs = mu[:, None, None] * e + np.sqrt(1.0 - mu ** 2)[:, None, None] * ring[None]
    dots = np.einsum("mzk,nk->mzn", dirs, axes)
    nearest = np.argmax(dots, axis=2)
    own = np.take_along_axis(dots, nearest[..., None], axis=2)[..., 0]
    n_mu, n_azimuth, n = len(mu), len(ring), len(axes)
    index = (np.arange(n_mu)[:, None] * n + nearest).ravel()
    frac = np.bincount(index, minlength=n_mu * n).reshape(n_mu, n) / n_azimuth
    cos = np.bincount(index, own.ravel(), minlength=n_mu * n).reshape(n_mu, n) / n_azimuth
    return frac, cos


def ordinates18_sweep(W, Wa, Th, Sh, Dh, inv_area, phi, F, w_min, forward_d, forward_u, forward_v, tally,
                      upwind=False):
    """One Gauss-Seidel sweep of the eighteen-ordinate walk (twin of
    kernels.ordinates18.ordinates18_sweep), cell by cell, in place, in float64, with each
    packet's scattered lobe split by :func:`lattice18_partition` at its own a_s (no table).
    W, Wa (n_d, n_u, n_v, 18). Cells in order of k, i, j (each increasing if its
    ``forward_*``); at each cell the ordinates o = 0..17 in turn: a packet above ``w_min`` is
    taken, visits (phi, F) with its path L = |offs[o]| (in cells: 1 on a face, sqrt 2 on an
    edge) and leaves through the sender's half step Th^L. Of that, S = Sh[src]^L Sh[dst]^L
    crosses to dst = src + offs[o] unscattered (Th[dst]^L) and keeps its a; the sender's share
    1 - Sh[src]^L scatters and its parts go to the sender's neighbours (each part n after that
    neighbour's Th^|offs[n]|); the receiver's share Sh[src]^L (1 - Sh[dst]^L) crosses into dst
    (Th[dst]^L) and splits there into dst's own ordinates; both with a_s = a (D - S) / (1 - S),
    D = (Dh[src] Dh[dst])^L. What leaves the grid is tallied. With ``upwind`` only the
    ordinates toward cells later in the order are sent (:func:`sends_ahead`); the others stay
    pending. Returns the packets sent."""
    from popvol.walk import ORDINATES18 as offs
    n0, n1, n2 = Th.shape
    Th, Sh, Dh = (x.astype(np.float64) for x in (Th, Sh, Dh))
    sent_packets = 0

    def inside(c):
        return 0 <= c[0] < n0 and 0 <= c[1] < n1 and 0 <= c[2] < n2

    def deliver(e, m, q, dst):
        if not _escaped(tally, Th.shape, dst, e):
            th = Th[dst] ** np.linalg.norm(offs[q])
            tally[ABSORBED] += e * (1.0 - th)
            W[dst + (q,)] += e * th
            Wa[dst + (q,)] += e * th * m

    for k in (range(n0) if forward_d else range(n0 - 1, -1, -1)):
        for i in (range(n1) if forward_u else range(n1 - 1, -1, -1)):
            for j in (range(n2) if forward_v else range(n2 - 1, -1, -1)):
                cell = (k, i, j)
                for o in range(18):
                    w = float(W[cell + (o,)])
                    if w <= w_min or (upwind and not sends_ahead(offs[o], forward_d, forward_u, forward_v)):
                        continue
                    wa = float(Wa[cell + (o,)])
                    W[cell + (o,)] = Wa[cell + (o,)] = 0.0
                    sent_packets += 1
                    L = float(np.linalg.norm(offs[o]))
                    phi[cell] += w * L * inv_area
                    F[:, k, i, j] += wa * L * offs[o] / L * inv_area
                    a = float(np.clip(wa / w, -1.0, 1.0))
                    sent = w * Th[cell] ** L
                    tally[ABSORBED] += w - sent
                    dst = tuple(int(x) for x in np.add(cell, offs[o]))
                    sh = Sh[cell] ** L
                    sh_dst = Sh[dst] ** L if inside(dst) else 1.0
                    D = (Dh[cell] * (Dh[dst] if inside(dst) else 1.0)) ** L
                    S = sh * sh_dst
                    deliver(sent * S, a, o, dst)
                    if S >= 1.0:
                        continue
                    a_s = a * (D - S) / (1.0 - S)
                    share, mean = lattice18_partition(a_s, o)
                    e = sent * (1.0 - sh)                      # scattered in the sender's half
                    for n in range(18):
                        deliver(e * share[n], mean[n], n, tuple(int(x) for x in np.add(cell, offs[n])))
                    if inside(dst):                            # scattered in the receiver's half
                        th = Th[dst] ** L
                        e = sent * sh * (1.0 - sh_dst)
                        tally[ABSORBED] += e * (1.0 - th)
                        W[dst] += e * th * share
                        Wa[dst] += e * th * share * mean
    return sent_packets


def sweep(R, Ra, Th, Dh, rule, periodic, forward, flip, w_min, inv_area, phi, phia, tally,
          band_rows=16, handover=-1.0, diffusive=None, Q=None, a_stream=1.0):
    """One Gauss-Seidel sweep (twin of kernels.propagation.sweep), cell by cell, in place.

    (R, Ra) hold what has arrived at each cell, before the cell's own half step. Visiting order:
    slices along +d (``forward``) or -d; in each slice the bands of ``band_rows`` rows of u one
    after the other (the kernel runs them in parallel: they touch disjoint rows), rows and
    columns increasing, or decreasing if ``flip``. A side part that crosses into another band
    waits until the end of the sweep. Cells whose pending energy is <= w_min keep it. In an
    empty cell (Th = Dh = 1) a packet with a >= ``a_stream`` goes on whole to the front
    neighbour, keeping its a (with ``a_stream`` = 1 that is collimated light, which the exact
    split sends all to the front anyway).
    Returns the energy still pending.
    """
    n0, n1, n2 = R.shape
    edges = list(range(0, n1, band_rows)) + [n1]
    if len(edges) > 2 and edges[-1] - edges[-2] < 2:
        edges.pop(-2)
    later = []                                  # (k, i, j, e, e*a) crossing a band edge
    for k in (range(n0) if forward else range(n0 - 1, -1, -1)):
        for b in range(len(edges) - 1):
            rows = range(edges[b], edges[b + 1])
            for i in (reversed(rows) if flip else rows):
                for j in (range(n2 - 1, -1, -1) if flip else range(n2)):
                    if R[k, i, j] <= w_min:
                        continue
                    th, dh = float(Th[k, i, j]), float(Dh[k, i, j])
                    w = R[k, i, j] * th
                    wa = Ra[k, i, j] * th * dh
                    tally[ABSORBED] += R[k, i, j] * (1 - th)          # the receiver's half step
                    R[k, i, j] = Ra[k, i, j] = 0.0
                    if w <= 0.0:                                      # all absorbed
                        continue
                    if handover > 0 and abs(wa) < handover * diffusive[k, i, j] * w:
                        Q[0, k, i, j] += w
                        Q[1, k, i, j] += wa
                        continue
                    tally[ABSORBED] += w * (1 - th)                   # the sender's
                    phi[k, i, j] += w * inv_area
                    phia[k, i, j] += wa * inv_area
                    if th == 1.0 and dh == 1.0 and wa >= a_stream * w:   # streams on unsplit
                        if k + 1 < n0:
                            R[k + 1, i, j] += w
                            Ra[k + 1, i, j] += wa
                        else:
                            tally[TRANSMITTED] += w
                        continue
                    (ef, mf), (es, ms), (eb, mb) = split_exact(w, wa, rule)
                    for kn, e, m, slot in ((k + 1, ef, mf, TRANSMITTED), (k - 1, eb, mb, REFLECTED)):
                        if 0 <= kn < n0:
                            R[kn, i, j] += e * th
                            Ra[kn, i, j] += e * m * th * dh
                        else:
                            tally[slot] += e * th
                    for di, dj in ((0, -1), (0, 1), (-1, 0), (1, 0)):
                        ii, jj = i + di, j + dj
                        if not (0 <= ii < n1 and 0 <= jj < n2) and not periodic:
                            tally[SIDE_ESCAPED] += es * th
                            continue
                        part = (es * th, es * ms * th * dh)
                        crosses = not edges[b] <= ii < edges[b + 1]   # before wrapping
                        ii, jj = ii % n1, jj % n2
                        if crosses:
                            later.append((k, ii, jj) + part)
                        else:
                            R[k, ii, jj] += part[0]
                            Ra[k, ii, jj] += part[1]
    for k, i, j, e, ea in later:
        R[k, i, j] += e
        Ra[k, i, j] += ea
    return float(R.sum(dtype=np.float64))


def skip_runs(skip):
    """Twin of kernels.cells.skip_runs: int (6,) + skip's shape, at each cell where ``skip``
    the number of skipped cells in a row from it across face o (+d, -d, +u, -u, +v, -v),
    itself included; 0 elsewhere. Each count by walking the line cell by cell."""
    skip = np.asarray(skip, bool)
    runs = np.zeros((6,) + skip.shape, int)
    for o in range(6):
        axis, step = o // 2, 1 - 2 * (o % 2)
        for start in np.argwhere(skip):
            c, n = list(start), 0
            while 0 <= c[axis] < skip.shape[axis] and skip[tuple(c)]:
                n += 1
                c[axis] += step
            runs[(o,) + tuple(start)] = n
    return runs


def trilinear(grid, q):
    """Twin of kernels.sampling.trilinear: grid (nx, ny, nz) at continuous indices q (..., 3);
    zero outside the cells [-1/2, n - 1/2], clamped to the edge within the outer half cell."""
    q = np.asarray(q, np.float64)
    n = np.asarray(grid.shape)
    inside = np.all((q >= -0.5) & (q <= n - 0.5), axis=-1)
    qc = np.clip(q, 0, n - 1)
    i0 = np.minimum(np.floor(qc).astype(int), np.maximum(n - 2, 0))
    f = qc - i0
    i1 = np.minimum(i0 + 1, n - 1)
    out = np.zeros(q.shape[:-1])
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                idx = tuple((i1 if c else i0)[..., a] for a, c in enumerate((cx, cy, cz)))
                w = np.prod([f[..., a] if c else 1 - f[..., a] for a, c in enumerate((cx, cy, cz))], axis=0)
                out += w * grid[idx]
    return np.where(inside, out, 0.0)


def walk_lobes(p, pa, p_dir, mu, g):
    """Twin of kernels.render.walk_lobes, whole arrays: phi_dir f_hg(mu; g) + (phi - phi_dir)
    f_hg(mu; g A_rest), the unscattered part (a delta lobe, at most phi) lit apart."""
    p, pa, p_dir, mu, g = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (p, pa, p_dir, mu, g)))
    p_dir = np.where(p > 0, np.minimum(p_dir, p), 0.0)
    val = np.where(p_dir > 0, p_dir * hg.f_hg(mu, np.clip(g, -0.9999, 0.9999)), 0.0)
    rest, rest_a = p - np.maximum(p_dir, 0), pa - np.maximum(p_dir, 0)
    A = np.divide(rest_a, rest, out=np.zeros(rest.shape), where=rest > 0)
    return val + np.where(rest > 0, rest * hg.f_hg(mu, np.clip(g * A, -0.9999, 0.9999)), 0.0)


def diffuse_lobe(pd, J, d, g, cap=0.5):
    """Twin of kernels.render.diffuse_lobe, whole arrays: phi_d f_hg(-d . J/|J|; g min(|J| /
    phi_d, cap)), phi_d / 4 pi where J = 0, 0 where phi_d <= 0; J and d (..., 3)."""
    pd, g = np.asarray(pd, np.float64), np.asarray(g, np.float64)
    J = np.asarray(J, np.float64)
    jn = np.linalg.norm(J, axis=-1)
    mu = -np.sum(J * d, axis=-1) / np.where(jn > 0, jn, 1.0)
    A = np.minimum(jn / np.where(pd > 0, pd, 1.0), cap)
    lobe = np.where(jn > 0, hg.f_hg(mu, np.clip(g * A, -0.9999, 0.9999)), 1 / (4 * np.pi))
    return np.where(pd > 0, pd * lobe, 0.0)


def _power(solution, l, c, n_ch):
    """Light l's RGB power lighting channel c of its fields (a grey solution's one channel lights all)."""
    return solution.irradiance[l] if n_ch == 1 else np.eye(3)[c] * solution.irradiance[l]


def in_scattering_source(scene, solution):
    """Twin of kernels.source.in_scattering_source: float64 (nx, ny, nz, 3), at the voxels the
    renderer reads (pipeline.voxels_seen) L_s / sigma_s toward the camera of every term lit on
    the medium's grid (the suns' walk and diffuse lobes, the point lights' diffuse lobes), with
    the voxel's own view direction (x - c) / |x - c| and g; 0 elsewhere."""
    from popvol.pipeline import voxels_seen
    med = scene.medium
    d = _voxel_centres(med) - np.asarray(scene.camera.origin, float)
    d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    return np.where(voxels_seen(med.density)[..., None], _grid_lit(scene, solution, d), 0.0)


def _voxel_centres(med):
    return med.origin + np.moveaxis(np.indices(med.shape), 0, -1) * med.voxel_size


def _grid_lit(scene, solution, d, patterns=False):
    """L_s / sigma_s (nx, ny, nz, 3) at the voxel centres along the rays d (nx, ny, nz, 3) of
    the terms lit on the medium's grid (the suns' walk lobes, every diffuse lobe). With
    ``patterns`` (the gathered last bounce's rule), an environment region whose walk kept its
    unscattered lobe (Solution.lobe_a0 > 0), in a medium of one g, is lit by that lobe in its
    region's pattern (:func:`region_pattern_lit`) and by the rest of its light as one lobe about
    the rest's flux."""
    med = scene.medium
    g = med.g.astype(np.float64) if med.g_per_voxel else np.full(med.shape, float(med.g))
    n_ch = solution.phi.shape[1]
    out = np.zeros(med.shape + (3,))
    for l in range(len(solution.is_point)):
        region = (patterns and solution.lobe_a0 is not None and solution.lobe_a0[l] > 0
                  and not med.g_per_voxel)
        for c in range(n_ch):
            val = np.zeros(med.shape)
            if not solution.is_point[l]:
                mu = -(d @ solution.directions[l])
                val += walk_lobes(solution.phi[l, c], solution.phia[l, c], solution.direct[l, c], mu, g)
            if region:
                pd = solution.phid[l, c].astype(np.float64)
                pu = np.clip(solution.direct[l, c], 0.0, np.maximum(pd, 0.0))
                J = np.moveaxis(solution.flux[l, c], 0, -1) - (solution.lobe_a0[l] * pu)[..., None] * \
                    solution.directions[l]
                val += pu * region_pattern_lit(scene, l, d, float(med.g))
                val += diffuse_lobe(pd - pu, J, d, g, 1.0)
            elif solution.phid.shape[0]:
                val += diffuse_lobe(solution.phid[l, c], np.moveaxis(solution.flux[l, c], 0, -1), d, g,
                                    solution.lobe_cap[l])
            out += val[..., None] * _power(solution, l, c, n_ch)
    return out


def region_pattern_lit(scene, l, d, g):
    """(d's shape without its last axis): what a unit fluence of environment region l's
    unscattered light scatters along the rays d (..., 3), per steradian: the region's texels'
    luminance times solid angle, normalised to sum to 1, each scattering its light (travelling
    away from its texel's direction) by f_hg into -d. Texel by texel (docs/METHOD.md Eq. 26a)."""
    from popvol.envmap import texel_geometry
    env = scene.environment.radiance.astype(np.float64)
    toward, omega = texel_geometry(*env.shape[:2])
    mask = scene.lights[l].texels
    w = (0.2126 * env[..., 0] + 0.7152 * env[..., 1] + 0.0722 * env[..., 2]) * omega * mask
    w, travel = w[mask], -toward[mask]
    rays, where = np.unique(-np.asarray(d, np.float64).reshape(-1, 3), axis=0, return_inverse=True)
    val = np.array([np.sum(w * hg.f_hg(np.clip(travel @ x, -1.0, 1.0), g)) for x in rays]) / w.sum()
    return val[where.ravel()].reshape(np.shape(d)[:-1])


def _bilinear_slice(buf, u, v):
    """buf (nu, nv) at the continuous index (u, v): 0 outside [-1/2, n - 1/2], clamped to the
    edge in the outer half cell (kernels/gather.py)."""
    nu, nv = buf.shape
    if not (-0.5 <= u <= nu - 0.5 and -0.5 <= v <= nv - 0.5):
        return 0.0
    u, v = min(max(u, 0.0), nu - 1.0), min(max(v, 0.0), nv - 1.0)
    i0, j0 = min(int(u), max(nu - 2, 0)), min(int(v), max(nv - 2, 0))
    i1, j1 = min(i0 + 1, nu - 1), min(j0 + 1, nv - 1)
    fu, fv = u - i0, v - j0
    return ((1 - fu) * ((1 - fv) * buf[i0, j0] + fv * buf[i0, j1])
            + fu * ((1 - fv) * buf[i1, j0] + fv * buf[i1, j1]))


def _unscattered_lit(solution, l):
    """(nx, ny, nz, 3): directional light l's unscattered lobe's weight, without its angular
    factor: phi_dir (at most phi) times the light's power, summed over its field channels (the
    part of :func:`_grid_lit` that is phi_dir f_hg(mu; g), :func:`walk_lobes`)."""
    n_ch = solution.phi.shape[1]
    out = 0.0
    for c in range(n_ch):
        p = solution.phi[l, c].astype(np.float64)
        p_dir = np.where(p > 0, np.minimum(solution.direct[l, c], p), 0.0)
        out = out + np.maximum(p_dir, 0.0)[..., None] * _power(solution, l, c, n_ch)
    return out


def default_sun(scene, solution):
    """The light gathered apart (renderer.separated_sun, the rule written again): the directional
    light with the most unscattered light, where g is the same everywhere (to 1e-6 of itself);
    None without one."""
    g = np.asarray(scene.medium.g, np.float64)
    if np.ptp(g) > 1e-6 * abs(float(g.flat[0])):
        return None
    power = [0.0 if solution.is_point[l] else float(_unscattered_lit(solution, l).sum())
             for l in range(len(solution.is_point))]
    return int(np.argmax(power)) if max(power, default=0.0) > 0 else None


_GAUSS = np.polynomial.legendre.leggauss(32)


def _linear_source(q_up, s_up, q_v, s_v, path):
    """The light a segment of ``path`` emits toward its end: int_0^path sigma(s) J(s) exp(-(tau -
    tau(s))) ds, with sigma_t linear from s_up to s_v, tau(s) the optical depth from the upstream
    end and the source function J = q / sigma_t linear in it (where sigma_t is 0 at one end, the
    other end's J), by Gauss-Legendre quadrature in s (the kernel's closed form,
    kernels.gather._segment, is held against this)."""
    j_v = q_v / s_v if s_v > 0 else 0.0
    j_up = q_up / s_up if s_up > 0 else j_v
    j_v = j_v if s_v > 0 else j_up
    x, wt = _GAUSS
    s = 0.5 * path * (x + 1.0)
    sigma = s_up + (s_v - s_up) * s / path
    tau_s = s_up * s + 0.5 * (s_v - s_up) * s * s / path
    tau = 0.5 * (s_up + s_v) * path
    if tau <= 0:
        return 0.0
    J = j_up + (j_v - j_up) * tau_s / tau
    return float(0.5 * path * np.sum(wt * sigma * J * np.exp(-(tau - tau_s))))


def _transport(q, sig, w, med, entering):
    """The radiance L (nx, ny, nz, 3) reaching each voxel along w from the emission per unit
    length q (nx, ny, nz, 3) through sigma_t ``sig``, slice by slice (:func:`gathered_source`)."""
    a = int(np.argmax(np.abs(w)))
    b, c = [k for k in range(3) if k != a]
    ell = med.voxel_size[a] / abs(w[a])
    ob, oc = -ell * w[b] / med.voxel_size[b], -ell * w[c] / med.voxel_size[c]
    # the arrays with the sweep axis first and the other two in increasing order
    q_s, sig_s = np.moveaxis(q, a, 0), np.moveaxis(sig, a, 0)
    L = np.zeros(q_s.shape)
    order = range(q_s.shape[0]) if w[a] > 0 else range(q_s.shape[0] - 1, -1, -1)
    for step, s in enumerate(order):
        prev = s - 1 if w[a] > 0 else s + 1
        for p in range(q_s.shape[1]):
            for r in range(q_s.shape[2]):
                for ch in range(3):
                    sv, qv = sig_s[s, p, r, ch], q_s[s, p, r, ch]
                    u, v = p + ob, r + oc
                    if step == 0:
                        l_up, q_up, s_up, path = entering[ch], qv, sv, 0.5 * ell
                    elif not (-0.5 <= u <= L.shape[1] - 0.5 and -0.5 <= v <= L.shape[2] - 0.5):
                        l_up, q_up, s_up, path = entering[ch], 0.0, 0.0, ell    # from outside the grid
                    else:
                        l_up, q_up, s_up = (_bilinear_slice(f[prev, :, :, ch], u, v) for f in (L, q_s, sig_s))
                        path = ell
                    tau = 0.5 * (s_up + sv) * path
                    L[s, p, r, ch] = l_up * np.exp(-tau) + _linear_source(q_up, s_up, qv, sv, path)
    return np.moveaxis(L, 0, a)


def gathered_source(scene, solution, dirs, weights, boundary=None, sun="default"):
    """Twin of kernels.gather.gathered_source for directional lights (the point lights' walk
    lobes are not lit here), divided by its phase quadrature: float64 (nx, ny, nz, 3), the light
    reaching each voxel from each direction w (radiance transported slice by slice across the
    axis where |w| is largest, from the lobes' light toward w, sigma_t linear along each upstream
    segment and the source function linear in its optical depth, half a segment in the first
    slice; ``boundary`` (N, 3), the radiance
    entering the grid along each direction, at the first slice and wherever the point upstream
    is outside the grid; None: 0), scattered toward the camera with f_hg, at the voxels the
    renderer reads; 0 elsewhere. Light ``sun``'s unscattered lobe (default: :func:`default_sun`;
    None: none) is transported apart without its angular factor f_hg(d_sun . w; g), and its
    light is the quadrature's mean weighted by that factor times the phase, times their exact
    integral f_hg(d_sun . to the eye; g g) (docs/METHOD.md Eq. 25e)."""
    from popvol.pipeline import voxels_seen
    med = scene.medium
    rho = med.density.astype(np.float64)
    alb = med.albedo.astype(np.float64) if med.albedo_per_voxel else np.ones(med.shape)
    alb_rgb = np.ones(3) if med.albedo_per_voxel else np.asarray(med.albedo, np.float64) * np.ones(3)
    g = med.g.astype(np.float64) if med.g_per_voxel else np.full(med.shape, float(med.g))
    sig = rho[..., None] * np.asarray(med.scale, np.float64)          # (nx, ny, nz, 3)
    centres = _voxel_centres(med)
    to_eye = np.asarray(scene.camera.origin, float) - centres
    to_eye /= np.maximum(np.linalg.norm(to_eye, axis=-1, keepdims=True), 1e-300)
    out, norm = np.zeros(med.shape + (3,)), np.zeros(med.shape)
    out_sun, norm_sun = np.zeros(med.shape + (3,)), np.zeros(med.shape)
    boundary = np.zeros((len(dirs), 3)) if boundary is None else np.asarray(boundary, np.float64)
    sun = default_sun(scene, solution) if sun == "default" else sun
    g_sun = np.clip(g, -0.9999, 0.9999)
    if sun is not None:
        d_sun = solution.directions[sun]
        apart = np.where(rho[..., None] > 0, _unscattered_lit(solution, sun), 0.0)
        q_sun = sig * (alb[..., None] * alb_rgb) * apart
    for w, wt, entering in zip(dirs, weights, boundary):
        J = np.where(rho[..., None] > 0, _grid_lit(scene, solution, np.broadcast_to(-w, med.shape + (3,)),
                                                   patterns=True), 0.0)
        f = wt * hg.f_hg(np.clip(to_eye @ w, -1.0, 1.0), g)
        if sun is not None:
            f_sun = hg.f_hg(w @ d_sun, g_sun)
            J = J - apart * f_sun[..., None]
            norm_sun += f * f_sun
            out_sun += (f * f_sun)[..., None] * _transport(q_sun, sig, w, med, np.zeros(3))
        q = sig * (alb[..., None] * alb_rgb) * J
        norm += f
        out += f[..., None] * _transport(q, sig, w, med, entering)
    out /= np.where(norm > 0, norm, 1.0)[..., None]
    if sun is not None:
        out += (out_sun / np.where(norm_sun > 0, norm_sun, 1.0)[..., None]
                * hg.f_hg(np.clip(to_eye @ d_sun, -1.0, 1.0), g * g_sun)[..., None])
    return np.where(voxels_seen(med.density)[..., None], out, 0.0)


def render_pixel(scene, solution, px, py, combined=True, source=None):
    """Twin of kernels.render.render_kernel for one pixel centre (no jitter): linear RGB (3,).
    Channel c of the fields (grey solutions have one) lights colour c; sigma_t, albedo and the
    view transmittance are per colour. ``combined`` (as the renderer's): samples at least
    renderer.NEAR_VOXELS voxels from the camera read the grid-lit terms from the combined source
    (``source``, default :func:`in_scattering_source`) by trilinear interpolation, plus the
    point lights' walk lobes; nearer ones, or all without ``combined``, are lit light by light.
    A segment in an 8^3 block whose densest voxel (within one voxel of it) makes it optically
    thicker than MAX_SEGMENT_DEPTH is split into equal parts, each sampled at its centre; in a
    block so thin that n steps are at most COARSE_DEPTH thick, one sample spans n steps."""
    from popvol.kernels.render import COARSE_DEPTH, MAX_SEGMENT_DEPTH, MAX_SUBSTEPS, NEAR_POINT_LIGHT
    from popvol.renderer import BLOCK, NEAR_VOXELS
    med, cam, m = scene.medium, scene.camera, scene.method
    fwd, right, up = cam.basis()
    tan_half = np.tan(np.radians(cam.fov) / 2)
    sx = (2 * (px + 0.5) / cam.width - 1) * tan_half * cam.width / cam.height
    sy = (1 - 2 * (py + 0.5) / cam.height) * tan_half
    d = fwd + sx * right + sy * up
    d /= np.linalg.norm(d)
    lo, hi = med.bounds
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - cam.origin) / d, (hi - cam.origin) / d
    t0 = max(0.0, np.nanmax(np.minimum(ta, tb)))
    t1 = np.nanmin(np.maximum(ta, tb))
    step = m.step * med.voxel_size.min()
    near = NEAR_VOXELS * med.voxel_size.min()
    if combined and source is None:
        source = in_scattering_source(scene, solution)
    last = np.asarray(med.shape) - 0.5
    edge = thick_faces(med)
    n_ch = solution.phi.shape[1]

    def light_at(x, ts, q, g):
        """L_s / sigma_s at the sample x, ts along the ray (q: its clamped cell index)."""
        from_source = combined and ts >= near
        Ls = np.array([float(trilinear(source[..., k], q)) for k in range(3)]) if from_source else np.zeros(3)
        for l in range(len(solution.directions)):
            if from_source and not solution.is_point[l]:
                continue
            for c in range(n_ch):
                E = _power(solution, l, c, n_ch)
                w = solution.directions[l]
                if solution.is_point[l]:      # its spherical domain holds r^2 phi; the lobe is radial
                    sol = next(o for o in solution.domains if o.light_index == l and o.channel == c)
                    r2 = (sol.domain.radii ** 2)[:, None, None]
                    at_x = np.ones((1, 1, 1), bool)
                    p, pa, p_dir = (spherical_to_world(f * r2, sol.domain, x, np.zeros(3), at_x)[0, 0, 0]
                                    for f in (sol.result.phi, sol.result.phia, sol.direct))
                    w = x - solution.positions[l]
                    p, pa, p_dir = p / np.dot(w, w), pa / np.dot(w, w), p_dir / np.dot(w, w)
                    w = w / np.linalg.norm(w)
                else:
                    p = float(trilinear(solution.phi[l, c], q))
                    pa = float(trilinear(solution.phia[l, c], q))
                    p_dir = float(trilinear(solution.direct[l, c], q))
                # the unscattered part (a delta lobe along w) is lit apart from the rest
                Ls += float(walk_lobes(p, pa, p_dir, -np.dot(w, d), g)) * E
                if solution.phid.shape[0] and not from_source:     # the diffuse lobe, about its flux J
                    pd = float(trilinear(solution.phid[l, c], q))
                    J = np.array([float(trilinear(solution.flux[l, c, k], q)) for k in range(3)])
                    Ls += float(diffuse_lobe(pd, J, d, g, solution.lobe_cap[l])) * E
        return Ls

    def block_of(x):
        """x's 8^3 block and the largest density within one voxel of it."""
        b = np.clip((x - med.origin) / med.voxel_size, 0, np.asarray(med.shape) - 1).astype(int) // BLOCK
        lo_v, hi_v = np.maximum(BLOCK * b - 1, 0), BLOCK * (b + 1) + 2
        return b, float(med.density[lo_v[0]:hi_v[0], lo_v[1]:hi_v[1], lo_v[2]:hi_v[2]].max())

    def parts(x, ds):
        """How many parts the segment at x is split into: enough that none is optically thicker
        than MAX_SEGMENT_DEPTH at the largest density within one voxel of x's 8^3 block."""
        tau = block_of(x)[1] * float(np.max(med.scale)) * ds
        return 1 if tau <= MAX_SEGMENT_DEPTH else min(int(np.ceil(tau / MAX_SEGMENT_DEPTH)), MAX_SUBSTEPS)

    def spans(t, ts):
        """How many steps the sample at ts (of the segment starting at t) spans: as many as make
        at most COARSE_DEPTH mean free paths at the densest voxel of its block (method.max_step
        at most), within the block, and within NEAR_POINT_LIGHT of the distance from t to a
        point light; 1 unless t lies in the sample's block."""
        x, xt = cam.origin + ts * d, cam.origin + t * d
        b, rho_max = block_of(x)
        if m.max_step <= 1 or rho_max <= 0 or t1 - t <= step or np.any(block_of(xt)[0] != b):
            return 1                   # the segment's start must lie in the sample's block
        tau = rho_max * float(np.max(med.scale)) * step
        n = m.max_step if tau * m.max_step <= COARSE_DEPTH else int(COARSE_DEPTH / tau)
        blocks = -(-np.asarray(med.shape) // BLOCK)
        leave = np.inf                 # the grid's outer blocks reach to the box's faces
        for a in range(3):
            if d[a] > 0 and b[a] < blocks[a] - 1:
                leave = min(leave, (med.origin[a] + BLOCK * (b[a] + 1) * med.voxel_size[a] - x[a]) / d[a])
            elif d[a] < 0 and b[a] > 0:
                leave = min(leave, (med.origin[a] + BLOCK * b[a] * med.voxel_size[a] - x[a]) / d[a])
        n = min(n, int(min((ts + max(leave, 0.0) - t) / step, 1e9)))
        for l in np.flatnonzero(solution.is_point):
            n = min(n, int(NEAR_POINT_LIGHT * np.linalg.norm(xt - solution.positions[l]) / step))
        return max(n, 1)

    L, Tv, i = np.zeros(3), np.ones(3), 0
    while t0 + i * step < t1:
        t = t0 + i * step          # the kernel's samples: t0 + (i + 1/2) step, the last segment cut at t1
        ds = min(step, t1 - t)
        n = spans(t, t + 0.5 * ds)  # one sample for n steps where the medium is thin
        ds = min(n * step, t1 - t)
        i += n
        k = parts(cam.origin + (t + 0.5 * ds) * d, ds)
        for j in range(k):         # a segment in an optically thick block: k parts, each sampled
            ts = t + (j + 0.5) * ds / k
            x = cam.origin + ts * d
            q = np.clip((x - med.origin) / med.voxel_size, -0.5, last)
            rho = float(trilinear(med.density, q))
            if rho <= 0:
                continue
            albedo = (float(trilinear(med.albedo, q)) * np.ones(3) if med.albedo_per_voxel
                      else np.asarray(med.albedo, float))
            g = float(trilinear(med.g, q)) if med.g_per_voxel else med.g
            Ls = light_at(x, ts, q, g)
            sigma_t = med.scale * rho
            if edge:
                Ls += edge_single_scattering(scene, solution, x, d, g, sigma_t, ds / k)
            T_seg = np.exp(-sigma_t * ds / k)
            L += np.where(sigma_t > 0, Tv * (1 - T_seg) * albedo * Ls, 0.0)
            Tv *= T_seg
            if Tv.max() < 1e-4:
                return L
    return L + Tv * background_twin(scene, d)


def thick_faces(medium):
    """Whether some voxel on the grid's faces is at least EDGE_DEPTH mean free paths thick along
    the face's normal (twin of renderer.thick_faces)."""
    from popvol.kernels.render import EDGE_DEPTH
    rho, sigma = medium.density, float(np.max(medium.scale))
    return any(max(rho.take(0, axis=a).max(), rho.take(-1, axis=a).max()) * sigma * medium.voxel_size[a] >= EDGE_DEPTH
               for a in range(3))


def edge_single_scattering(scene, solution, x, d, g, sigma_t, ds, n_quad=4000):
    """Twin of kernels.render.edge_single_scattering for a sample at the middle of its segment
    of length ds. Along each axis on which x lies beyond the last voxel centres (the grid's outer
    half cell), a sun's unscattered fluence by Beer-Lambert from the face it enters by, or from
    the clamped value for light that leaves by it, followed along the segment, its values capped
    at 1 point by point and their mean weighted by the camera's transmittance taken by a
    midpoint rule of ``n_quad`` points (the kernel's is in closed form); the largest of the axes'
    means, minus the clamped value the fields give, times the phase and the light's power (RGB
    (3,)); 0 where x is not beyond the centres."""
    med = scene.medium
    u = (x - med.origin) / med.voxel_size
    beyond = np.maximum(-u, u - (np.asarray(med.shape) - 1.0)) * med.voxel_size   # <= 0 within
    out = np.zeros(3)
    if beyond.max() <= 0:
        return out
    outward = np.where(u < 0, -1.0, 1.0)
    q = np.clip(u, -0.5, np.asarray(med.shape) - 0.5)
    s = (np.arange(n_quad) + 0.5) / n_quad * ds - 0.5 * ds      # along the ray, from the sample
    n_ch = solution.direct.shape[1]
    for l, sun in enumerate(solution.directions):
        if solution.is_point[l] or not solution.unscattered[l]:
            continue
        phase = float(hg.f_hg(-np.dot(sun, d), np.clip(g, -0.9999, 0.9999)))
        for c in range(n_ch):
            sig = sigma_t[c] if n_ch == 3 else sigma_t[0]
            if sig <= 0:
                continue
            clamped = float(trilinear(solution.direct[l, c], q))

            def along(a, depth):
                """phi_dir at points ``depth`` beyond the centres along axis a."""
                w = sun[a] * outward[a]                # the light's travel along the outward normal
                with np.errstate(over="ignore"):
                    if w < 0:                          # entering: from the face, 0.5 h - depth away
                        return np.exp(-sig * (0.5 * med.voxel_size[a] - depth) / -w)
                    return clamped * np.exp(-sig * depth / w)      # leaving: from the clamped value

            axes = [a for a in range(3) if beyond[a] > 0 and sun[a] != 0]
            if not axes:
                continue
            weight = sig * np.exp(-sig * (s + 0.5 * ds))
            mean = max(float(np.sum(np.minimum(along(a, beyond[a] + outward[a] * d[a] * s), 1.0) * weight))
                       * ds / n_quad / -np.expm1(-sig * ds) for a in axes)
            out += (mean - clamped) * phase * _power(solution, l, c, n_ch)
    return out


def background_twin(scene, d):
    """Twin of kernels.render.background_radiance: the constant, or the environment map's
    bilinear value along d (Mitsuba's envmap convention, texel centres, wrapping in u)."""
    if scene.environment is None:
        return np.asarray(scene.background, float)
    m = scene.environment.radiance.astype(float)
    H, W = m.shape[:2]
    u = (np.arctan2(d[0], -d[2]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[1], -1, 1)) / np.pi
    x, y = u * W - 0.5, float(np.clip(v * H - 0.5, 0, H - 1))
    j0 = int(np.floor(x))
    i0 = min(int(y), H - 2)
    fx, fy = x - j0, y - i0
    rows = [m[i, j0 % W] * (1 - fx) + m[i, (j0 + 1) % W] * fx for i in (i0, min(i0 + 1, H - 1))]
    return rows[0] * (1 - fy) + rows[1] * fy


def face_factors(Tr, Tt, Tp, Dr, Dt, Dp, full):
    """Twin of kernels.spherical.face_factors: (Fr, Ft, Fp), each face's (T, D) in the last axis,
    the product of the half steps of the two cells it joins, built by padding each factor
    array with what lies beyond its first and last cells along its axis: the antipodal cell
    (inner sphere), the cell at phi + pi (poles) or the other end (phi) on a full sphere, and 1
    (nothing: the part leaves) elsewhere."""
    n0, n1, n2 = Tr.shape
    r, t, p = (np.stack([T, D], -1).astype(np.float64) for T, D in ((Tr, Dr), (Tt, Dt), (Tp, Dp)))
    one = lambda shape: np.ones(shape + (2,))
    half_turn = lambda x: np.roll(x, -(n2 // 2), axis=-2)      # cell (., ., j + n_phi / 2)
    inner = half_turn(r[0, ::-1])[None] if full else one((1, n1, n2))
    r = np.concatenate([inner, r, one((1, n1, n2))], axis=0)
    pole0 = half_turn(t[:, :1]) if full else one((n0, 1, n2))
    pole1 = half_turn(t[:, -1:]) if full else one((n0, 1, n2))
    t = np.concatenate([pole0, t, pole1], axis=1)
    p = np.concatenate([p[:, :, -1:] if full else one((n0, n1, 1)), p,
                        p[:, :, :1] if full else one((n0, n1, 1))], axis=2)
    return (r[:-1] * r[1:], t[:, :-1] * t[:, 1:], p[:, :, :-1] * p[:, :, 1:])


def sweep_spherical(R, Ra, Tr, Tt, Tp, Dr, Dt, Dp, rule, full, forward, flip, w_min, inv_area,
                    phi, phia, tally, band_rows=16, handover=-1.0, diffusive=None, Q=None,
                    k_end=None):
    """One sweep of a point light's spherical domain (twin of kernels.spherical.sweep_spherical_
    bands + deliver), cell by cell, bands of theta rows one after the other. A transfer along
    axis X multiplies by T_X[src] T_X[dst] and D_X[src] D_X[dst]; a full sphere wraps phi,
    crosses the poles to phi + pi and sends the innermost back part to the antipodal cell with
    its anisotropy reversed. Parts crossing a band edge and through the light wait until the
    end. A part whose destination lies at or beyond k_end[i, j] (int (n_theta, n_phi), beyond
    the medium's box; None: n_r) has left and is tallied as transmitted. Returns the power
    still pending."""
    n0, n1, n2 = R.shape
    edges = list(range(0, n1, band_rows)) + [n1]
    if len(edges) > 2 and edges[-1] - edges[-2] < 2:
        edges.pop(-2)
    later = []
    for b in range(len(edges) - 1):
        rows = range(edges[b], edges[b + 1])
        for k in (range(n0) if forward else range(n0 - 1, -1, -1)):
            for i in (reversed(rows) if flip else rows):
                for j in (range(n2 - 1, -1, -1) if flip else range(n2)):
                    w, wa = float(R[k, i, j]), float(Ra[k, i, j])
                    if w <= w_min:
                        continue
                    R[k, i, j] = Ra[k, i, j] = 0.0
                    if handover > 0 and abs(wa) < handover * diffusive[k, i, j] * w:
                        Q[0, k, i, j] += w
                        Q[1, k, i, j] += wa
                        continue
                    phi[k, i, j] += w * inv_area[k, i]
                    phia[k, i, j] += wa * inv_area[k, i]
                    (ef, mf), (es, ms), (eb, mb) = split_exact(w, wa, rule)
                    ef, mf, es, ms, eb, mb = (float(v) for v in (ef, mf, es, ms, eb, mb))
                    # (destination or None, part, its a, T, D, tally slot if it leaves, later?)
                    moves = []
                    for kn, e, m, slot in ((k + 1, ef, mf, TRANSMITTED), (k - 1, eb, mb, REFLECTED)):
                        if 0 <= kn < n0:
                            moves.append(((kn, i, j), e, m, Tr, Dr, None, False))
                        elif kn < 0 and full:
                            dst = (0, n1 - 1 - i, (j + n2 // 2) % n2)
                            moves.append((dst, e, -m, Tr, Dr, None, True))
                        else:
                            moves.append((None, e, m, Tr, Dr, slot, False))
                    for jj in (j - 1, j + 1):
                        if 0 <= jj < n2 or full:
                            moves.append(((k, i, jj % n2), es, ms, Tp, Dp, None, False))
                        else:
                            moves.append((None, es, ms, Tp, Dp, SIDE_ESCAPED, False))
                    for ii in (i - 1, i + 1):
                        if 0 <= ii < n1:
                            moves.append(((k, ii, j), es, ms, Tt, Dt, None, not edges[b] <= ii < edges[b + 1]))
                        elif full:              # across the pole
                            moves.append(((k, i, (j + n2 // 2) % n2), es, ms, Tt, Dt, None, False))
                        else:
                            moves.append((None, es, ms, Tt, Dt, SIDE_ESCAPED, False))
                    for dst, e, m, T, D, slot, wait in moves:
                        t_src, d_src = float(T[k, i, j]), float(D[k, i, j])
                        if dst is not None and k_end is not None and dst[0] >= k_end[dst[1], dst[2]]:
                            t = t_src * float(T[dst])
                            tally[TRANSMITTED] += e * t
                            tally[ABSORBED] += e * (1 - t)
                            continue
                        if dst is None:
                            tally[slot] += e * t_src
                            tally[ABSORBED] += e * (1 - t_src)
                            continue
                        t = t_src * float(T[dst])
                        part = (e * t, e * m * t * d_src * float(D[dst]))
                        tally[ABSORBED] += e * (1 - t)
                        if wait:
                            later.append(dst + part)
                        else:
                            R[dst] += part[0]
                            Ra[dst] += part[1]
    for k, i, j, e, ea in later:
        R[k, i, j] += e
        Ra[k, i, j] += ea
    return float(R.sum(dtype=np.float64))


def domain_to_world(field, frame, origin, h, world_origin, voxel, needed):
    """Twin of kernels.sampling.domain_to_world for one field: its trilinear value (clamped to
    the edge) at the world voxel centres where ``needed``, 0 elsewhere."""
    idx = np.indices(needed.shape).reshape(3, -1).T
    q = (world_origin + idx * voxel - origin) @ np.asarray(frame).T / h - 0.5
    q = np.clip(q, 0, np.asarray(field.shape) - 1)
    return np.where(needed, trilinear(field, q).reshape(needed.shape), 0.0)


def cells_read(frame, origin, h, world_origin, voxel, needed, shape):
    """Twin of kernels.sampling.cells_read: bool ``shape``, True at the 8 corners of the
    trilinear stencil (clamped to the edge, as :func:`domain_to_world`'s) of every world voxel
    centre where ``needed``."""
    idx = np.argwhere(needed)
    q = (world_origin + idx * voxel - origin) @ np.asarray(frame).T / h - 0.5
    n = np.asarray(shape)
    qc = np.clip(q, 0, n - 1)
    i0 = np.minimum(np.floor(qc).astype(int), np.maximum(n - 2, 0))
    i1 = np.minimum(i0 + 1, n - 1)
    out = np.zeros(shape, bool)
    for corner in np.ndindex(2, 2, 2):
        c = np.where(np.array(corner, bool), i1, i0)
        out[c[:, 0], c[:, 1], c[:, 2]] = True
    return out


def spherical_to_world(field, dom, world_origin, voxel, needed):
    """One field of a SphericalDomain at world voxel centres (twin of the renderer's
    kernels.render.point_lookup): their (r, theta, phi) as continuous cell indices, trilinear,
    clamped in r and theta, periodic in phi on a full sphere; 0 where not ``needed``."""
    idx = np.indices(needed.shape).reshape(3, -1).T
    local = (world_origin + idx * voxel - dom.centre) @ dom.frame.T
    r = np.linalg.norm(local, axis=1)
    theta = np.arccos(np.clip(local[:, 2] / np.maximum(r, 1e-300), -1, 1))
    phi = np.arctan2(local[:, 1], local[:, 0])
    if dom.full:
        phi = np.mod(phi, 2 * np.pi)
    q = np.stack([(r - dom.r0) / dom.dr, (theta - dom.theta0) / dom.dtheta, (phi - dom.phi0) / dom.dphi], 1) - 0.5
    n = np.asarray(field.shape)
    q[:, :2] = np.clip(q[:, :2], 0, n[:2] - 1)
    if dom.full:
        j0 = np.floor(q[:, 2]).astype(int)
        fj = q[:, 2] - j0
        j0, j1 = j0 % n[2], (j0 + 1) % n[2]
    else:
        q2 = np.clip(q[:, 2], 0, n[2] - 1)
        j0 = np.minimum(np.floor(q2).astype(int), max(n[2] - 2, 0))
        fj = q2 - j0
        j1 = np.minimum(j0 + 1, n[2] - 1)
    k0 = np.minimum(np.floor(q[:, 0]).astype(int), max(n[0] - 2, 0))
    i0 = np.minimum(np.floor(q[:, 1]).astype(int), max(n[1] - 2, 0))
    fk, fi = q[:, 0] - k0, q[:, 1] - i0
    k1, i1 = np.minimum(k0 + 1, n[0] - 1), np.minimum(i0 + 1, n[1] - 1)
    out = np.zeros(len(q))
    for kk, wk in ((k0, 1 - fk), (k1, fk)):
        for ii, wi in ((i0, 1 - fi), (i1, fi)):
            for jj, wj in ((j0, 1 - fj), (j1, fj)):
                out += wk * wi * wj * field[kk, ii, jj]
    return np.where(needed, out.reshape(needed.shape), 0.0)


def resample_spherical(grid, voxel, grid_origin, dom, clamp):
    """Twin of kernels.spherical.resample_spherical: ``grid`` at the centres of a
    SphericalDomain's cells (trilinear; clamped to the edge outside if ``clamp``, else 0)."""
    q = (dom.index_to_world(np.moveaxis(np.indices(dom.shape), 0, -1)) - grid_origin) / voxel
    if clamp:
        q = np.clip(q, 0, np.asarray(grid.shape) - 1)
    return trilinear(grid, q)


def splat_to_grid(Q, dom, grid, region):
    """Twin of kernels.spherical.splat_to_grid: each spherical cell's power added to the cell of
    the rectilinear DirectionalDomain ``grid`` holding its centre (nearest edge cell if outside),
    or, if that cell is not in ``region``, to the region cell among its 26 neighbours with the
    nearest centre; returns (grid of power, power lost where there is none)."""
    centres = dom.index_to_world(np.moveaxis(np.indices(dom.shape), 0, -1)).reshape(-1, 3)
    q = (centres - grid.origin) @ grid.frame.T / grid.h
    idx = np.clip(np.floor(q).astype(int), 0, np.asarray(grid.shape) - 1)
    out, lost = np.zeros(grid.shape), 0.0
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    for qi, cell, e in zip(q, idx, Q.reshape(-1)):
        if e == 0:
            continue
        if not region[tuple(cell)]:
            options = [cell + o for o in offsets
                       if np.all(cell + o >= 0) and np.all(cell + o < grid.shape) and region[tuple(cell + o)]]
            if not options:
                lost += float(e)
                continue
            cell = min(options, key=lambda n: float(np.sum((n + 0.5 - qi) ** 2)))
        out[tuple(cell)] += e
    return out, lost


def boundary_weight(mask) -> np.ndarray:
    """float32 (mask's shape): 1 / |n|_1 = |grad m|_2 / |grad m|_1 (in [1/sqrt(3), 1]), with m the
    region mask smoothed by a binomial filter [1 4 6 4 1] / 16 along each axis (a Gaussian of
    one cell; zero outside the grid): the factor by which a boundary cell's faces overstate the
    area of the smooth surface through it. 1 where the smoothed mask is flat or outside the
    region. Twin of kernels.diffusion.boundary_weight."""
    m = mask.astype(np.float64)
    kernel = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    for axis in range(3):
        pad = [(0, 0)] * 3
        pad[axis] = (2, 2)
        p = np.pad(m, pad)
        n = m.shape[axis]
        m = sum(kernel[t] * np.take(p, np.arange(t, t + n), axis=axis) for t in range(5))
    grads = [np.gradient(m, axis=a) if m.shape[a] > 1 else np.zeros_like(m) for a in range(3)]
    l2 = np.sqrt(sum(gr * gr for gr in grads))
    l1 = sum(np.abs(gr) for gr in grads)
    w = np.where(mask & (l2 > 1e-6), l2 / np.maximum(l1, 1e-30), 1.0)
    return w.astype(np.float32)


def block_mean(x: np.ndarray, factor: int) -> np.ndarray:
    """Twin of kernels.sampling.block_sums with ``held`` (through renderer.block_mean): float32,
    the mean of x (..., nx, ny, nz) over blocks of factor^3 voxels along its last three axes
    (the blocks at the far edges over the voxels they hold), one axis at a time."""
    out = np.asarray(x, np.float32)
    for axis in range(out.ndim - 3, out.ndim):
        n = out.shape[axis]
        m = -(-n // factor)
        if m * factor != n:
            pad = [(0, 0)] * out.ndim
            pad[axis] = (0, m * factor - n)
            out = np.pad(out, pad)
        out = out.reshape(out.shape[:axis] + (m, factor) + out.shape[axis + 1:]).sum(axis=axis + 1)
        held = np.minimum(factor, n - factor * np.arange(m)).astype(np.float32)    # voxels per block
        out /= held.reshape((m,) + (1,) * (out.ndim - axis - 1))
    return out



def coarsen(x: np.ndarray, factor: int, how: str = "sum") -> np.ndarray:
    """Twin of diffusion.coarsen (kernels.sampling.block_sums without ``held``): float64, the
    sum of x (nx, ny, nz) over blocks of factor^3 cells, or that sum / factor^3 (``how`` =
    "mean"), the grid padded with zeros to a multiple of factor, by reshaping."""
    n = [-(-s // factor) * factor for s in x.shape]
    pad = np.zeros(n)
    pad[: x.shape[0], : x.shape[1], : x.shape[2]] = x
    b = pad.reshape(n[0] // factor, factor, n[1] // factor, factor, n[2] // factor, factor).sum(axis=(1, 3, 5))
    return b if how == "sum" else b / factor ** 3


def pending_blocks(W, Wa, cell, factor: int):
    """Twin of kernels.ordinates18.pending_blocks: (P, M) float64 (b_d, b_u, b_v, n), the rows
    of W, Wa (m, n) placed at their cells (``cell``, -1 where none) and summed over blocks of
    factor^3 cells by :func:`coarsen`, one ordinate at a time."""
    full = [np.zeros(cell.shape + (W.shape[1],)) for _ in range(2)]
    kept = cell >= 0
    for x, out in zip((W, Wa), full):
        out[kept] = x[cell[kept]]
    return tuple(np.stack([coarsen(out[..., o], factor) for o in range(W.shape[1])], axis=-1) for out in full)


def upsample(coarse: np.ndarray, factor: int, shape: tuple) -> np.ndarray:
    """Twin of kernels.sampling.upsample_blocks (and add_upsampled_blocks): (nx, ny, nz, C) from the blocks' values
    ``coarse`` at their centres, trilinear at every voxel centre, clamped to the edge
    (separable: one linear interpolation per axis)."""
    out = coarse
    for axis, n in enumerate(shape):
        nc = out.shape[axis]
        u = np.clip((np.arange(n) - 0.5 * (factor - 1)) / factor, 0.0, nc - 1.0)
        i0 = np.minimum(u.astype(np.int64), max(nc - 2, 0))
        i1 = np.minimum(i0 + 1, nc - 1)
        w = (u - i0).astype(out.dtype).reshape((-1,) + (1,) * (out.ndim - axis - 1))
        lower = np.take(out, i0, axis=axis)
        out = lower + (np.take(out, i1, axis=axis) - lower) * w
    return out


def densest_in_blocks(density: np.ndarray, block: int) -> np.ndarray:
    """Twin of kernels.sampling.densest_near_blocks (through renderer.densest_in_blocks): float32
    (ceil(nx / block), ...), the largest density over voxels [block b - 1, block (b + 1) + 1] of
    each axis, within the grid, by slicing."""
    m = density
    for axis in range(3):
        n = m.shape[axis]
        parts = [np.take(m, np.arange(max(b - 1, 0), min(b + block + 2, n)), axis=axis).max(axis=axis, keepdims=True)
                 for b in range(0, n, block)]
        m = np.concatenate(parts, axis=axis)
    return np.ascontiguousarray(m, np.float32)


def skip_blocks(densest: np.ndarray, reach: int) -> np.ndarray:
    """Twin of renderer.skip_blocks: float32, ``densest`` where > 0, else minus the Chebyshev
    distance (in blocks) to the nearest block > 0, at most ``reach``, by brute force over all
    pairs of blocks."""
    occupied = np.argwhere(densest > 0)
    out = densest.astype(np.float32).copy()
    for b in np.argwhere(densest <= 0):
        n = np.abs(occupied - b).max(axis=1).min() if len(occupied) else reach
        out[tuple(b)] = -min(n, reach)
    return out


# -- per-cell arrays of a rectilinear domain (kernels/cells.py) ---------------------------------

def medium_factors(sigma_t, sigma_s, g, h, decay):
    """Twin of kernels.cells.medium_factors (walk.medium_factors): (Th, Dh) float32 of the
    broadcast shape; h may be an array (a spherical cell's transfer lengths)."""
    sigma_a = np.maximum(np.asarray(sigma_t, np.float64) - sigma_s, 0.0)
    Th = np.exp(-0.5 * h * sigma_a)
    x = 0.5 * h * np.asarray(sigma_s, np.float64)
    if decay == "paper":
        with np.errstate(divide="ignore"):
            Dh = np.where(x > 0, np.power(np.maximum(g, 0.0), x), 1.0)
    else:
        Dh = np.exp(-x * (1.0 - np.asarray(g, np.float64)))
    return Th.astype(np.float32), Dh.astype(np.float32)


def handover_factor(sigma_t, sigma_s, g, s):
    """Twin of kernels.cells.handover_factor (walk.handover_factor); s may be an array."""
    sigma_t, sigma_s = np.asarray(sigma_t, np.float64), np.asarray(sigma_s, np.float64)
    sigma_tr = np.maximum(sigma_t - sigma_s, 0.0) + sigma_s * (1.0 - np.asarray(g, np.float64))
    return np.where((sigma_s > 0) & (sigma_t > 0), -np.expm1(-sigma_tr * s), 0.0).astype(np.float32)


def direct_fluence(sigma_t, h):
    """Twin of kernels.cells.direct_fluence (walk.direct_fluence): exp(-tau) along axis 0."""
    tau_half = np.asarray(sigma_t, np.float64) * (0.5 * h)
    tau = 2.0 * np.cumsum(tau_half, axis=0) - tau_half
    return np.exp(-tau).astype(np.float32)


def hand_over_pending(W, Wa, Th, Dh, diffusive, Q):
    """Twin of kernels.cells.hand_over_pending (walk.hand_over_pending), in place on W, Wa, Q;
    returns the power the half steps absorbed."""
    region = diffusive > 0
    w = np.where(region, W, 0.0).astype(np.float64)
    th = np.asarray(Th, np.float64)
    Q[0] += (w * th).astype(np.float32)
    Q[1] += np.where(region, Wa.astype(np.float64) * th * Dh, 0.0).astype(np.float32)
    W[region] = 0.0
    Wa[region] = 0.0
    return float(np.sum(w * (1.0 - th)))


def lanes_sum(a, b=None):
    """Twin of kernels/reduction.py's fixed-order sums (kernels.diffusion.dot with ``b``,
    kernels.propagation.total_energy without): per slice k and row i, term j = a[k, i, j]
    (times b[k, i, j], the product in the arrays' precision) goes to lane j mod 8 (the row's
    last n2 mod 8 terms to lane 0), the eight lanes are added ((0 + 1) + (2 + 3)) + ((4 + 5)
    + (6 + 7)), the rows in order, then the slices in order; every addition in float64 one at a
    time, as Python floats do."""
    n0, n1, n2 = a.shape
    full = 8 * (n2 // 8)
    total = 0.0
    for k in range(n0):
        s = 0.0
        for i in range(n1):
            acc = [0.0] * 8
            for j in range(n2):
                term = a[k, i, j] * b[k, i, j] if b is not None else a[k, i, j]
                acc[j % 8 if j < full else 0] += float(term)
            s += ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
        total += s
    return total


def blend_rows(table, rows, weights):
    """Twin of kernels/sampling.py's blend_rows: each output row the weighted sum of the table's
    rows it names."""
    return np.einsum("mk,mkw->mw", np.asarray(weights, np.float64), np.asarray(table, np.float64)[rows])
