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
            # only the cosine to the slab normal matters: rotate it about a random azimuth
            ct = _sample_cos(g)
            st = math.sqrt(max(0.0, 1.0 - ct * ct))
            mu = mu * ct + math.sqrt(max(0.0, 1.0 - mu * mu)) * st * math.cos(2.0 * math.pi * np.random.random())
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
