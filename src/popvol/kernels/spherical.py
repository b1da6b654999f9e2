"""Numba kernels of a point light's spherical domain (see domains.SphericalDomain).

Propagation follows kernels/propagation.py (supplement Eq. 4, 7, 9, 12) with the radial
direction as the principal ordinate: a packet's front part moves out one shell, its back part
in one shell, and its four side parts to the neighbours in theta and phi. The cells are not
cubes, so each transfer has its own length:

    radial dr,    along theta r dtheta,    along phi r sin(theta) dphi,

and a cell's half step of each has its own transmittance and decay. A transfer src -> dst is
attenuated by T[src] T[dst] of its direction and its anisotropy decays by D[src] D[dst], both
applied by the sender, so pending packets (R, Ra) are what has arrived at a cell's centre. What
leaves the domain crosses only the sender's half cell. The products are computed once per face
before the sweeps (:func:`face_factors`), so a send reads one (T, D) pair per neighbour. The
split shares are those of a cube (the six principal ordinates).

Fluence: a visit of power W adds W / (r^2 Omega) to phi (Omega: the cell's solid angle), its
power per area at the cell's centre radius, so that in vacuum phi = I / r^2 exactly at every
centre (the inverse-square law; test). Full sphere: a side step across a pole lands in the cell
on the other side (phi + pi, same row); a back step from the innermost shell passes the light
(or the empty ball around it) and comes out of the antipodal cell travelling outward (a -> -a).

Budget tallies as in propagation.py: [reflected (in through the inner sphere of a cone domain),
transmitted (out through the outer sphere), side (out through a cone's lateral faces),
absorbed].

NumPy twins: tests/twins.py (sweep_spherical, resample_spherical, splat_to_grid).
"""
import math

import numba as nb
import numpy as np

from . import ON_ITS_OWN
from .cells import rates as cell_rates
from .propagation import (ABSORBED, REFLECTED, SIDE_ESCAPED, TRANSMITTED, _add, _hands_over, _wrap,
                          bands_of, lanes_of, split, total_energy)
from .sampling import trilinear, trilinear_clamped


@nb.njit(inline="always", fastmath=True, cache=True)
def _local(frame, r, st, ct, sp, cp):
    """World offset from the centre of the point at radius r, direction (theta, phi)."""
    x = r * (st * cp * frame[0, 0] + st * sp * frame[1, 0] + ct * frame[2, 0])
    y = r * (st * cp * frame[0, 1] + st * sp * frame[1, 1] + ct * frame[2, 1])
    z = r * (st * cp * frame[0, 2] + st * sp * frame[1, 2] + ct * frame[2, 2])
    return x, y, z


@nb.njit(**ON_ITS_OWN)
def _one(medium, k, i, j):
    """The rates (kernels.cells.rates) of cell (k, i, j): what a part leaving the domain across
    its face meets. medium: (sigma_t, sigma_s, g, paper)."""
    sigma_t, sigma_s, g, paper = medium
    return cell_rates(sigma_t, sigma_s, g, k, i, j, paper)


@nb.njit(**ON_ITS_OWN)
def _two(medium, k, i, j, k2, i2, j2):
    """The rates of cell (k, i, j) plus those of cell (k2, i2, j2): what a part crossing the
    face between them meets.

    _one and _two are compiled on their own (kernels.ON_ITS_OWN): :func:`face_factors` calls
    them at seven faces, and seven copies inlined into its Numba IR take about 16 s of a first
    run to compile."""
    sigma_t, sigma_s, g, paper = medium
    a, d = cell_rates(sigma_t, sigma_s, g, k, i, j, paper)
    a2, d2 = cell_rates(sigma_t, sigma_s, g, k2, i2, j2, paper)
    return a + a2, d + d2


@nb.njit(inline="always", fastmath=True, cache=True)
def _store(F, k, i, j, s, rates):
    """Face (k, i, j) of F gets T = exp(-a s / 2), D = exp(-d s / 2), (a, d) = ``rates``: the
    product of the half steps of length s of the cells whose rates sum to (a, d)."""
    a, d = rates
    F[k, i, j, 0] = math.exp(-0.5 * s * a) if a > 0.0 else 1.0
    F[k, i, j, 1] = math.exp(-0.5 * s * d) if d > 0.0 else 1.0


def empty_faces(shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uninitialised float32 face arrays (Fr, Ft, Fp) of a domain of ``shape`` (n_r, n_theta,
    n_phi), as :func:`face_factors` fills them."""
    n0, n1, n2 = shape
    return (np.empty((n0 + 1, n1, n2, 2), np.float32), np.empty((n0, n1 + 1, n2, 2), np.float32),
            np.empty((n0, n1, n2 + 1, 2), np.float32))


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def face_factors(sigma_t, sigma_s, g, params, paper, full, Fr, Ft, Fp, handover):
    """The transmittance and decay of a transfer across each face, (T, D) in the last axis of
    Fr float32 (n_r + 1, n_theta, n_phi, 2), Ft (n_r, n_theta + 1, n_phi, 2) and Fp (n_r,
    n_theta, n_phi + 1, 2) (:func:`empty_faces`), and each cell's hand-over factor into
    ``handover`` float32 (the domain's shape). A face's (T, D) is the product of the half steps
    of the two cells it joins, each of its own step length along the face's axis (dr, r dtheta,
    r sin(theta) dphi; both cells of a face share it):

      T = exp(-sigma_a s / 2),  D = exp(-sigma_s s (1 - g) / 2)  (``paper``: g^(sigma_s s / 2)),
      f = 1 - exp(-sigma_tr s_mean) where sigma_s > 0 and sigma_t > 0, else 0,

    s_mean the mean of the cell's three lengths (NumPy twins: twins.medium_factors and
    twins.handover_factor per cell, tests/twins.face_factors per face). Face k of Fr lies
    between shells k - 1 and k, face i of Ft between rows i - 1 and i, face j of Fp between
    columns j - 1 and j, so cell (k, i, j) sends out across Fr[k + 1] and in across Fr[k], and
    so on. At the domain's edges a face holds what a part crosses there: the sender's half step
    where it leaves (outer sphere; a cone's inner sphere and lateral faces), times the
    receiver's on a full sphere where it passes the light (inner face of shell 0: the antipodal
    cell (n_theta - 1 - i, j + n_phi / 2)), crosses a pole (first and last faces of Ft: the
    cell at phi + pi in the same row) or wraps in phi (first and last faces of Fp: columns 0
    and n_phi - 1)."""
    n0, n1, n2 = sigma_t.shape
    r0, dr, t0, dt, dp = params[0], params[1], params[2], params[3], params[5]
    half = n2 // 2
    m = (sigma_t, sigma_s, g, paper)
    for k in nb.prange(n0 + 1):
        for i in range(n1):                 # radial faces, between shells k - 1 and k
            for j in range(n2):
                if k == 0:                  # the inner face of shell 0: past the light
                    rates = _two(m, 0, i, j, 0, n1 - 1 - i, (j + half) % n2) if full else _one(m, 0, i, j)
                elif k == n0:               # the outer sphere
                    rates = _one(m, k - 1, i, j)
                else:
                    rates = _two(m, k - 1, i, j, k, i, j)
                _store(Fr, k, i, j, dr, rates)
        if k == n0:
            continue
        r = r0 + (k + 0.5) * dr
        s_t = r * dt
        for i in range(n1 + 1):             # theta faces, between rows i - 1 and i
            for j in range(n2):
                if i == 0 or i == n1:       # a pole: across it to phi + pi, or out of a cone
                    ie = 0 if i == 0 else n1 - 1
                    rates = _two(m, k, ie, j, k, ie, (j + half) % n2) if full else _one(m, k, ie, j)
                else:
                    rates = _two(m, k, i - 1, j, k, i, j)
                _store(Ft, k, i, j, s_t, rates)
        for i in range(n1):                 # phi faces, between columns j - 1 and j
            s_p = r * math.sin(t0 + (i + 0.5) * dt) * dp
            for j in range(n2 + 1):
                if j == 0 or j == n2:       # wrapping in phi, or out of a cone
                    je = 0 if j == 0 else n2 - 1
                    rates = _two(m, k, i, je, k, i, n2 - 1 - je) if full else _one(m, k, i, je)
                else:
                    rates = _two(m, k, i, j - 1, k, i, j)
                _store(Fp, k, i, j, s_p, rates)
            s_mean = (dr + s_t + s_p) / 3.0
            for j in range(n2):
                f = 0.0
                if sigma_s[k, i, j] > 0.0 and sigma_t[k, i, j] > 0.0:
                    a, d = cell_rates(sigma_t, sigma_s, g, k, i, j, False)     # sigma_tr = a + d
                    f = -math.expm1(-(a + d) * s_mean)
                handover[k, i, j] = f


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def direct_fluence(sigma_t, params, out):
    """``out`` float32 (the domain's shape): r^2 phi_dir = exp(-tau) at each cell centre per
    unit intensity, tau = sigma_t integrated along the ray from the inner sphere to the centre,
    sigma_t piecewise constant (Eq. 22; NumPy twin: twins.direct_fluence). An empty cell takes
    the exp(-tau) of the ray so far, kept per ray, so only cells that hold medium call exp."""
    n0, n1, n2 = sigma_t.shape
    dr = params[1]
    for i in nb.prange(n1):
        tau = np.zeros(n2)                  # along each ray of the row, to the shell's inner face
        seen = np.ones(n2)                  # exp(-tau): what an empty cell holds, without an exp
        for k in range(n0):
            for j in range(n2):
                half = np.float64(sigma_t[k, i, j]) * (0.5 * dr)
                if half == 0.0:             # most of a point light's domain is empty space
                    out[k, i, j] = seen[j]
                    continue
                out[k, i, j] = math.exp(-(tau[j] + half))
                tau[j] += 2.0 * half
                seen[j] = math.exp(-tau[j])


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def resample_spherical(grid, inv_voxel, grid_origin, centre, frame, params, shape, clamp, out):
    """Sample ``grid`` (a world voxel grid) at the centres of a spherical domain's cells into
    ``out`` float32 ``shape``; params = (r0, dr, theta0, dtheta, phi0, dphi). ``clamp``: clamp
    to the edge outside the grid instead of returning 0."""
    r0, dr, t0, dt, p0, dp = params[0], params[1], params[2], params[3], params[4], params[5]
    sin_p = np.sin(p0 + (np.arange(shape[2]) + 0.5) * dp)
    cos_p = np.cos(p0 + (np.arange(shape[2]) + 0.5) * dp)
    for k in nb.prange(shape[0]):
        r = r0 + (k + 0.5) * dr
        for i in range(shape[1]):
            t = t0 + (i + 0.5) * dt
            st = math.sin(t)
            ct = math.cos(t)
            for j in range(shape[2]):
                ox, oy, oz = _local(frame, r, st, ct, sin_p[j], cos_p[j])
                x = (centre[0] + ox - grid_origin[0]) * inv_voxel[0]
                y = (centre[1] + oy - grid_origin[1]) * inv_voxel[1]
                z = (centre[2] + oz - grid_origin[2]) * inv_voxel[2]
                if clamp:
                    out[k, i, j] = trilinear_clamped(grid, x, y, z)
                else:
                    out[k, i, j] = trilinear(grid, x, y, z)


@nb.njit(inline="always", fastmath=True, cache=True)
def spherical_index(centre, frame, params, full, wx, wy, wz):
    """Continuous cell index (centres at integers) of world point (wx, wy, wz), and its r."""
    dx = wx - centre[0]
    dy = wy - centre[1]
    dz = wz - centre[2]
    a = dx * frame[0, 0] + dy * frame[0, 1] + dz * frame[0, 2]
    b = dx * frame[1, 0] + dy * frame[1, 1] + dz * frame[1, 2]
    c = dx * frame[2, 0] + dy * frame[2, 1] + dz * frame[2, 2]
    r = math.sqrt(a * a + b * b + c * c)
    t = math.acos(min(1.0, max(-1.0, c / r))) if r > 0.0 else 0.0
    p = math.atan2(b, a)
    if full and p < 0.0:
        p += 2.0 * math.pi
    q0 = (r - params[0]) / params[1] - 0.5
    q1 = (t - params[2]) / params[3] - 0.5
    q2 = (p - params[4]) / params[5] - 0.5
    return q0, q1, q2, r


@nb.njit(fastmath=True, cache=True, nogil=True)
def splat_to_grid(Q, centre, frame, params, grid_origin, h, grid_frame, region, out):
    """Add each spherical cell's power Q (n_r, n_theta, n_phi) to the cell of a rectilinear
    domain (frame rows d, u, v, corner ``grid_origin``, cubic cells h; ``out`` its shape) that
    holds the cell's centre (the nearest edge cell if outside). If that cell is not in the
    diffusion ``region`` (bool, out's shape; the two grids sample the medium at different
    points, so this happens at the medium's edges), the power goes to the region cell among its
    26 neighbours whose centre is nearest; if there is none, it is returned as lost. Serial:
    two cells may land in the same target."""
    n0, n1, n2 = Q.shape
    m0, m1, m2 = out.shape
    r0, dr, t0, dt, p0, dp = params[0], params[1], params[2], params[3], params[4], params[5]
    lost = 0.0
    for k in range(n0):
        r = r0 + (k + 0.5) * dr
        for i in range(n1):
            t = t0 + (i + 0.5) * dt
            st = math.sin(t)
            ct = math.cos(t)
            for j in range(n2):
                e = Q[k, i, j]
                if e == 0.0:
                    continue
                p = p0 + (j + 0.5) * dp
                ox, oy, oz = _local(frame, r, st, ct, math.sin(p), math.cos(p))
                px = centre[0] + ox - grid_origin[0]
                py = centre[1] + oy - grid_origin[1]
                pz = centre[2] + oz - grid_origin[2]
                qa = (px * grid_frame[0, 0] + py * grid_frame[0, 1] + pz * grid_frame[0, 2]) / h
                qb = (px * grid_frame[1, 0] + py * grid_frame[1, 1] + pz * grid_frame[1, 2]) / h
                qc = (px * grid_frame[2, 0] + py * grid_frame[2, 1] + pz * grid_frame[2, 2]) / h
                a = min(max(int(math.floor(qa)), 0), m0 - 1)
                b = min(max(int(math.floor(qb)), 0), m1 - 1)
                c = min(max(int(math.floor(qc)), 0), m2 - 1)
                if not region[a, b, c]:
                    best = 1e300
                    ba, bb, bc = -1, -1, -1
                    for da in range(-1, 2):
                        for db in range(-1, 2):
                            for dc in range(-1, 2):
                                na, nb_, nc = a + da, b + db, c + dc
                                if (na < 0 or na >= m0 or nb_ < 0 or nb_ >= m1 or nc < 0 or nc >= m2
                                        or not region[na, nb_, nc]):
                                    continue
                                d2 = (na + 0.5 - qa) ** 2 + (nb_ + 0.5 - qb) ** 2 + (nc + 0.5 - qc) ** 2
                                if d2 < best:
                                    best = d2
                                    ba, bb, bc = na, nb_, nc
                    if ba < 0:
                        lost += e
                        continue
                    a, b, c = ba, bb, bc
                out[a, b, c] += e
    return lost


@nb.njit(inline="always", fastmath=True, cache=True)
def _move(absorbed, escaped, R, Ra, k_end, k, i, j, e, ea, F):
    """Send part (e, e a) across a face with factors F = (T, D) (:func:`face_factors`) to cell
    (k, i, j), unless that cell lies beyond the medium's box (k >= k_end[i, j],
    :func:`exit_shells`): then the part has left the box for good and is added to ``escaped``.
    Returns the running tallies (absorbed on the way, escaped)."""
    T = F[0]
    absorbed += e * (np.float32(1.0) - T)
    if k >= k_end[i, j]:
        return absorbed, escaped + e * T
    R[k, i, j] += e * T
    Ra[k, i, j] += ea * T * F[1]
    return absorbed, escaped


@nb.njit(inline="always", fastmath=True, cache=True)
def _gap(x, lo, hi):
    """How far x lies outside [lo, hi] (0 inside)."""
    return max(lo - x, 0.0, x - hi)


#: a cell is beyond the medium's box when its centre is farther from the box than this many of
#: its own diagonals (the renderer's trilinear stencil at a point in the box stays short of it)
EXIT_MARGIN = 2.0


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def exit_shells(centre, frame, params, shape, lo, hi):
    """int32 (n_theta, n_phi): per ray of cells (i, j), the first shell k_end from which every
    cell's centre lies farther than EXIT_MARGIN cell diagonals (dr, r dtheta, r sin(theta) dphi)
    from the box [lo, hi] (at least 1: shell 0 holds the light's own emission). The box is
    convex, so light that reaches such a cell has left it and never comes back: the sweep
    counts it as escaped instead of walking it on through empty space. A ray that misses the
    box gets 1; a domain whose box holds every cell gets n_r."""
    n0, n1, n2 = shape[0], shape[1], shape[2]
    r0, dr, t0, dt, p0, dp = params[0], params[1], params[2], params[3], params[4], params[5]
    out = np.empty((n1, n2), np.int32)
    for i in nb.prange(n1):
        t = t0 + (i + 0.5) * dt
        st = math.sin(t)
        ct = math.cos(t)
        for j in range(n2):
            p = p0 + (j + 0.5) * dp
            sp = math.sin(p)
            cp = math.cos(p)
            k_end = 0
            for kk in range(n0):
                k = n0 - 1 - kk
                r = r0 + (k + 0.5) * dr
                ox, oy, oz = _local(frame, r, st, ct, sp, cp)
                gx = _gap(centre[0] + ox, lo[0], hi[0])
                gy = _gap(centre[1] + oy, lo[1], hi[1])
                gz = _gap(centre[2] + oz, lo[2], hi[2])
                d2 = gx * gx + gy * gy + gz * gz
                diag2 = dr * dr + (r * dt) ** 2 + (r * st * dp) ** 2
                if d2 <= EXIT_MARGIN * EXIT_MARGIN * diag2:
                    k_end = k + 1
                    break
            out[i, j] = max(k_end, 1)
    return out


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def sweep_spherical_bands(R, Ra, Fr, Ft, Fp, table, moment, full, forward, flip, w_min, inv_area,
                          phi, phia, bands, band_lane, halo, anti, tally_b, handover, diffusive, Q, k_end):
    """One sweep over the shells (``forward``: outward), each band of theta rows by one
    thread, the lanes of ``band_lane`` in parallel (as kernels.propagation.sweep_bands); cells
    with pending power <= w_min wait.

    Fr, Ft, Fp: the faces' (T, D) (:func:`face_factors`). inv_area float32 (n_r, n_theta):
    1 / (r^2 Omega). halo float32 (n_bands, 2, 2, n_r, n_phi) parks side parts crossing into the
    band above/below; anti float32 (2, n_theta, n_phi) parks what passes the light into the
    antipodal cell of shell 0 (full sphere; each target has one sender). tally_b float64
    (n_bands, 5): four tallies and the cells that sent. k_end int32 (n_theta, n_phi)
    (:func:`exit_shells`): what reaches a cell at or beyond it has left the medium's box and is
    tallied as transmitted, so nothing is pending there (a band visits its shells up to its
    largest k_end only).
    """
    n0, n1, n2 = R.shape
    half = n2 // 2
    one = np.float32(1.0)
    for lane in nb.prange(lanes_of(band_lane)):
        for b in bands_of(band_lane, lane):
            lo = bands[b]
            hi = bands[b + 1]
            refl = 0.0
            trans = 0.0
            side_out = 0.0
            absorbed = 0.0
            sent = 0
            # beyond the band's last k_end nothing ever arrives: those shells are not visited
            n_k = 1
            for i in range(lo, hi):
                for j in range(n2):
                    n_k = max(n_k, k_end[i, j])
            for step in range(n_k):
                k = step if forward else n_k - 1 - step
                for si in range(hi - lo):
                    i = hi - 1 - si if flip else lo + si
                    for sj in range(n2):
                        j = n2 - 1 - sj if flip else sj
                        w = R[k, i, j]
                        if w <= w_min:
                            continue
                        wa = Ra[k, i, j]
                        R[k, i, j] = 0.0
                        Ra[k, i, j] = 0.0
                        sent += 1
                        if _hands_over(handover, diffusive, Q, k, i, j, w, wa):
                            continue
                        phi[k, i, j] += w * inv_area[k, i]
                        phia[k, i, j] += wa * inv_area[k, i]
                        ef, efa, es, esa, eb, eba = split(table, w, wa, moment)
                        # radial: out one shell (or out of the domain), in one shell
                        F = Fr[k + 1, i, j]
                        if k + 1 < n0:
                            absorbed, trans = _move(absorbed, trans, R, Ra, k_end, k + 1, i, j, ef, efa, F)
                        else:
                            trans += ef * F[0]
                            absorbed += ef * (one - F[0])
                        if eb > 0.0:
                            F = Fr[k, i, j]
                            if k > 0:
                                absorbed, trans = _move(absorbed, trans, R, Ra, k_end, k - 1, i, j, eb, eba, F)
                            elif full:                  # past the light, out of the antipodal cell
                                ia = n1 - 1 - i
                                ja = (j + half) % n2
                                anti[0, ia, ja] += eb * F[0]
                                anti[1, ia, ja] -= eba * F[0] * F[1]
                                absorbed += eb * (one - F[0])
                            else:
                                refl += eb * F[0]
                                absorbed += eb * (one - F[0])
                        if es <= 0.0:
                            continue
                        # phi neighbours: same band (wrapping on a full sphere)
                        for side in range(2):
                            jj = j - 1 + 2 * side
                            F = Fp[k, i, j + side]
                            if jj < 0 or jj >= n2:
                                if not full:
                                    side_out += es * F[0]
                                    absorbed += es * (one - F[0])
                                    continue
                                jj = _wrap(jj, n2)
                            absorbed, trans = _move(absorbed, trans, R, Ra, k_end, k, i, jj, es, esa, F)
                        # theta neighbours: across a pole (same row), in the band, or parked
                        for side in range(2):
                            ii = i - 1 + 2 * side
                            F = Ft[k, i + side, j]
                            if ii < 0 or ii >= n1:
                                if not full:
                                    side_out += es * F[0]
                                    absorbed += es * (one - F[0])
                                    continue
                                absorbed, trans = _move(absorbed, trans, R, Ra, k_end, k, i, (j + half) % n2,
                                                        es, esa, F)
                            elif ii >= lo and ii < hi:
                                absorbed, trans = _move(absorbed, trans, R, Ra, k_end, k, ii, j, es, esa, F)
                            elif k >= k_end[ii, j]:
                                trans += es * F[0]
                                absorbed += es * (one - F[0])
                            else:
                                halo[b, side, 0, k, j] += es * F[0]
                                halo[b, side, 1, k, j] += esa * F[0] * F[1]
                                absorbed += es * (one - F[0])
            tally_b[b, REFLECTED] += refl
            tally_b[b, TRANSMITTED] += trans
            tally_b[b, SIDE_ESCAPED] += side_out
            tally_b[b, ABSORBED] += absorbed
            tally_b[b, 4] += sent


@nb.njit(fastmath=True, cache=True, nogil=True)
def sweep(R, Ra, Fr, Ft, Fp, table, moment, full, forward, flip, w_min, inv_area, phi, phia, bands,
          band_lane, halo, anti, tally_b, handover, diffusive, Q, k_end):
    """One sweep (sweep_spherical_bands, the bands dealt to lanes by ``band_lane``, as
    kernels.propagation.sweep) and the delivery of parked parts; returns the power pending."""
    tally_b[:] = 0.0
    sweep_spherical_bands(R, Ra, Fr, Ft, Fp, table, moment, full, forward, flip, w_min, inv_area,
                          phi, phia, bands, band_lane, halo, anti, tally_b, handover, diffusive, Q, k_end)
    deliver(R, Ra, bands, halo, anti)
    return total_energy(R)


@nb.njit(fastmath=True, cache=True, nogil=True)
def deliver(R, Ra, bands, halo, anti):
    """After a sweep: side parts parked at band edges go to their rows (bands never wrap in
    theta), and what passed the light goes to shell 0."""
    n0, n1, n2 = R.shape
    for b in range(bands.shape[0] - 1):
        for side in range(2):
            ii = bands[b] - 1 if side == 0 else bands[b + 1]
            if ii < 0 or ii >= n1:
                continue
            for k in range(n0):
                for j in range(n2):
                    e = halo[b, side, 0, k, j]
                    if e != 0.0:
                        _add(R, Ra, k, ii, j, e, halo[b, side, 1, k, j])
                        halo[b, side, 0, k, j] = 0.0
                        halo[b, side, 1, k, j] = 0.0
    for i in range(n1):
        for j in range(n2):
            if anti[0, i, j] != 0.0:
                _add(R, Ra, 0, i, j, anti[0, i, j], anti[1, i, j])
                anti[0, i, j] = 0.0
                anti[1, i, j] = 0.0
