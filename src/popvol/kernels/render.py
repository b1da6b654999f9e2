"""Numba ray-marching kernel: the image of a solved scene (docs/METHOD.md, "Rendering").

For a camera ray x(t) = c + t v:
  L = int T_v(t) L_s(x(t), -v) dt + T_v(t_max) L_background,   T_v(t) = exp(-int_0^t sigma_t)
  L_s(x, w_o) = sigma_s(x) sum_l E_l phi_l(x) f_hg(d_l . w_o; g(x) A_l(x))
where phi_l is the light's fluence per unit irradiance and A_l = phia_l / phi_l its lobe's
anisotropy (a point light: E_l is its intensity, d_l = (x - p_l) / r the direction from the
light, and phi_l and A_l are looked up in the light's spherical domain at the sample, where
r^2 phi_l is stored: phi_l = (r^2 phi_l) / r^2); f_hg(.; g A) is the exact convolution of the
lobe HG_A with the phase HG_g (supplement Eq. 3).

A sun's (or point light's) fluence is a mixture: its unscattered light phi_dir = exp(-tau) (a
delta lobe along d_l, computed in the light's domain) and the scattered rest. One HG lobe of the
mixture's mean anisotropy understates what the mixture scatters sideways and back (HG(.; g A)
is convex in A there), so the two are lit apart:
  phi_l f_hg(.; g A_l)  ->  phi_dir f_hg(.; g) + (phi_l - phi_dir) f_hg(.; g A_rest),
  A_rest = (phia_l - phi_dir) / (phi_l - phi_dir)
(the same fluence and first moment). phi_dir is taken at most phi_l: the walk's fluence holds
the unscattered light, and only interpolation across a shadow edge can put it below.

Each march segment of length ds uses sigma_t at one point inside it (its midpoint at one sample
per pixel, a hashed point at more) and integrates T_v exactly over the segment:
int T = T_v (1 - exp(-sigma_t ds)) / sigma_t.

Two shortcuts, neither changing which samples are taken:
- A combined source. The camera ray's direction at a point x is (x - c) / |x - c|, a function
  of x alone, so every term lit on the medium's grid (a sun's walk and diffuse lobes, a point
  light's diffuse lobe) is summed once per frame at the voxels into one RGB field
  (kernels/source.py), and a sample reads that field's trilinear value (one lookup) plus the
  point lights' walk lobes, instead of 3 + 4 lookups per light and channel. The field
  interpolates the product, not the fields, and its phase is evaluated at voxel centres, so the
  image changes slightly (docs/METHOD.md, "Rendering"); samples nearer the camera than ``near``,
  where the view direction turns fast across a voxel, are lit light by light.
- Empty-space skipping. A coarse grid holds each block's largest density within one voxel of
  it, and at an empty block how far the empty blocks around it reach (renderer.skip_blocks);
  a sample in an empty block jumps to the first sample past them. Samples sit at
  t0 + (i + jt) step, not at an accumulated t, so the jump leaves every other sample where it
  was: the image is bitwise the same without skipping. For the same reason a ray is marched
  only across the box of the non-empty blocks (renderer.dense_blocks_box), and a sample whose
  trilinear stencil reads only empty voxels (one byte per cell, renderer.occupied_cells) does
  not interpolate the density.

Two refinements change the samples, by the optical depth of each block: a segment in a block
whose densest voxel would make it thicker than MAX_SEGMENT_DEPTH mean free paths is split into
equal parts, each sampled; in a block so thin that n segments together are at most
COARSE_DEPTH thick, one sample spans n segments (at most method.max_step, within the block,
and not near a point light) (:func:`march_ray`). And where some voxel on the grid's faces is
at least EDGE_DEPTH thick, a sample in the grid's outer half cell, where the fields are clamped
to the outermost voxels' values, takes the suns' unscattered light there by Beer-Lambert from
the face, averaged over its segment in closed form (:func:`edge_single_scattering`).

The kernel takes its inputs packed in tuples (the renderer's ``render_inputs`` builds them):
  medium     (density, scale, albedo, albedo_rgb, g, origin, voxel, lo, hi, blocks, block_bits, occupied)
  lights     (is_point, direction, power, position, unscattered, lobe_a0)
  grid       (phi, phia, direct, phid, flux, lobe_cap)      the fields on the medium's grid
  spherical  (fields, offset, shape, params, frame, full)   the point lights' own fields
  view       (source, near, points)                         the combined source, if any
  camera     (origin, basis, tan_half, width, height)
  march      (step, spp, seed, jitter, skip, dense, coarse, edge, box)
(types in :func:`render_kernel`). NumPy twin: tests/twins.py (render_pixel).
"""
import math

import numba as nb
import numpy as np

from . import ON_ITS_OWN
from .sampling import cell_corners, corner_weights, interpolate
from .spherical import spherical_index

INV_FOUR_PI = 1.0 / (4.0 * math.pi)
MAX_DIFFUSE_ANISOTROPY = 0.5   # |J| / phi at a Marshak (vacuum) boundary, where diffusion's light
                               # leaves; 1/3 (P1 >= 0) left the lit faces ~6 % dark, 1 made speckles
T_MIN = 1e-4    # stop marching when the view transmittance falls below this (bias <= 1e-4 of L)
#: a march segment is split where its block's densest voxel makes it optically thicker than this
#: (a lit skin thinner than a segment is sampled, not stepped over: docs/METHOD.md, "Rendering")
MAX_SEGMENT_DEPTH = 2.0
MAX_SUBSTEPS = 256      # ... into at most this many parts
#: samples in the grid's outer half cell take the suns' unscattered light there by Beer-Lambert
#: (edge_single_scattering) where some voxel on the grid's faces is at least this many mean free
#: paths thick (renderer.thick_faces); below it the clamped fields' error is a few percent
EDGE_DEPTH = 0.25
#: one sample spans several segments (method.max_step) only where they are together at most this
#: many mean free paths thick, and at most NEAR_POINT_LIGHT of the distance to a point light long
COARSE_DEPTH = 0.5
NEAR_POINT_LIGHT = 0.125
G_MAX = 0.9999  # |g A| at most this in f_hg
TINY = 1e-30    # a floor for divisors that may be 0 (where the lobe's weight is 0)

# Positions in the bundles, for the helpers of the innermost loops (per sample, light and
# channel), which read single arrays of a bundle where they use them: unpacking a bundle into
# names there, Numba took and dropped a reference to its arrays (atomic counts) at every sample.
IS_POINT, DIRECTION, POWER, POSITION, UNSCATTERED, LOBE_A0 = 0, 1, 2, 3, 4, 5  # lights
PHI, PHIA, DIRECT, PHID, FLUX, LOBE_CAP = 0, 1, 2, 3, 4, 5      # grid
FIELDS, OFFSET, SHAPE, PARAMS, FRAME, FULL = 0, 1, 2, 3, 4, 5   # spherical


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


@nb.njit(**ON_ITS_OWN)
def point_lookup(fields, off, shape, q0, q1, q2, full):
    """(r^2 phi, r^2 phia, r^2 phi_dir) of a point light's spherical block (fields[:, off:], C-ordered
    ``shape``) at continuous cell index (q0, q1, q2): trilinear, clamped in r and theta,
    periodic in phi on a full sphere (NumPy twin: tests/twins.py, spherical_to_world)."""
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
def background_radiance(bg, d):
    """The background seen along direction d (RGB): a constant (bg of shape (1, 1, 3)) or a
    lat-long map in Mitsuba's envmap convention, bilinear between texel centres, wrapping in u."""
    H = bg.shape[0]
    W = bg.shape[1]
    if H == 1 and W == 1:
        return float(bg[0, 0, 0]), float(bg[0, 0, 1]), float(bg[0, 0, 2])
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
    texels = (i0, i1, j0 % W, (j0 + 1) % W, fx, fy)
    return _bilinear(bg, texels, 0), _bilinear(bg, texels, 1), _bilinear(bg, texels, 2)


@nb.njit(inline="always", fastmath=True, cache=True)
def _bilinear(bg, texels, c):
    """Channel c of the map bg, bilinear on texels = (row i0, i1, column j0, j1, weights fx of
    j1 and fy of i1)."""
    i0, i1, ja, jb, fx, fy = texels
    top = bg[i0, ja, c] * (1.0 - fx) + bg[i0, jb, c] * fx
    bot = bg[i1, ja, c] * (1.0 - fx) + bg[i1, jb, c] * fx
    return top * (1.0 - fy) + bot * fy


@nb.njit(inline="always", cache=True)
def pixel_sample(march, px, py, s):
    """Sample s of pixel (px, py): its sub-pixel offsets (jx, jy) and the offset jt of the
    march's sample points within their segments, each in [0, 1): hashed from the seed, or 1/2
    without jitter (pixel centres and segment midpoints)."""
    step, spp, seed, jitter, skip, dense, coarse, edge, box = march
    if jitter:
        return (hash_uniform(seed, px, py, s, 0), hash_uniform(seed, px, py, s, 1),
                hash_uniform(seed, px, py, s, 2))
    return 0.5, 0.5, 0.5


@nb.njit(inline="always", fastmath=True, cache=True)
def camera_ray(camera, u, v):
    """Unit direction (tuple) of the pinhole camera's ray through the image point (u, v), in
    pixels from the top-left corner: forward + sx right + sy up, with sx in [-tan_half aspect,
    tan_half aspect] and sy in [-tan_half, tan_half] (basis rows forward, right, up)."""
    origin, basis, tan_half, width, height = camera
    sx = (2.0 * u / width - 1.0) * tan_half * (width / height)
    sy = (1.0 - 2.0 * v / height) * tan_half
    dx = basis[0, 0] + sx * basis[1, 0] + sy * basis[2, 0]
    dy = basis[0, 1] + sx * basis[1, 1] + sy * basis[2, 1]
    dz = basis[0, 2] + sx * basis[1, 2] + sy * basis[2, 2]
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / norm, dy / norm, dz / norm


@nb.njit(**ON_ITS_OWN)
def light_geometry(lights, spherical, l, x, d):
    """Light l seen from the sample x on the camera ray d: (is_point, mu, 1/r^2, q0, q1, q2) with
    mu = d_l . (-d) (d_l the direction the light travels: a sun's, or (x - p_l) / r from a point
    light at distance r), 1/r^2 = 1 for a sun, and a point light's continuous cell index q of x
    in its spherical domain (0 for a sun)."""
    is_point, direction, position = lights[IS_POINT], lights[DIRECTION], lights[POSITION]
    if is_point[l]:
        fields, offset, shape, params, frame, full = spherical
        p = position[l]
        q0, q1, q2, r = spherical_index(p, frame[l], params[l], full[l], x[0], x[1], x[2])
        r = max(r, 1e-15)
        mu = -((x[0] - p[0]) * d[0] + (x[1] - p[1]) * d[1] + (x[2] - p[2]) * d[2]) / r
        return True, mu, 1.0 / (r * r), q0, q1, q2
    mu = -(direction[l, 0] * d[0] + direction[l, 1] * d[1] + direction[l, 2] * d[2])
    return False, mu, 1.0, 0.0, 0.0, 0.0


@nb.njit(inline="always", fastmath=True, cache=True)
def _clamp_g(g):
    return max(min(g, G_MAX), -G_MAX)


@nb.njit(inline="always", fastmath=True, cache=True)
def walk_lobe_weights(p, pa, pdir, g):
    """The walk's light as two lobes about the light's direction, seen through the phase:
    (phi_dir, g, phi - phi_dir, g A_rest), A_rest = (phia - phi_dir) / (phi - phi_dir), with
    phi_dir taken at most phi (docs/METHOD.md Eq. 23; f_hg(.; g A) of a lobe: supplement Eq. 3);
    a weight is 0 where its lobe is empty. p, pa, pdir: phi, phia, phi_dir at the sample (pa,
    pdir are not read where p <= 0); the g are clamped to G_MAX."""
    w_dir = 0.0
    g_rest = 0.0
    if p > 0.0:
        pdir = min(pdir, p)
        if pdir > 0.0:          # the unscattered light: a delta lobe
            w_dir = pdir
            p -= pdir
            pa -= pdir
    if p > 0.0:
        g_rest = _clamp_g(g * (pa / p))
    return w_dir, _clamp_g(g), max(p, 0.0), g_rest


@nb.njit(inline="always", fastmath=True, cache=True)
def walk_lobes(p, pa, pdir, mu, g):
    """The walk's light scattered toward the camera, per unit power: phi_dir f_hg(mu; g) +
    (phi - phi_dir) f_hg(mu; g A_rest) (:func:`walk_lobe_weights`: the same lobes), mu =
    d_l . (-d). Without branches, so that loops over voxels overlap in the pipeline: an empty
    lobe has weight 0 (and its g, clamped, does not matter)."""
    p = max(p, 0.0)
    w_dir = min(max(pdir, 0.0), p)
    w_rest = p - w_dir
    g_rest = _clamp_g(g * ((pa - w_dir) / max(w_rest, TINY)))
    return w_dir * f_hg(mu, _clamp_g(g)) + w_rest * f_hg(mu, g_rest)


@nb.njit(inline="always", fastmath=True, cache=True)
def rest_lobe(p, pa, mu, g):
    """:func:`walk_lobes` of a light without an unscattered part (phi_dir = 0 everywhere: an
    environment's lights): the one lobe (phi, g A), A = phia / phi, by the same arithmetic, so
    the same value (a zero may come out as -0.0 where walk_lobes gives +0.0)."""
    p = max(p, 0.0)
    return p * f_hg(mu, _clamp_g(g * (pa / max(p, TINY))))


@nb.njit(inline="always", fastmath=True, cache=True)
def diffuse_lobe_axis(phid, flux, corners, g, cap):
    """The diffusion stage's light as one lobe about its own flux J, seen through the phase:
    (phi_d, J/|J| (3 numbers), g A_d), A_d = min(|J| / phi_d, cap) (supplement Eq. 3;
    docs/METHOD.md Eq. 24); isotropic (g A_d = 0) where J = 0, weight 0 where phi_d <= 0.
    phid (nx, ny, nz) and flux (3, nx, ny, nz) of one light and channel, on the medium's grid at
    the stencil ``corners``. ``cap``: MAX_DIFFUSE_ANISOTROPY for the diffusion stage's light; 1
    for the six-ordinate walk's scattered light, which the pipeline stores in the same fields
    (docs/METHOD.md, "Six ordinates")."""
    pd = interpolate(phid, corners)
    if pd <= 0.0:
        return 0.0, 0.0, 0.0, 1.0, 0.0
    return flux_lobe_axis(pd, interpolate(flux[0], corners), interpolate(flux[1], corners),
                          interpolate(flux[2], corners), g, cap)


@nb.njit(inline="always", fastmath=True, cache=True)
def flux_lobe_axis(pd, jx, jy, jz, g, cap):
    """Light of fluence pd > 0 and flux J = (jx, jy, jz) as one lobe about J, seen through the
    phase: (pd, J/|J| (3 numbers), g min(|J| / pd, cap)); isotropic where J = 0
    (:func:`diffuse_lobe_axis` at a point)."""
    jn = math.sqrt(jx * jx + jy * jy + jz * jz)
    if jn <= 0.0:
        return pd, 0.0, 0.0, 1.0, 0.0
    return pd, jx / jn, jy / jn, jz / jn, _clamp_g(g * min(jn / pd, cap))


@nb.njit(inline="always", fastmath=True, cache=True)
def lobe_toward(pd, jx, jy, jz, d0, d1, d2, g, cap):
    """The diffusion stage's light of fluence pd and flux J = (jx, jy, jz) scattered along the
    camera ray d, per unit power: phi_d f_hg(-d . J/|J|; g A_d), A_d = min(|J| / phi_d, cap)
    (:func:`diffuse_lobe_axis`: the same lobe); phi_d / 4 pi where J = 0, 0 where phi_d <= 0.
    Without branches (see :func:`walk_lobes`)."""
    jn = math.sqrt(jx * jx + jy * jy + jz * jz)
    mu = -(jx * d0 + jy * d1 + jz * d2) / max(jn, TINY)
    g_d = _clamp_g(g * min(jn / max(pd, TINY), cap))
    return max(pd, 0.0) * f_hg(mu, g_d)


@nb.njit(**ON_ITS_OWN)
def diffuse_lobe(phid, flux, corners, d, g, cap):
    """:func:`lobe_toward` of phid (nx, ny, nz) and flux (3, nx, ny, nz) of one light and
    channel on the medium's grid, trilinear on the stencil ``corners``."""
    return lobe_toward(interpolate(phid, corners), interpolate(flux[0], corners), interpolate(flux[1], corners),
                       interpolate(flux[2], corners), d[0], d[1], d[2], g, cap)


@nb.njit(**ON_ITS_OWN)
def grid_fields(grid, l, c, corners):
    """(phi, phia, phi_dir) of light l in channel c on the medium's grid at the stencil
    ``corners``; phia and phi_dir are not looked up (0) where phi <= 0."""
    p = interpolate(grid[PHI][l, c], corners)
    if p <= 0.0:
        return p, 0.0, 0.0
    return p, interpolate(grid[PHIA][l, c], corners), interpolate(grid[DIRECT][l, c], corners)


@nb.njit(inline="always", fastmath=True, cache=True)
def light_channel(grid, spherical, l, c, corners, geometry, d, g, walk, diffuse):
    """phi_l f_hg of light l in channel c at the sample, per unit power: the walk's light
    (:func:`walk_lobes`, its fields divided by r^2 for a point light) if ``walk``, plus the
    diffusion stage's (:func:`diffuse_lobe`) if ``diffuse``; ``geometry`` from
    :func:`light_geometry`, ``corners`` the sample's stencil on the medium's grid, d the camera
    ray, g the phase's anisotropy."""
    point, mu, inv_r2, q0, q1, q2 = geometry
    val = 0.0
    if walk:
        if point:
            p, pa, pdir = point_lookup(spherical[FIELDS], spherical[OFFSET][l, c], spherical[SHAPE][l],
                                       q0, q1, q2, spherical[FULL][l])
        else:
            p, pa, pdir = grid_fields(grid, l, c, corners)
        val = walk_lobes(p, pa, pdir, mu, g) * inv_r2
    if diffuse and grid[PHID].shape[0] > 0:
        val += diffuse_lobe(grid[PHID][l, c], grid[FLUX][l, c], corners, d, g, grid[LOBE_CAP][l])
    return val


@nb.njit(**ON_ITS_OWN)
def light_in_scattering(lights, grid, spherical, l, corners, x, d, g, walk=True, diffuse=True):
    """Light l's term of L_s / sigma_s at the sample x (RGB): E_l phi_l f_hg(d_l . -d; g A_l),
    split into the lobes of docs/METHOD.md Eq. 23-24 (see :func:`light_channel`; ``walk`` and
    ``diffuse`` select the lobes); a grey medium's one channel is scaled by the light's RGB
    power."""
    power = lights[POWER]
    geometry = light_geometry(lights, spherical, l, x, d)
    n_ch = grid[PHI].shape[1]
    v0 = v1 = v2 = 0.0
    for c in range(n_ch):
        v = light_channel(grid, spherical, l, c, corners, geometry, d, g, walk, diffuse)
        if c == 0:
            v0 = v
        elif c == 1:
            v1 = v
        else:
            v2 = v
    if n_ch == 1:
        v1 = v2 = v0
    return v0 * power[l, 0], v1 * power[l, 1], v2 * power[l, 2]


@nb.njit(inline="always", fastmath=True, cache=True)
def interpolate_rgb(grid, corners):
    """Trilinear RGB value of ``grid`` (nx, ny, nz, 3) on the stencil ``corners`` (as
    sampling.interpolate, the three channels of a corner side by side in memory)."""
    i0, i1, j0, j1, k0, k1, fx, fy, fz = corners
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w10 = fx * (1.0 - fy)
    w11 = fx * fy
    out0 = out1 = out2 = 0.0
    for a in range(8):
        i = i1 if a & 4 else i0
        j = j1 if a & 2 else j0
        k = k1 if a & 1 else k0
        w = (w11 if a & 2 else w10) if a & 4 else (w01 if a & 2 else w00)
        w *= fz if a & 1 else 1.0 - fz
        out0 += w * grid[i, j, k, 0]
        out1 += w * grid[i, j, k, 1]
        out2 += w * grid[i, j, k, 2]
    return out0, out1, out2


@nb.njit(inline="always", fastmath=True, cache=True)
def march_segment(L, T, sigma_t, ds, albedo, ls):
    """One march segment of length ds in one channel (docs/METHOD.md Eq. 25): adds
    int_seg T_v sigma_s L_s dt = T (1 - exp(-sigma_t ds)) albedo ls to L (ls = L_s / sigma_s)
    and attenuates T by exp(-sigma_t ds); returns (L, T)."""
    if sigma_t > 0.0:
        Tseg = math.exp(-sigma_t * ds)
        return L + T * (1.0 - Tseg) * albedo * ls, T * Tseg
    return L, T


@nb.njit(inline="always", fastmath=True, cache=True)
def medium_at(medium, x):
    """The medium at the world point x: (corners, rho, g, sigma_t, albedo) with ``corners`` the
    trilinear stencil of x on the medium's grid, rho the density, g the phase's anisotropy, and
    sigma_t = scale rho and the albedo per RGB channel (3-tuples); all 0 where rho <= 0."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    corners = cell_corners((x[0] - origin[0]) / voxel[0], (x[1] - origin[1]) / voxel[1],
                           (x[2] - origin[2]) / voxel[2], density.shape)
    if occupied.shape[0] > 0 and not occupied[corners[0], corners[2], corners[4]]:
        return corners, 0.0, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)     # the stencil's voxels are empty
    rho = interpolate(density, corners)
    if rho <= 0.0:
        return corners, 0.0, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    # albedo and g: constants stored as (1, 1, 1), or grids of the density's shape
    alb = albedo[0, 0, 0] if albedo.size == 1 else interpolate(albedo, corners)
    g = g_grid[0, 0, 0] if g_grid.size == 1 else interpolate(g_grid, corners)
    return (corners, rho, g, (scale[0] * rho, scale[1] * rho, scale[2] * rho),
            (alb * albedo_rgb[0], alb * albedo_rgb[1], alb * albedo_rgb[2]))


@nb.njit(inline="always", fastmath=True, cache=True)
def _block_index(x, o, h, n, bits):
    """Along one axis: the block holding the world coordinate x (grid origin o, voxel h, n
    voxels, blocks of 2^bits voxels; the voxel index clamped to the grid as the trilinear
    stencil's is), by a shift: it runs once per block a ray enters."""
    return int(min(max((x - o) / h, 0.0), n - 1.0)) >> bits


@nb.njit(inline="always", fastmath=True, cache=True)
def _block_exit(x, o, h, size, n_blocks, b, r, d):
    """Along one axis: the distance along the ray (direction component d) from the world
    coordinate x, in block b, to the face by which it leaves blocks b - r .. b + r (1e300 where
    it would leave by the grid's outer blocks, which reach to the box's face)."""
    if d > 0.0 and b + r < n_blocks - 1:
        return (o + size * (b + r + 1) * h - x) / d
    if d < 0.0 and b - r > 0:
        return (o + size * (b - r) * h - x) / d
    return 1e300


@nb.njit(inline="always", fastmath=True, cache=True)
def block_at(medium, x, d):
    """x's block of the coarse grid (renderer.skip_blocks): (its value, the distance along the
    ray d to where the ray leaves the blocks the value vouches for). A value > 0 is the largest
    density within one voxel of the block, and those blocks are the block itself; a value
    -n < 0 says the block is empty and so is every block within n - 1 of it (Chebyshev
    distance, in blocks), and those are that cube of blocks. (0, 1e300) without the grid (shape
    (0, 0, 0)): no block is empty or dense."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, bits, occupied = medium
    if blocks.shape[0] == 0:
        return 0.0, 1e300
    s = density.shape
    bx = _block_index(x[0], origin[0], voxel[0], s[0], bits)
    by = _block_index(x[1], origin[1], voxel[1], s[1], bits)
    bz = _block_index(x[2], origin[2], voxel[2], s[2], bits)
    block = 1 << bits
    value = float(blocks[bx, by, bz])
    r = int(-value) - 1 if value < 0.0 else 0
    ex = _block_exit(x[0], origin[0], voxel[0], block, blocks.shape[0], bx, r, d[0])
    ey = _block_exit(x[1], origin[1], voxel[1], block, blocks.shape[1], by, r, d[1])
    ez = _block_exit(x[2], origin[2], voxel[2], block, blocks.shape[2], bz, r, d[2])
    return value, max(min(ex, ey, ez), 0.0)


@nb.njit(inline="always", fastmath=True, cache=True)
def substeps(medium, rho_max, ds):
    """How many parts a march segment of length ds is split into, in a block whose densest
    voxel (within one voxel of it) has density ``rho_max``: enough that none is optically
    thicker than MAX_SEGMENT_DEPTH at that density, at most MAX_SUBSTEPS; 1 without the grid."""
    scale = medium[1]
    tau = rho_max * max(scale[0], scale[1], scale[2]) * ds
    if tau <= MAX_SEGMENT_DEPTH:
        return 1
    return min(int(math.ceil(tau / MAX_SEGMENT_DEPTH)), MAX_SUBSTEPS)


@nb.njit(inline="always", fastmath=True, cache=True)
def coarse_factor(tau_step, coarse, room):
    """How many segments of the march one sample may span in a block where a segment is at
    most ``tau_step`` mean free paths thick (its densest voxel's): at most ``coarse``, at most
    COARSE_DEPTH thick together, and within the block (which the ray leaves ``room`` segments
    on); at least 1."""
    m = coarse
    if tau_step * coarse > COARSE_DEPTH:
        m = int(COARSE_DEPTH / tau_step)
    if room < m:                    # room may be 1e300 (the grid's outer blocks): no int() of it
        m = int(room)
    return max(m, 1)


@nb.njit(inline="always", fastmath=True, cache=True)
def same_block(medium, a, b):
    """Whether the world points a and b lie in the same block of the coarse grid."""
    density, origin, voxel, bits = medium[0], medium[5], medium[6], medium[10]
    s = density.shape
    for k in range(3):
        if (_block_index(a[k], origin[k], voxel[k], s[k], bits)
                != _block_index(b[k], origin[k], voxel[k], s[k], bits)):
            return False
    return True


@nb.njit(inline="always", fastmath=True, cache=True)
def point_light_room(lights, x, step):
    """How many segments of length ``step`` fit in NEAR_POINT_LIGHT times the distance from x
    to the nearest point light, where the light's 1 / r^2 makes the in-scattered light steep
    (10^9 without point lights)."""
    is_point, position = lights[IS_POINT], lights[POSITION]
    r2 = 1e300
    for l in range(is_point.shape[0]):
        if is_point[l]:
            dx, dy, dz = x[0] - position[l, 0], x[1] - position[l, 1], x[2] - position[l, 2]
            r2 = min(r2, dx * dx + dy * dy + dz * dz)
    room = NEAR_POINT_LIGHT * math.sqrt(r2) / step
    return int(min(room, 1e9))


@nb.njit(**ON_ITS_OWN)
def light_sample(lights, grid, spherical, view, x, d, corners, g, ts):
    """L_s / sigma_s at the sample x (RGB) at distance ts along the camera ray d: with a combined
    source (``view`` = (source, near, points), source of shape (nx, ny, nz, 3)) its trilinear
    value plus the walk lobes of the point lights (their indices ``points``, in order) where
    ts >= near; otherwise (or without one: shape (0, 0, 0, 3)) light by light
    (:func:`light_in_scattering`)."""
    source, near, points = view
    is_point = lights[IS_POINT]
    ls0 = ls1 = ls2 = 0.0
    if source.shape[0] > 0 and ts >= near:
        ls0, ls1, ls2 = interpolate_rgb(source, corners)
        for p in range(points.shape[0]):
            e0, e1, e2 = light_in_scattering(lights, grid, spherical, points[p], corners, x, d, g, True, False)
            ls0 += e0
            ls1 += e1
            ls2 += e2
    else:
        for l in range(is_point.shape[0]):
            e0, e1, e2 = light_in_scattering(lights, grid, spherical, l, corners, x, d, g, True, True)
            ls0 += e0
            ls1 += e1
            ls2 += e2
    return ls0, ls1, ls2


@nb.njit(inline="always", fastmath=True, cache=True)
def beyond_centres(medium, x):
    """Whether the world point x lies in the grid's outer half cell: beyond the voxel centres
    along some axis, where the trilinear stencil is clamped."""
    density, origin, voxel = medium[0], medium[5], medium[6]
    s = density.shape
    for a in range(3):
        u = (x[a] - origin[a]) / voxel[a]
        if u < 0.0 or u > s[a] - 1.0:
            return True
    return False


@nb.njit(inline="always", fastmath=True, cache=True)
def _log_mean_exp(beta):
    """ln of (1 - exp(-beta)) / beta, the mean of exp(-beta s) over s in [0, 1], for any real
    beta without overflow (0 at beta = 0)."""
    if abs(beta) < 1e-9:
        return -0.5 * beta
    if beta > 0.0:
        return math.log(-math.expm1(-beta)) - math.log(beta)
    return -beta + math.log(-math.expm1(beta)) - math.log(-beta)


@nb.njit(**ON_ITS_OWN)
def edge_single_scattering(medium, lights, grid, x, d, g, sigma_t, jt, ds):
    """What the suns' unscattered light scattered once adds to L_s / sigma_s (RGB) at a sample x
    in the grid's outer half cell (beyond the last voxel centres, where every field is clamped
    to the outermost voxels' values), on a march segment of length ds sampled at offset jt
    (docs/METHOD.md Eq. 25d); (0, 0, 0) elsewhere.

    Along an axis a on which x lies beyond the centres, by ``depth`` (world units), the density
    is the outermost voxels' (the stencil is clamped) and nothing lies outside the grid, so
    Beer-Lambert gives a sun's unscattered fluence: light entering by that face (w = d_l . n < 0,
    n the outward normal) has crossed sigma_t over (h_a / 2 - depth) / |w|, so phi_dir =
    exp(-sigma_t (h_a / 2 - depth) / |w|); light leaving by it has the clamped value times
    exp(-sigma_t depth / w). Along the camera ray that is exp(-sigma_t kappa s) of its value at
    the segment's start, kappa = d[a] / d_l[a], and its mean over the segment weighted by the
    camera's transmittance is taken in closed form,
      phi_dir(start) sigma_t ds m(sigma_t (1 + kappa) ds) / (1 - exp(-sigma_t ds)),
    m(b) = (1 - exp(-b)) / b, so that a lit skin far thinner than the segment is integrated,
    not sampled. Beyond the centres along several axes (an edge or corner of the grid) the
    light came in by one face, and the largest of the axes' means is taken. That mean replaces the clamped phi_dir the fields light the sample with
    (light_sample): the term added is E_l (mean - clamped) f_hg(d_l . -d; g) per light with an
    unscattered part, per channel (a grey field's one channel scaled by the light's RGB power)."""
    density, origin, voxel = medium[0], medium[5], medium[6]
    s = density.shape
    u0, u1, u2 = (x[0] - origin[0]) / voxel[0], (x[1] - origin[1]) / voxel[1], (x[2] - origin[2]) / voxel[2]
    v0 = v1 = v2 = 0.0          # and so they stay where no axis has x beyond the centres
    corners = cell_corners(u0, u1, u2, s)
    is_point, direction, power, unscattered = lights[IS_POINT], lights[DIRECTION], lights[POWER], lights[UNSCATTERED]
    direct = grid[DIRECT]
    n_ch = direct.shape[1]
    for l in range(is_point.shape[0]):
        if is_point[l] or not unscattered[l]:
            continue
        mu = -(direction[l, 0] * d[0] + direction[l, 1] * d[1] + direction[l, 2] * d[2])
        f = f_hg(mu, _clamp_g(g))
        for c in range(n_ch):
            sig = sigma_t[c] if n_ch == 3 else sigma_t[0]
            if sig <= 0.0:                      # a channel the medium does not scatter
                continue
            clamped = interpolate(direct[l, c], corners)
            # the segment's mean along each axis x lies beyond the centres on; the largest
            ln_mean = -1e300
            for a in range(3):
                u = u0 if a == 0 else (u1 if a == 1 else u2)
                outward = -1.0 if u < 0.0 else 1.0
                depth = (-u if u < 0.0 else u - (s[a] - 1.0)) * voxel[a]
                w = direction[l, a] * outward   # the light's travel along the outward normal
                if depth <= 0.0 or w == 0.0:
                    continue
                if w < 0.0:
                    ln_x = -sig * (0.5 * voxel[a] - depth) / -w
                else:
                    ln_x = math.log(max(clamped, 1e-300)) - sig * depth / w
                kappa = d[a] / direction[l, a]
                ln_start = min(ln_x + sig * kappa * jt * ds, 0.0)   # exp(-tau) with tau >= 0
                ln_mean = max(ln_mean, ln_start + math.log(sig * ds) + _log_mean_exp(sig * (1.0 + kappa) * ds)
                              - math.log(-math.expm1(-sig * ds)))
            if ln_mean == -1e300:
                continue
            v = (math.exp(min(ln_mean, 0.0)) - clamped) * f
            if n_ch == 1:
                v0 += v * power[l, 0]
                v1 += v * power[l, 1]
                v2 += v * power[l, 2]
            elif c == 0:
                v0 += v * power[l, 0]
            elif c == 1:
                v1 += v * power[l, 1]
            else:
                v2 += v * power[l, 2]
    return v0, v1, v2


@nb.njit(inline="always", fastmath=True, cache=True)
def march_segments(L, T, sigma_t, ds, albedo, ls):
    """:func:`march_segment` in the three channels (L, T, sigma_t, albedo, ls: 3-tuples); a grey
    medium's segment takes one exponential."""
    L0, L1, L2 = L
    T0, T1, T2 = T
    if sigma_t[0] == sigma_t[1] and sigma_t[1] == sigma_t[2]:
        Tseg = math.exp(-sigma_t[0] * ds)
        return ((L0 + T0 * (1.0 - Tseg) * albedo[0] * ls[0], L1 + T1 * (1.0 - Tseg) * albedo[1] * ls[1],
                 L2 + T2 * (1.0 - Tseg) * albedo[2] * ls[2]), (T0 * Tseg, T1 * Tseg, T2 * Tseg))
    L0, T0 = march_segment(L0, T0, sigma_t[0], ds, albedo[0], ls[0])
    L1, T1 = march_segment(L1, T1, sigma_t[1], ds, albedo[1], ls[1])
    L2, T2 = march_segment(L2, T2, sigma_t[2], ds, albedo[2], ls[2])
    return (L0, L1, L2), (T0, T1, T2)


@nb.njit(**ON_ITS_OWN)
def march_ray(medium, lights, grid, spherical, view, o, d, segments):
    """The ray o + t d through the medium in ``segments`` = (t0, t1, step, jt, skip, dense,
    coarse, edge, t_in, t_out): from t0 to t1 (its span in the medium's box) in segments [t0 + i step, t0 + (i + 1)
    step] (the last one cut at t1), the optics and fields taken at offset jt within each.
    Returns (L0, L1, L2, T0, T1, T2): the radiance scattered toward o, int T_v sigma_s L_s dt
    (docs/METHOD.md Eq. 24), and the view transmittance T_v at the exit, 0 once it fell below
    T_MIN.

    L_s / sigma_s: :func:`light_sample`. The coarse grid (:func:`block_at`) is read once per
    block the ray enters, not per sample. A segment in a block so dense that it would be
    optically thicker than MAX_SEGMENT_DEPTH is split into :func:`substeps` equal parts, each
    sampled at offset jt, so that a lit skin thinner than a segment is not stepped over
    (``dense`` says whether any block is that dense). In a block so thin that n segments are
    together at most COARSE_DEPTH thick, one segment spans n steps (``coarse`` at most,
    :func:`coarse_factor`, :func:`point_light_room`; decided at the segment's start, which must
    lie in that block), sampled at offset jt within it. With ``skip``, a sample in an empty
    block jumps to the first sample past the empty blocks around it that the grid vouches for:
    their density is 0, so they add nothing, and the samples taken are the same; for the same
    reason the march starts at the last sample a step or more before t_in and stops at t_out
    (the ray's span in the march's ``box``, outside which every block is empty). With ``edge``
    (some voxel on the grid's faces is at least EDGE_DEPTH thick), a sample in the grid's outer
    half cell adds what the clamped fields miss of the suns' single scattering there
    (:func:`edge_single_scattering`)."""
    t0, t1, step, jt, skip, dense, coarse, edge, t_in, t_out = segments
    scale = medium[1]
    sigma_max = max(scale[0], scale[1], scale[2])
    L = (0.0, 0.0, 0.0)
    T = (1.0, 1.0, 1.0)
    i = 0
    if skip:                        # the samples before t_in and from t_out on lie in empty blocks
        if t_in >= t_out:
            return 0.0, 0.0, 0.0, 1.0, 1.0, 1.0
        i = max(int((t_in - t0) / step) - 1, 0)
    rho_max = 0.0                   # the densest voxel near the block of the last lookup
    t_leave = -1.0                  # where the ray leaves that block, if it holds density
    while True:
        t = t0 + i * step           # not accumulated: skipping samples leaves the others as they are
        if t >= t1 or (skip and t >= t_out):
            break
        ds = min(step, t1 - t)
        ts = t + jt * ds
        i += 1
        x = (o[0] + ts * d[0], o[1] + ts * d[1], o[2] + ts * d[2])
        if ts >= t_leave:           # a block not looked up yet
            rho_max, exit = block_at(medium, x, d)
            if rho_max < 0.0:       # an empty block, and maybe more around it
                if skip:
                    if ts + exit >= t1:
                        break
                    # the first sample at or past the exit (the blocks hold one voxel of margin)
                    i = max(i, int(math.ceil((ts + exit - t0) / step - jt)))
                continue
            t_leave = ts + exit
        if coarse > 1 and rho_max > 0.0 and t1 - t > step:
            # decided from the segment's start, not its sample: for every offset jt the same
            # segments, each sampled uniformly (the start in the sample's block, so that no part
            # of the longer segment is sampled only for some jt)
            m = coarse_factor(rho_max * sigma_max * step, coarse, (t_leave - t) / step)
            xt = (o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2])
            if m > 1:
                m = min(m, point_light_room(lights, xt, step))
            if m > 1 and same_block(medium, xt, x):
                i += m - 1
                ds = min(m * step, t1 - t)
                ts = t + jt * ds
                x = (o[0] + ts * d[0], o[1] + ts * d[1], o[2] + ts * d[2])
        k = substeps(medium, rho_max, ds) if dense else 1
        for j in range(k):
            if k > 1:
                ts = t + (j + jt) * ds / k
                x = (o[0] + ts * d[0], o[1] + ts * d[1], o[2] + ts * d[2])
            corners, rho, g, sigma_t, albedo = medium_at(medium, x)
            if rho <= 0.0:
                continue
            ls = light_sample(lights, grid, spherical, view, x, d, corners, g, ts)
            if edge and beyond_centres(medium, x):
                e0, e1, e2 = edge_single_scattering(medium, lights, grid, x, d, g, sigma_t, jt, ds / k)
                ls = (ls[0] + e0, ls[1] + e1, ls[2] + e2)
            L, T = march_segments(L, T, sigma_t, ds / k, albedo, ls)
            if max(T[0], T[1], T[2]) < T_MIN:
                return L[0], L[1], L[2], 0.0, 0.0, 0.0
    return L[0], L[1], L[2], T[0], T[1], T[2]


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def render_kernel(medium, lights, grid, spherical, view, camera, march, background, out, lanes):
    """Render into ``out`` float32 (height, width, 3), linear radiance: per pixel the mean over
    its samples of the march's L + T_v L_background (docs/METHOD.md Eq. 24). Rows go to
    ``lanes`` (numba.get_num_threads()) lanes round-robin, lane l rows l, l + lanes, ...: rows
    through the medium cost far more than the sky's, and neighbouring rows about the same
    (kernels/__init__.py, "Lanes").

    medium: density float32 (nx, ny, nz); scale float64 (3,), sigma_t per channel = scale *
        density; albedo, g: float32 grids (1, 1, 1) or density-shaped; albedo_rgb float64 (3,),
        the albedo of channel c is albedo * albedo_rgb[c]; origin, voxel float64 (3,): the
        centre of voxel (0, 0, 0) and the voxel size; lo, hi float64 (3,): the medium's box;
        blocks float32 (ceil(nx / 2^block_bits), ...): the largest density within one voxel of
        each block of (2^block_bits)^3 voxels, or at an empty block -n, n its Chebyshev distance
        in blocks to the nearest non-empty one (renderer.skip_blocks; shape (0, 0, 0): no
        grid); block_bits int (renderer.BLOCK_BITS); occupied uint8 (nx, ny, nz): whether the
        cell from voxel (i, j, k) to (i + 1, j + 1, k + 1) has a voxel of density > 0
        (renderer.occupied_cells; shape (0, 0, 0): not known, the density is interpolated).
    lights: is_point bool (n_lights,); direction float64 (n_lights, 3), the direction a sun's
        light travels; power float64 (n_lights, 3), RGB irradiance or intensity; position
        float64 (n_lights, 3), a point light's; unscattered bool (n_lights,), whether the
        light's unscattered part is in ``direct`` as a delta lobe (an environment's lights' is
        not); lobe_a0 float64 (n_lights,), read by the gathered last bounce alone
        (kernels/gather.py): an environment region's a0 where its unscattered lobe is in
        ``direct`` and gathered with its region's pattern, else 0.
    grid: phi, phia, direct float32 (n_lights, n_channels (1 or 3), nx, ny, nz) per unit power
        (direct: the unscattered part of phi; all 0 for point lights; an environment region's
        unscattered lobe, a part of phid, with phi and phia 0); phid, flux: the diffuse
        lobe's fluence (n_lights, n_channels, ...) and world flux vector (n_lights, n_channels,
        3, ...), or arrays with n_lights = 0 when there is no diffusion stage; lobe_cap float64
        (n_lights,), the largest anisotropy of each light's diffuse lobe (diffuse_lobe).
    spherical: the point lights' fields (r^2 phi, r^2 phia, r^2 phi_dir) in their spherical
        domains: fields float32 (3, total), offset int64 (n_lights, n_channels), shape int64
        (n_lights, 3), params float64 (n_lights, 6), frame float64 (n_lights, 3, 3), full bool
        (n_lights,) (the renderer's PointFields).
    view: source float32 (nx, ny, nz, 3), every term of L_s / sigma_s on the medium's grid
        toward this camera (kernels/source.py), or (0, 0, 0, 3) to light sample by sample;
        near float, the distance from the camera within which samples are lit light by light;
        points int64 (n_point_lights,), the point lights' indices in order (their walk lobes
        are lit per sample also with the combined source).
    camera: origin float64 (3,); basis float64 (3, 3), rows forward, right, up; tan_half, the
        tangent of half the vertical field of view; width, height in pixels.
    march: step in world units; spp samples per pixel; seed; jitter: hashed sub-pixel and
        along-ray offsets (False: pixel centres and segment midpoints, renderer.render's choice
        at one sample per pixel); skip: jump over empty blocks; dense: whether a segment of
        ``step`` is optically thicker than MAX_SEGMENT_DEPTH in some block (march_ray splits
        those); coarse: the most steps one sample spans in thin blocks (1: every segment one
        step; method.max_step); edge: whether some voxel on the grid's faces is at least
        EDGE_DEPTH mean free paths thick, so that samples in the grid's outer half cell take the
        suns' single scattering there exactly (edge_single_scattering); box float64 (2, 3): the
        world box (lo, hi) of the coarse grid's non-empty blocks, outside which the march takes
        no sample when it skips (renderer.dense_blocks_box; lo > hi where every block is empty).
    background: float32 (1, 1, 3) (a constant) or (H, 2H, 3) (a lat-long environment map, see
        background_radiance).
    """
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    is_point, direction, power, position, unscattered, lobe_a0 = lights
    phi, phia, direct, phid, flux, lobe_cap = grid
    fields, offset, shape, params, frame, full = spherical
    source, near, points = view
    o, basis, tan_half, width, height = camera
    step, spp, seed, jitter, skip, dense, coarse, edge, box = march
    for lane in nb.prange(lanes):
        # The bundles are rebuilt here from their arrays, so that the helpers read the arrays
        # themselves: with the bundles as passed in, the march took and dropped references to
        # their arrays (atomic counts) at every sample, about 1.2x slower.
        medium_ = (density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits,
                   occupied)
        lights_ = (is_point, direction, power, position, unscattered, lobe_a0)
        grid_ = (phi, phia, direct, phid, flux, lobe_cap)
        spherical_ = (fields, offset, shape, params, frame, full)
        view_ = (source, near, points)
        camera_ = (o, basis, tan_half, width, height)
        march_ = (step, spp, seed, jitter, skip, dense, coarse, edge, box)
        for py in range(lane, height, lanes):
            for px in range(width):
                acc0 = acc1 = acc2 = 0.0
                for s in range(spp):
                    jx, jy, jt = pixel_sample(march_, px, py, s)
                    d = camera_ray(camera_, px + jx, py + jy)
                    t0, t1 = ray_box(o, d, lo, hi)
                    t_in, t_out = ray_box(o, d, box[0], box[1]) if skip else (t0, t1)
                    L0, L1, L2, T0, T1, T2 = march_ray(medium_, lights_, grid_, spherical_, view_, o, d,
                                                       (t0, t1, step, jt, skip, dense, coarse, edge, t_in, t_out))
                    b0, b1, b2 = background_radiance(background, d)
                    acc0 += L0 + T0 * b0
                    acc1 += L1 + T1 * b1
                    acc2 += L2 + T2 * b2
                out[py, px, 0] = acc0 / spp
                out[py, px, 1] = acc1 / spp
                out[py, px, 2] = acc2 / spp
