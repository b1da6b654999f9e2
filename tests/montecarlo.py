"""Independent Monte Carlo oracles for the tests (no popvol code is used).

A homogeneous medium of extinction tau (per unit length, unit-size geometry), single-scattering
albedo and Henyey-Greenstein phase g. Weighted random walks: at each event the weight is
multiplied by the albedo (the lost share is absorbed); Russian roulette below 1e-3 keeps the
estimate unbiased. Serial Numba loops with a fixed seed, so results are deterministic.
"""
import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _sample_cos(g):
    """cos(theta) distributed as HG_g (inverse CDF)."""
    u = np.random.random()
    if abs(g) < 1e-6:
        return 2.0 * u - 1.0
    t = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return min(1.0, max(-1.0, (1.0 + g * g - t * t) / (2.0 * g)))


@nb.njit(cache=True)
def _scatter(ux, uy, uz, g):
    """New unit direction after an HG scattering event from direction (ux, uy, uz)."""
    ct = _sample_cos(g)
    st = math.sqrt(max(0.0, 1.0 - ct * ct))
    phi = 2.0 * math.pi * np.random.random()
    cp, sp = math.cos(phi), math.sin(phi)
    if abs(uz) > 0.99999:
        return st * cp, st * sp, ct * (1.0 if uz > 0 else -1.0)
    den = math.sqrt(1.0 - uz * uz)
    nx = st * (ux * uz * cp - uy * sp) / den + ux * ct
    ny = st * (uy * uz * cp + ux * sp) / den + uy * ct
    nz = -st * cp * den + uz * ct
    n = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / n, ny / n, nz / n


@nb.njit(cache=True)
def _scatter_mu(mu, g):
    """The cosine to a slab's normal after an HG scattering event from cosine ``mu`` (in a
    plane-parallel medium only that cosine matters: the new direction about a random azimuth)."""
    ct = _sample_cos(g)
    st = math.sqrt(max(0.0, 1.0 - ct * ct))
    return mu * ct + math.sqrt(max(0.0, 1.0 - mu * mu)) * st * math.cos(2.0 * math.pi * np.random.random())


@nb.njit(cache=True)
def _roulette(w):
    if w < 1e-3:
        if np.random.random() < 0.1:
            return w / 0.1
        return 0.0
    return w


@nb.njit(cache=True)
def _slab(tau, albedo, g, n, seed):
    np.random.seed(seed)
    t_sum = t_sq = r_sum = r_sq = a_sum = 0.0
    for _ in range(n):
        z, mu, w = 0.0, 1.0, 1.0
        t_i = r_i = 0.0
        while w > 0.0:
            z += mu * (-math.log(1.0 - np.random.random()) / tau)
            if z >= 1.0:
                t_i += w
                break
            if z <= 0.0:
                r_i += w
                break
            a_sum += w * (1.0 - albedo)
            w = _roulette(w * albedo)
            if w == 0.0:
                break
            mu = _scatter_mu(mu, g)
        t_sum += t_i
        t_sq += t_i * t_i
        r_sum += r_i
        r_sq += r_i * r_i
    return t_sum, t_sq, r_sum, r_sq, a_sum


def slab_mc(tau, albedo, g, n_photons=200_000, seed=0):
    """Plane-parallel slab of optical thickness tau, collimated normal incidence at the top.

    Returns fractions of the incident power: T (out through the bottom, scattered or not),
    R (out through the top), A (absorbed), and the standard errors of T and R.
    """
    t, t2, r, r2, a = _slab(float(tau), float(albedo), float(g), int(n_photons), int(seed))
    n = n_photons
    return {"T": t / n, "R": r / n, "A": a / n,
            "stderr_T": math.sqrt(max(t2 / n - (t / n) ** 2, 0) / n),
            "stderr_R": math.sqrt(max(r2 / n - (r / n) ** 2, 0) / n)}


@nb.njit(cache=True)
def _slab_tally(mu0, albedo, g, depth, nbins, lmax, scattered_only, n, seed):
    """Per depth bin, each flight's track length times P_l(mu), l = 0..lmax (the light that has
    scattered only, or all of it)."""
    np.random.seed(seed)
    acc = np.zeros((nbins, lmax + 1))
    P = np.zeros(lmax + 1)
    dz = depth / nbins
    for _ in range(n):
        z, mu, w = 0.0, mu0, 1.0
        scattered = False
        while w > 0.0:
            z1 = z + mu * (-math.log(1.0 - np.random.random()))
            lo, hi = (z, min(z1, depth)) if mu > 0.0 else (max(z1, 0.0), z)
            if (scattered or not scattered_only) and mu != 0.0 and hi > lo:
                P[0] = 1.0
                if lmax > 0:
                    P[1] = mu
                for l in range(2, lmax + 1):          # Bonnet's recursion
                    P[l] = ((2 * l - 1) * mu * P[l - 1] - (l - 1) * P[l - 2]) / l
                for b in range(int(lo / dz), min(int(hi / dz), nbins - 1) + 1):   # the flight's
                    part = min(hi, (b + 1) * dz) - max(lo, b * dz)                 # length in each bin
                    if part > 0.0:
                        track = w * part / abs(mu)
                        for l in range(lmax + 1):
                            acc[b, l] += track * P[l]
            if z1 <= 0.0 or z1 >= depth:
                break
            z = z1
            w = _roulette(w * albedo)
            if w == 0.0:
                break
            mu = _scatter_mu(mu, g)
            scattered = True
    return acc


def slab_fluence_mc(mu0, albedo, g, depth, n_bins, n_photons=200_000, seed=0):
    """Fluence inside a plane-parallel slab of optical thickness ``depth`` lit at its top by a
    collimated beam of unit irradiance (normal to the beam) at cos ``mu0`` to the normal:
    float64 (n_bins,), the mean fluence over each of n_bins equal layers from the top, in units
    of the irradiance (the track length in each layer: the unscattered light alone gives
    exp(-z / mu0) averaged over the layer)."""
    acc = _slab_tally(float(mu0), float(albedo), float(g), float(depth), int(n_bins), 0, False, int(n_photons),
                      int(seed))[:, 0]
    return mu0 * acc / (n_photons * (depth / n_bins))


def slab_legendre_mc(albedo, g, depth, n_bins, lmax=48, n_photons=200_000, seed=0):
    """The scattered light's angular shape inside a plane-parallel slab of optical thickness
    ``depth`` lit at its top by a collimated beam of unit irradiance along its normal: float64
    (n_bins, lmax + 1), per layer (n_bins equal layers from the top), the scattered fluence
    (column 0, in units of the irradiance) times the Legendre moments <P_l(mu)> of its radiance
    about the beam (column l; mu the cosine to the beam). Track-length estimates of the light
    that scattered at least once, so column 0 is slab_fluence_mc's fluence less exp(-z)."""
    acc = _slab_tally(1.0, float(albedo), float(g), float(depth), int(n_bins), int(lmax), True, int(n_photons),
                      int(seed))
    return acc / (n_photons * (depth / n_bins))


@nb.njit(cache=True)
def _r2_integral(a, b, c, d, L):
    """int_0^L (a + b t)^2 + (c + d t)^2 dt."""
    return (a * a + c * c) * L + (a * b + c * d) * L * L + (b * b + d * d) * L * L * L / 3.0


@nb.njit(cache=True)
def _cube(tau, albedo, g, halfwidth, n, seed, nbins, faces, faces_sq, fluence, r2_bins):
    np.random.seed(seed)
    absorbed = 0.0
    track = 0.0
    track_r2 = 0.0
    face_i = np.zeros(3)
    for _ in range(n):
        x = 0.0
        y = 0.5 + halfwidth * (2.0 * np.random.random() - 1.0)
        z = 0.5 + halfwidth * (2.0 * np.random.random() - 1.0)
        ux, uy, uz = 1.0, 0.0, 0.0
        w = 1.0
        face_i[:] = 0.0
        while w > 0.0:
            s = -math.log(1.0 - np.random.random()) / tau
            # distance to the cube's boundary along u, and which face
            t_exit = 1e300
            face = -1
            for axis in range(3):
                p = x if axis == 0 else (y if axis == 1 else z)
                u = ux if axis == 0 else (uy if axis == 1 else uz)
                if u > 1e-300:
                    t = (1.0 - p) / u
                    f = 0 if axis == 0 else 2       # transmitted / side
                elif u < -1e-300:
                    t = -p / u
                    f = 1 if axis == 0 else 2       # reflected / side
                else:
                    continue
                if t < t_exit:
                    t_exit = t
                    face = f
            L = min(s, t_exit)
            # track-length tallies of this segment
            track += w * L
            track_r2 += w * _r2_integral(y - 0.5, uy, z - 0.5, uz, L)
            for b in range(nbins):
                x0, x1 = b / nbins, (b + 1) / nbins
                if abs(ux) < 1e-300:
                    if x0 <= x < x1:
                        ta, tb = 0.0, L
                    else:
                        continue
                else:
                    ta, tb = (x0 - x) / ux, (x1 - x) / ux
                    if ta > tb:
                        ta, tb = tb, ta
                    ta, tb = max(ta, 0.0), min(tb, L)
                if tb <= ta:
                    continue
                fluence[b] += w * (tb - ta)
                yy, zz = y - 0.5 + ta * uy, z - 0.5 + ta * uz
                r2_bins[b] += w * _r2_integral(yy, uy, zz, uz, tb - ta)
            if s >= t_exit:
                face_i[face] += w
                break
            x += s * ux
            y += s * uy
            z += s * uz
            absorbed += w * (1.0 - albedo)
            w = _roulette(w * albedo)
            if w == 0.0:
                break
            ux, uy, uz = _scatter(ux, uy, uz, g)
        for f in range(3):
            faces[f] += face_i[f]
            faces_sq[f] += face_i[f] * face_i[f]
    return absorbed, track, track_r2


def cube_beam_mc(tau, albedo, g, beam_halfwidth, n_photons=100_000, seed=0, n_depth_bins=16):
    """A collimated beam travelling +x into the cube [0, 1]^3 (sigma_t = tau) through the
    square |y - 1/2|, |z - 1/2| <= beam_halfwidth of the face x = 0.

    Returns fractions of the incident power leaving through the faces x = 1 ("transmitted"),
    x = 0 ("reflected"), y = 0, 1 and z = 0, 1 together ("side"), and "absorbed", with
    "stderr_<name>"; "r2_mean", the fluence-weighted mean of (y - 1/2)^2 + (z - 1/2)^2 over the
    cube (track-length estimator, integrated exactly along each segment); "fluence_depth", the
    track length per depth bin per unit incident power and unit bin width (1 everywhere for an
    unattenuated beam: the fluence integrated over the cross-section); "r2_depth", the
    fluence-weighted mean r^2 per depth bin.
    """
    faces, faces_sq = np.zeros(3), np.zeros(3)
    fluence, r2_bins = np.zeros(n_depth_bins), np.zeros(n_depth_bins)
    absorbed, track, track_r2 = _cube(float(tau), float(albedo), float(g), float(beam_halfwidth),
                                      int(n_photons), int(seed), int(n_depth_bins), faces, faces_sq,
                                      fluence, r2_bins)
    n = n_photons
    out = {"absorbed": absorbed / n, "r2_mean": track_r2 / track,
           "fluence_depth": fluence * n_depth_bins / n,
           "r2_depth": np.divide(r2_bins, fluence, out=np.zeros_like(fluence), where=fluence > 0)}
    for f, name in enumerate(("transmitted", "reflected", "side")):
        out[name] = faces[f] / n
        out["stderr_" + name] = math.sqrt(max(faces_sq[f] / n - (faces[f] / n) ** 2, 0) / n)
    return out


@nb.njit(cache=True)
def _half_space(mu0, view, albedo, g, depth, n, seed):
    """Photons enter z = 0 of the medium z in [0, depth] (optical depth units) along (sqrt(1 -
    mu0^2), 0, mu0); at each collision a next-event estimate of the radiance scattered out of
    z = 0 along the unit ``view`` (its z < 0). Returns the sums and squared sums of the
    single-scattering and total estimates per photon."""
    np.random.seed(seed)
    vx, vy, vz = view
    mu_v = -vz
    s1 = s1q = st = stq = 0.0
    for _ in range(n):
        z = 0.0
        ux, uy, uz = math.sqrt(1.0 - mu0 * mu0), 0.0, mu0
        w = 1.0
        first = True
        single = total = 0.0
        while w > 0.0:
            z += uz * (-math.log(1.0 - np.random.random()))
            if z < 0.0 or z > depth:
                break
            cos_t = ux * vx + uy * vy + uz * vz
            # the scattered light's share toward the view, HG (supplement Eq. 1), seen through z / mu_v
            p = (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_t) ** 1.5)
            c = w * albedo * p * math.exp(-z / mu_v) / mu_v
            total += c
            if first:
                single = c
                first = False
            w = _roulette(w * albedo)
            ux, uy, uz = _scatter(ux, uy, uz, g)
        s1 += single
        s1q += single * single
        st += total
        stq += total * total
    return s1, s1q, st, stq


def half_space_mc(light, view, albedo, g, depth=math.inf, n_photons=400_000, seed=0):
    """Radiance reflected by the plane-parallel medium below z = 0 (world), optical thickness
    ``depth`` (inf: a half-space), lit by a sun of unit irradiance travelling along ``light``
    (its z < 0) and seen along ``view`` (the unit direction from the surface to the eye, z > 0).
    Returns {"single", "total"} and their standard errors ("stderr_single", "stderr_total")."""
    l = np.asarray(light, float) / np.linalg.norm(light)
    v = np.asarray(view, float) / np.linalg.norm(view)
    az = math.atan2(l[1], l[0]) if abs(l[0]) + abs(l[1]) > 0 else 0.0
    c, s = math.cos(az), math.sin(az)       # turn the light's azimuth to +x; z into the medium
    out = (c * v[0] + s * v[1], -s * v[0] + c * v[1], -v[2])
    mu0 = -l[2]
    s1, s1q, st, stq = _half_space(mu0, out, float(albedo), float(g), min(float(depth), 1e300),
                                   int(n_photons), int(seed))
    n = n_photons
    # per photon entering the surface; photons per unit area = irradiance times mu0
    return {"single": mu0 * s1 / n, "total": mu0 * st / n,
            "stderr_single": mu0 * math.sqrt(max(s1q / n - (s1 / n) ** 2, 0) / n),
            "stderr_total": mu0 * math.sqrt(max(stq / n - (st / n) ** 2, 0) / n)}


def chandrasekhar_h(mu, albedo, n=64, iterations=400):
    """Chandrasekhar's H function of isotropic scattering with single-scattering ``albedo``, at
    cosines ``mu``: H(mu) = 1 + mu H(mu) (albedo / 2) int_0^1 H(m) / (mu + m) dm, iterated on an
    n-point Gauss-Legendre rule of [0, 1] (Chandrasekhar, Radiative Transfer, 1950, Ch. V)."""
    x, wq = np.polynomial.legendre.leggauss(n)
    m, wq = 0.5 * (x + 1), 0.5 * wq
    H = np.ones(n)
    for _ in range(iterations):
        H = 1.0 / (1.0 - m * 0.5 * albedo * np.sum(wq * H / (m[:, None] + m), axis=1))
    mu = np.asarray(mu, float)
    return 1.0 / (1.0 - mu * 0.5 * albedo * np.sum(wq * H / (mu[..., None] + m), axis=-1))
