"""Numba ray-marching kernel (METHOD.md step 6, RECONSTRUCTION.md 2.10).

For a camera ray x(t) = c + t v:
  L = int T_v(t) L_s(x(t), -v) dt + T_v(t_max) L_background,   T_v(t) = exp(-int_0^t sigma_t)
  L_s(x, w_o) = sigma_s(x) sum_l E_l phi_l(x) f_hg(d_l . w_o; g(x) A_l(x))
where phi_l is the light's fluence per unit irradiance and A_l = phia_l / phi_l its lobe's
anisotropy (a point light: E_l is its intensity, d_l = (x - p_l) / r the direction from the
light, and phi_l and A_l are looked up in the light's spherical domain at the sample, where
r^2 phi_l is stored: phi_l = (r^2 phi_l) / r^2, see popvol/spherical.py); f_hg(.; g A) is the
exact convolution of the lobe HG_A with the phase HG_g (supplement Eq. 3).

A sun's (or point light's) fluence is a mixture: its unscattered light phi_dir = exp(-tau) (a delta lobe along
d_l; propagate.direct_fluence) and the scattered rest. One HG lobe of the mixture's mean
anisotropy understates what the mixture scatters sideways and back (HG(.; g A) is convex in A
there), so the two are lit apart:
  phi_l f_hg(.; g A_l)  ->  phi_dir f_hg(.; g) + (phi_l - phi_dir) f_hg(.; g A_rest),
  A_rest = (phia_l - phi_dir) / (phi_l - phi_dir)
(the same fluence and first moment). phi_dir is taken at most phi_l: the walk's fluence holds
the unscattered light, and only interpolation across a shadow edge can put it below.

Each march segment of length ds uses sigma_t at a jittered point inside it and integrates T_v
exactly over the segment: int T = T_v (1 - exp(-sigma_t ds)) / sigma_t.
"""
import math

import numba as nb
import numpy as np

from .sampling import corner_weights
from .spherical import spherical_index

INV_FOUR_PI = 1.0 / (4.0 * math.pi)
MAX_DIFFUSE_ANISOTROPY = 0.5   # |J| / phi at a Marshak (vacuum) boundary, where diffusion's light
                               # leaves; 1/3 (P1 >= 0) left the lit faces ~6 % dark, 1 made speckles
T_MIN = 1e-4    # stop marching when the view transmittance falls below this (bias <= 1e-4 of L)


@nb.njit(inline="always", fastmath=True, cache=True)
def f_hg(mu, g):
    """Henyey-Greenstein phase function (supplement Eq. 1), |g| < 1."""
    d = 1.0 + g * g - 2.0 * g * mu
    return (1.0 - g * g) * INV_FOUR_PI / (d * math.sqrt(d))


@nb.njit(inline="always", cache=True)
def _mix(h):
    """splitmix64 finaliser: a bijective scramble of a 64-bit integer."""
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


@nb.njit(inline="always", cache=True)
def hash_uniform(seed, x, y, s, dim):
    """A uniform number in [0, 1) from integer coordinates (seed, pixel x, y, sample, dimension)."""
    golden = np.uint64(0x9E3779B97F4A7C15)
    h = _mix(np.uint64(seed) + golden)
    h = _mix(h ^ (np.uint64(x) + golden))
    h = _mix(h ^ (np.uint64(y) + golden))
    h = _mix(h ^ (np.uint64(s) + golden))
    h = _mix(h ^ (np.uint64(dim) + golden))
    return (h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@nb.njit(inline="always", fastmath=True, cache=True)
def _interp(grid, i0, i1, j0, j1, k0, k1, fx, fy, fz):
    c00 = grid[i0, j0, k0] * (1 - fz) + grid[i0, j0, k1] * fz
    c01 = grid[i0, j1, k0] * (1 - fz) + grid[i0, j1, k1] * fz
    c10 = grid[i1, j0, k0] * (1 - fz) + grid[i1, j0, k1] * fz
    c11 = grid[i1, j1, k0] * (1 - fz) + grid[i1, j1, k1] * fz
    return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx


@nb.njit(inline="always", fastmath=True, cache=True)
def point_lookup(fields, off, shape, q0, q1, q2, full):
    """(r^2 phi, r^2 phia, r^2 phi_dir) of a point light's spherical block (fields[:, off:], C-ordered
    ``shape``) at continuous cell index (q0, q1, q2): trilinear, clamped in r and theta,
    periodic in phi on a full sphere (NumPy twin: kernels.reference.spherical_to_world)."""
    n0, n1, n2 = shape[0], shape[1], shape[2]
    k0, k1, fk = corner_weights(q0, n0)
    i0, i1, fi = corner_weights(q1, n1)
    if full:
        jf = math.floor(q2)
        fj = q2 - jf
        j0 = int(jf) % n2
        j1 = (j0 + 1) % n2
    else:
        j0, j1, fj = corner_weights(q2, n2)
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for a in range(8):
        k = k1 if a & 4 else k0
        i = i1 if a & 2 else i0
        j = j1 if a & 1 else j0
        w = (fk if a & 4 else 1.0 - fk) * (fi if a & 2 else 1.0 - fi) * (fj if a & 1 else 1.0 - fj)
        idx = off + (k * n1 + i) * n2 + j
        out0 += w * fields[0, idx]
        out1 += w * fields[1, idx]
        out2 += w * fields[2, idx]
    return out0, out1, out2


@nb.njit(inline="always", fastmath=True, cache=True)
def ray_box(o, d, lo, hi):
    """Entry and exit distances of the ray o + t d with the box [lo, hi] (t0 >= 0)."""
    t0 = 0.0
    t1 = 1e300
    for a in range(3):
        if abs(d[a]) < 1e-300:
            if o[a] < lo[a] or o[a] > hi[a]:
                return 1.0, 0.0
            continue
        inv = 1.0 / d[a]
        ta = (lo[a] - o[a]) * inv
        tb = (hi[a] - o[a]) * inv
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    return t0, t1


@nb.njit(inline="always", fastmath=True, cache=True)
def _diffuse_lobe(phid, flux, i0, i1, j0, j1, k0, k1, fx, fy, fz, d, gg):
    """phi_d * f_hg(-d . J/|J|; g |J| / phi_d): the diffuse light's lobe about its own flux J,
    convolved with the phase function (see popvol/diffusion.py), seen along the camera ray d."""
    pd = _interp(phid, i0, i1, j0, j1, k0, k1, fx, fy, fz)
    if pd <= 0.0:
        return 0.0
    jx = _interp(flux[0], i0, i1, j0, j1, k0, k1, fx, fy, fz)
    jy = _interp(flux[1], i0, i1, j0, j1, k0, k1, fx, fy, fz)
    jz = _interp(flux[2], i0, i1, j0, j1, k0, k1, fx, fy, fz)
    jn = math.sqrt(jx * jx + jy * jy + jz * jz)
    if jn <= 0.0:
        return pd * INV_FOUR_PI
    A = min(jn / pd, MAX_DIFFUSE_ANISOTROPY)
    mu = -(jx * d[0] + jy * d[1] + jz * d[2]) / jn
    return pd * f_hg(mu, gg * A)


@nb.njit(inline="always", fastmath=True, cache=True)
def background_radiance(bg, d, out):
    """The background seen along direction d, into out (3,): a constant (bg of shape
    (1, 1, 3)) or a lat-long map in Mitsuba's envmap convention (popvol/envmap.py), bilinear
    between texel centres, wrapping in u."""
    H = bg.shape[0]
    W = bg.shape[1]
    if H == 1 and W == 1:
        for c in range(3):
            out[c] = bg[0, 0, c]
        return
    u = math.atan2(d[0], -d[2]) * (0.5 / math.pi)
    u -= math.floor(u)
    v = math.acos(min(1.0, max(-1.0, d[1]))) / math.pi
    x = u * W - 0.5
    y = min(max(v * H - 0.5, 0.0), H - 1.0)
    j0 = int(math.floor(x))
    fx = x - j0
    i0 = min(int(y), H - 2) if H > 1 else 0
    fy = y - i0
    i1 = min(i0 + 1, H - 1)
    ja = j0 % W
    jb = (j0 + 1) % W
    for c in range(3):
        top = bg[i0, ja, c] * (1.0 - fx) + bg[i0, jb, c] * fx
        bot = bg[i1, ja, c] * (1.0 - fx) + bg[i1, jb, c] * fx
        out[c] = top * (1.0 - fy) + bot * fy


@nb.njit(parallel=True, fastmath=True, cache=True)
def render_kernel(density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi,
                  phi, phia, direct, phid, flux, light_dir, irradiance, light_pos, is_point, p_fields,
                  p_offset, p_shape, p_params, p_frame, p_full, background,
                  cam_origin, cam_basis, tan_half, width, height,
                  step, spp, seed, jitter, out):
    """Render into ``out`` float32 (height, width, 3), linear radiance.

    density: float32 (nx, ny, nz); scale: float64 (3,), sigma_t per channel = scale * density;
    albedo, g_grid: float32 grids (1,1,1) or density-shaped; albedo_rgb: float64 (3,), the
    albedo of channel c is albedo * albedo_rgb[c];
    phi, phia: float32 (n_lights, n_channels (1 or 3), nx, ny, nz) per unit irradiance;
    direct: the same shape: the unscattered part of phi (0 where a light has none);
    phid, flux: the diffuse lobe's fluence (n_lights, n_channels, ...) and world flux vector
    (n_lights, n_channels, 3, ...), or arrays with n_lights = 0 when there is no diffusion stage;
    light_dir, irradiance: float64 (n_lights, 3); light_pos float64 (n_lights, 3) and is_point
    bool (n_lights,): point lights, whose walk fields are p_fields .. p_full (the arrays of
    spherical.PointFields) instead of phi, phia; background: float32 (1, 1, 3) (a constant)
    or (H, 2H, 3) (a lat-long environment map, see background_radiance);
    cam_basis rows forward, right, up; step in world units; jitter: random sub-pixel and
    along-ray offsets (False: pixel centres and segment midpoints, for tests).
    """
    nx, ny, nz = density.shape
    has_diffuse = phid.shape[0] > 0
    n_lights = phi.shape[0]
    n_ch = phi.shape[1]
    aspect = width / height
    const_albedo = albedo.size == 1      # else a grid of the density's shape
    const_g = g_grid.size == 1
    for py in nb.prange(height):
        d = np.empty(3)
        rgb = np.empty(3)
        ls = np.empty(3)
        Tv = np.empty(3)
        bgv = np.empty(3)
        for px in range(width):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for s in range(spp):
                if jitter:
                    jx = hash_uniform(seed, px, py, s, 0)
                    jy = hash_uniform(seed, px, py, s, 1)
                    jt = hash_uniform(seed, px, py, s, 2)
                else:
                    jx = 0.5
                    jy = 0.5
                    jt = 0.5
                sx = (2.0 * (px + jx) / width - 1.0) * tan_half * aspect
                sy = (1.0 - 2.0 * (py + jy) / height) * tan_half
                for a in range(3):
                    d[a] = cam_basis[0, a] + sx * cam_basis[1, a] + sy * cam_basis[2, a]
                norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                for a in range(3):
                    d[a] /= norm
                for c in range(3):
                    rgb[c] = 0.0
                    Tv[c] = 1.0
                t0, t1 = ray_box(cam_origin, d, lo, hi)
                t = t0
                while t < t1:
                    ds = min(step, t1 - t)
                    ts = t + jt * ds
                    t += ds
                    x = (cam_origin[0] + ts * d[0] - origin[0]) / voxel[0]
                    y = (cam_origin[1] + ts * d[1] - origin[1]) / voxel[1]
                    z = (cam_origin[2] + ts * d[2] - origin[2]) / voxel[2]
                    i0, i1, fx = corner_weights(x, nx)
                    j0, j1, fy = corner_weights(y, ny)
                    k0, k1, fz = corner_weights(z, nz)
                    rho = _interp(density, i0, i1, j0, j1, k0, k1, fx, fy, fz)
                    if rho <= 0.0:
                        continue
                    if const_albedo:
                        alb = albedo[0, 0, 0]
                    else:
                        alb = _interp(albedo, i0, i1, j0, j1, k0, k1, fx, fy, fz)
                    if const_g:
                        gg = g_grid[0, 0, 0]
                    else:
                        gg = _interp(g_grid, i0, i1, j0, j1, k0, k1, fx, fy, fz)
                    ls[0] = 0.0
                    ls[1] = 0.0
                    ls[2] = 0.0
                    for l in range(n_lights):
                        point = is_point[l]
                        inv_r2 = 1.0
                        q0 = q1 = q2 = 0.0
                        if point:
                            wx = cam_origin[0] + ts * d[0]
                            wy = cam_origin[1] + ts * d[1]
                            wz = cam_origin[2] + ts * d[2]
                            q0, q1, q2, r = spherical_index(light_pos[l], p_frame[l], p_params[l],
                                                           p_full[l], wx, wy, wz)
                            r = max(r, 1e-15)
                            inv_r2 = 1.0 / (r * r)
                            mu = -((wx - light_pos[l, 0]) * d[0] + (wy - light_pos[l, 1]) * d[1]
                                   + (wz - light_pos[l, 2]) * d[2]) / r
                        else:
                            mu = -(light_dir[l, 0] * d[0] + light_dir[l, 1] * d[1] + light_dir[l, 2] * d[2])
                        for c in range(n_ch):
                            pa = 0.0
                            pdir = 0.0
                            if point:
                                p, pa, pdir = point_lookup(p_fields, p_offset[l, c], p_shape[l], q0, q1, q2,
                                                           p_full[l])
                            else:
                                p = _interp(phi[l, c], i0, i1, j0, j1, k0, k1, fx, fy, fz)
                            val = 0.0
                            if p > 0.0:
                                if not point:
                                    pa = _interp(phia[l, c], i0, i1, j0, j1, k0, k1, fx, fy, fz)
                                    pdir = _interp(direct[l, c], i0, i1, j0, j1, k0, k1, fx, fy, fz)
                                pdir = min(pdir, p)
                                if pdir > 0.0:          # the unscattered light: a delta lobe
                                    val = pdir * inv_r2 * f_hg(mu, max(min(gg, 0.9999), -0.9999))
                                    p -= pdir
                                    pa -= pdir
                            if p > 0.0:
                                A = pa / p
                                p *= inv_r2
                                gA = gg * A
                                if gA > 0.9999:
                                    gA = 0.9999
                                elif gA < -0.9999:
                                    gA = -0.9999
                                val += p * f_hg(mu, gA)
                            if has_diffuse:
                                val += _diffuse_lobe(phid[l, c], flux[l, c], i0, i1, j0, j1, k0, k1,
                                                     fx, fy, fz, d, gg)
                            if n_ch == 1:
                                ls[0] += val * irradiance[l, 0]
                                ls[1] += val * irradiance[l, 1]
                                ls[2] += val * irradiance[l, 2]
                            else:
                                ls[c] += val * irradiance[l, c]
                    for c in range(3):
                        sigma_t = scale[c] * rho
                        if sigma_t > 0.0:
                            Tseg = math.exp(-sigma_t * ds)
                            # int_seg T dt = Tv (1 - Tseg) / sigma_t, times sigma_s = albedo sigma_t
                            rgb[c] += Tv[c] * (1.0 - Tseg) * alb * albedo_rgb[c] * ls[c]
                            Tv[c] *= Tseg
                    if max(Tv[0], Tv[1], Tv[2]) < T_MIN:
                        for c in range(3):
                            Tv[c] = 0.0
                        break
                background_radiance(background, d, bgv)
                acc0 += rgb[0] + Tv[0] * bgv[0]
                acc1 += rgb[1] + Tv[1] * bgv[1]
                acc2 += rgb[2] + Tv[2] * bgv[2]
            out[py, px, 0] = acc0 / spp
            out[py, px, 1] = acc1 / spp
            out[py, px, 2] = acc2 / spp
