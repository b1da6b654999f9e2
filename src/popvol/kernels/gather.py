"""Numba kernel: the last scattering gathered at render time (docs/METHOD.md, "Gathered last
bounce"; method.gather = N directions).

The combined source (kernels/source.py) lights a voxel toward the camera from the fields' own
angular model, one lobe per light and cell. Here the light arriving at the voxel is gathered
instead, from N fixed directions w_i (weights w_i summing to 4 pi), and scattered toward the
camera with the phase function:

  L_s(x, w_o) / sigma_s = sum_i wt_i f_hg(w_i . w_o; g) L_in(x, w_i) / sum_i wt_i f_hg(w_i . w_o; g)

(the denominator makes the quadrature of the phase function exact), where L_in(x, w_i), the
radiance reaching x travelling along w_i, is transported from the fields' in-scattered light
L_s(x', w_i) (the lobes of kernels/render.py, single scattering included) by one sweep per
direction over a grid (the medium's voxels, or blocks of them with the fields averaged over
each block: renderer.gather) by short characteristics:
slices are taken across the axis a along which |w_i| is largest, in the direction w_i travels,
and each voxel takes the radiance from the point one slice upstream (bilinear in that slice;
outside the grid, and in the first slice, the radiance entering it along w_i: an environment
map's light from -w_i, renderer.gathered_environment, or 0) over the path
l = voxel[a] / |w_i[a]| (half of it in the first slice, from the grid's face), with sigma_t linear
along it and the emission per unit length q = sigma_s L_s(., w_i) / sigma_s (the lobes' light
toward w_i times sigma_s, albedo included), per colour channel:

  L_in(v) = L_in(up) T + b_up J(up) + b_v J(v),  J = q / sigma_t,  T = exp(-tau),
  tau = (sigma_t(up) + sigma_t(v)) / 2 l,  b_up = (1 - T (1 + tau)) / tau,  b_v = 1 - T - b_up:

the source function J taken linear in optical depth along the segment and integrated exactly
(the linear short characteristics of stellar atmospheres; Olson and Kunasz 1987). Where a
segment is many mean free paths long, the light reaching the voxel comes from its own first mean
free path (b_v -> 1, b_up -> 0), not half from the point upstream as the mean of the two ends'
emission, (q(up) + q(v)) / 2 (1 - T) / sigma, would have it; where J is the same at both ends
(a medium in equilibrium with a uniform sky) it is J (1 - T) whatever sigma_t does.

The sun's unscattered lobe, f_hg(d_s . w; g) in every cell, is transported without that factor
and its light scattered toward the camera as

  f_hg(d_s . w_o; g g) sum_i wt_i f_i p_i D(x, w_i) / sum_i wt_i f_i p_i,

f_i = f_hg(d_s . w_i; g), p_i = f_hg(w_i . w_o; g): the two lobes integrated exactly, the
quadrature averaging only the transported light D (docs/METHOD.md Eq. 25e).

An environment region's unscattered lobe (``direct``, where ``lights``' lobe_a0 > 0) emits in
its region's own pattern, a number per region and direction (``pattern``, renderer.pattern_table),
and the rest of its walked light as one lobe about the rest's flux (:func:`region_lobes`;
docs/METHOD.md Eq. 26a).

So the second scattering toward the camera is transported, not modelled: near a free surface
little light arrives from outside, which one lobe per cell cannot say. What the renderer then
adds per sample is the single scattering (Solution.single_scattering()). ``out`` holds it toward
a pinhole at ``eye`` at the voxels where ``needed``. The directions are swept in a few lanes
that run in parallel, each with its own sums, one parallel region per frame. An empty voxel
that no light but the entering light reaches along w (nothing upstream of it holds medium)
holds that light unchanged, and the sweeps pass it without interpolating or integrating
(:func:`_untouched`). That light, 0 or an environment's, is constant along w, so the image is
the same up to the float64 rounding by which interpolating four equal values can miss their value
(bit for bit on the bench's demo, WDAS and cumulus field scenes).

NumPy twin: tests/twins.py (gathered_source).
"""
import math

import numba as nb
import numpy as np

from . import ON_ITS_OWN
from .render import (DIRECT, DIRECTION, FIELDS, FLUX, FULL, LOBE_A0, LOBE_CAP, OFFSET, PHI, PHID, POSITION, POWER,
                     SHAPE, diffuse_lobe_axis, f_hg, flux_lobe_axis, grid_fields, light_geometry, point_lookup,
                     walk_lobe_weights)
from .sampling import interpolate


#: a lobe whose g is PATTERN + j or more is light of angular pattern j (column j of
#: gathered_source's ``pattern``), not an HG lobe
PATTERN = 8.0


@nb.njit(inline="always", cache=True)
def _voxel(a, s, p, q):
    """The (x, y, z) index of the voxel at slice s across axis a and (p, q) along the two other
    axes in increasing order."""
    if a == 0:
        return s, p, q
    if a == 1:
        return p, s, q
    return p, q, s


@nb.njit(inline="always", fastmath=True, cache=True)
def _linear_stencil(u, nu):
    """Along one axis of nu cells, the linear stencil at the continuous index u: (inside, i0,
    i1, fu); outside [-1/2, n - 1/2] the value is 0, in the outer half cell it is clamped to the
    edge. A slice's bilinear stencil is the product of its two axes' (:func:`_bilinear`)."""
    if u < -0.5 or u > nu - 0.5:
        return False, 0, 0, 0.0
    u = min(max(u, 0.0), nu - 1.0)
    i0 = min(int(u), max(nu - 2, 0))
    return True, i0, min(i0 + 1, nu - 1), u - i0


@nb.njit(fastmath=True, cache=True, nogil=True)
def _axis_stencils(offset, n):
    """The linear stencils (:func:`_linear_stencil`) at u = i + offset, i = 0 .. n - 1: (inside
    bool (n,), i0 int64 (n,), i1 int64 (n,), fu float64 (n,)). The point upstream of every cell of
    a slice lies at the same offset, so one row of stencils per axis serves the whole sweep."""
    inside = np.zeros(n, np.bool_)
    i0 = np.zeros(n, np.int64)
    i1 = np.zeros(n, np.int64)
    f = np.zeros(n)
    for i in range(n):
        inside[i], i0[i], i1[i], f[i] = _linear_stencil(i + offset, n)
    return inside, i0, i1, f


@nb.njit(inline="always", fastmath=True, cache=True)
def _bilinear(buf, su, sv, p, q, k, ch):
    """buf (3, nu, nv, C) quantity k, channel ch at the point upstream of cell (p, q): the
    bilinear value on the stencils su[.][p] x sv[.][q] of :func:`_axis_stencils`, 0 outside."""
    if not (su[0][p] and sv[0][q]):
        return 0.0
    i0, i1, fu = su[1][p], su[2][p], su[3][p]
    j0, j1, fv = sv[1][q], sv[2][q], sv[3][q]
    return ((1 - fu) * ((1 - fv) * buf[k, i0, j0, ch] + fv * buf[k, i0, j1, ch])
            + fu * ((1 - fv) * buf[k, i1, j0, ch] + fv * buf[k, i1, j1, ch]))


@nb.njit(inline="always", fastmath=True, cache=True)
def mean_inverse_square(r, R):
    """The mean of 1/|y - p|^2 over the ball of radius R whose centre is r from the point p
    (a point light's 1/r^2 averaged over a cell of the same volume):
      3 / (4 r R^3) (2 r R + (R^2 - r^2) ln((r + R) / |r - R|)),
    which is 1/r^2 (1 + x^2/5 + 3 x^4/35 + ...), x = R/r, far from p (that series where
    x < 1/4), 3 / (2 R^2) at r = R and 3 / R^2 at r = 0: finite, where 1/r^2 is not."""
    if r > 4.0 * R:
        x2 = (R / r) ** 2
        return (1.0 + x2 / 5.0 + 3.0 * x2 * x2 / 35.0) / (r * r)
    if r <= 1e-6 * R:
        return 3.0 / (R * R)
    log = math.log((r + R) / max(abs(r - R), 1e-300 * R))
    return 3.0 / (4.0 * r * R ** 3) * (2.0 * r * R + (R * R - r * r) * log)


@nb.njit(inline="always", cache=True)
def mean_radial_cosine(r, R, M):
    """|m|, m the mean of the unit vector (y - p) / |y - p| weighted by 1/|y - p|^2 over the
    ball of radius R whose centre c is r from the point p (a point light's directions over a cell
    of the same volume, weighted as its unscattered light is); M = mean_inverse_square(r, R), the
    weights' mean, which the caller has. The weighted sum of the unit vectors is the field of a
    uniform ball at p, V (c - p) / r^3 outside it and (4 pi / 3) (c - p) inside, so |m| =
    1 / (r^2 M) for r >= R and r / (R^3 M) for r < R: 1 far from p (1 - x^2/5 + ..., x = R/r),
    2/3 at r = R and 0 at r = 0 (the light's own cell sends its light every way)."""
    if r <= 1e-6 * R:
        return 0.0
    if r >= R:
        return 1.0 / (r * r * M)
    return r / (R * R * R * M)


@nb.njit(inline="always", fastmath=True, cache=True)
def region_lobes(direct, phid, flux, corners, g, a0, axis):
    """An environment region's walked light at the stencil ``corners`` as two lobes (docs/METHOD.md,
    "Environment lights", Eq. 26a): (phi_u, the unscattered fluence ``direct``, taken at most
    phid, whose light the caller scatters with the region's pattern; then the rest, phid - phi_u,
    as :func:`~popvol.kernels.render.diffuse_lobe_axis` gives it, about its own flux J - a0 phi_u
    ``axis``: weight, axis (3 numbers), g A_rest, A_rest = min(|J_rest| / (phid - phi_u), 1)).
    The unscattered light is a lobe of mean cosine a0 about ``axis``, the light's direction."""
    pd = interpolate(phid, corners)
    if pd <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    pu = min(max(interpolate(direct, corners), 0.0), pd)
    rest = pd - pu
    if rest <= 0.0:
        return pu, 0.0, 0.0, 0.0, 1.0, 0.0
    rest, jx, jy, jz, g_rest = flux_lobe_axis(rest, interpolate(flux[0], corners) - a0 * pu * axis[0],
                                              interpolate(flux[1], corners) - a0 * pu * axis[1],
                                              interpolate(flux[2], corners) - a0 * pu * axis[2], g, 1.0)
    return pu, rest, jx, jy, jz, g_rest


@nb.njit(**ON_ITS_OWN)
def cell_lobes(medium, lights, grid, spherical, cells, lobes, m, n_ch, has_diffuse, cell_radius):
    """Row m of ``lobes`` (:func:`emission_lobes`)."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    is_point = lights[0]
    power = lights[POWER]
    ix, iy, iz = cells[m, 0], cells[m, 1], cells[m, 2]
    x = (origin[0] + ix * voxel[0], origin[1] + iy * voxel[1], origin[2] + iz * voxel[2])
    g = g_grid[0, 0, 0] if g_grid.size == 1 else g_grid[ix, iy, iz]
    corners = (ix, ix, iy, iy, iz, iz, 0.0, 0.0, 0.0)
    for l in range(is_point.shape[0]):
        point, mu, inv_r2, q0, q1, q2 = light_geometry(lights, spherical, l, x, (0.0, 0.0, 1.0))
        spread = 1.0
        if point:                   # the light travels from its position p through x
            p = lights[POSITION][l]
            r = math.sqrt(inv_r2)
            axis = ((x[0] - p[0]) * r, (x[1] - p[1]) * r, (x[2] - p[2]) * r)
            # the cell's mean of 1/r^2, not its centre's: finite with the light in the cell
            dist = 1.0 / max(r, 1e-300)
            inv_r2 = mean_inverse_square(dist, cell_radius)
            # and its lobes about the cell's mean direction from the light, as broad as the
            # directions across the cell make them (the first moment kept: g |m|)
            spread = mean_radial_cosine(dist, cell_radius, inv_r2)
        else:
            axis = (lights[DIRECTION][l, 0], lights[DIRECTION][l, 1], lights[DIRECTION][l, 2])
        for c in range(n_ch):
            if point:
                phi, phia, pdir = point_lookup(spherical[FIELDS], spherical[OFFSET][l, c], spherical[SHAPE][l],
                                               q0, q1, q2, spherical[FULL][l])
            else:
                phi, phia, pdir = grid_fields(grid, l, c, corners)
            w_dir, g_dir, w_rest, g_rest = walk_lobe_weights(phi, phia, pdir, g)
            pd, jx, jy, jz, g_d = 0.0, 0.0, 0.0, 1.0, 0.0
            region = not point and lights[LOBE_A0][l] > 0.0
            if region:
                # an environment region: its unscattered lobe (``direct``, a part of phid) in its
                # region's pattern, and the rest of its walked light about the rest's own flux
                w_dir, pd, jx, jy, jz, g_d = region_lobes(grid[DIRECT][l, c], grid[PHID][l, c], grid[FLUX][l, c],
                                                          corners, g, lights[LOBE_A0][l], axis)
                g_dir = PATTERN + l
            elif has_diffuse:
                pd, jx, jy, jz, g_d = diffuse_lobe_axis(grid[PHID][l, c], grid[FLUX][l, c], corners, g,
                                                        grid[LOBE_CAP][l])
            k = 3 * (l * n_ch + c)
            for kind in range(3):
                if kind == 2:
                    a0, a1, a2, gk, wk = jx, jy, jz, g_d, pd
                else:
                    a0, a1, a2 = axis
                    gk, wk = (g_dir * spread, w_dir * inv_r2) if kind == 0 else (g_rest * spread, w_rest * inv_r2)
                lobes[m, k + kind, 0] = a0
                lobes[m, k + kind, 1] = a1
                lobes[m, k + kind, 2] = a2
                lobes[m, k + kind, 3] = gk
                for colour in range(3):
                    on = n_ch == 1 or colour == c
                    lobes[m, k + kind, 4 + colour] = wk * power[l, colour] if on else 0.0


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def emission_lobes(medium, lights, grid, spherical, cells, lobes):
    """Fill ``lobes`` float32 (M, K, 7) with the in-scattered light at the centre x of each cell
    cells[m] (int64 (M, 3) indices into the bundles' grid) as K = n_lights x n_channels x 3
    lobes (axis (3), g, RGB weight (3)) such that the light leaving x along w is
      L_s(x, w) / sigma_s = sum_k weight_k f_hg(axis_k . w; g_k)
    (kernels/render.py, light_in_scattering with the camera ray d = -w): per light l and field
    channel c, the walk's unscattered light and its rest about the light's direction at x
    (walk_lobe_weights; for a point light, divided by r^2 averaged over the cell,
    :func:`mean_inverse_square`, and with g times :func:`mean_radial_cosine`, the spread of the
    directions from the light across it, since the lobe stands for the whole cell) and the
    diffusion stage's light about
    its flux (diffuse_lobe_axis); for an environment region (``lights``' lobe_a0 > 0) its
    unscattered lobe, marked as pattern l by its g = PATTERN + l (the light gathered_source's
    ``pattern`` gives it), and the rest about the rest's flux (:func:`region_lobes`); a grey
    field's lobe carries the light's RGB power, channel c's only colour c. Evaluated once per
    cell, they serve every direction of the gather."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    n_ch = grid[PHI].shape[1]
    has_diffuse = grid[PHID].shape[0] > 0
    cell_radius = (3.0 * voxel[0] * voxel[1] * voxel[2] / (4.0 * math.pi)) ** (1.0 / 3.0)
    for m in nb.prange(cells.shape[0]):
        cell_lobes(medium, lights, grid, spherical, cells, lobes, np.int64(m), n_ch, has_diffuse, cell_radius)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def gathered_source(medium, lobes, grids, across_z, dirs, weights, out, norm, boundary, sun, out_sun, norm_sun,
                    pattern):
    """Add to ``out`` float32 (lanes, nx, ny, nz, C) the gathered L_s / sigma_s toward the
    camera (module docstring) and to ``norm`` float32 (lanes, nx, ny, nz) the phase
    quadrature's sum, at the voxels where ``needed``; the caller sums the lanes and divides.
    C = 3 (RGB), or C = 1 where every lobe has one colour (one light, a grey medium): then the
    lobes' first weight is transported with sigma_t's first channel, and the caller multiplies
    by the colour.
    ``lobes``: the in-scattered light of the non-empty voxels (:func:`emission_lobes`).
    grids: (density float32, albedo float32, g float32 (the medium's grids, or (1, 1, 1)
    constants), slot int64 (voxel (i, j, k)'s row of ``lobes``, -1 where the density is 0),
    needed bool, to_eye float64 (nx, ny, nz, 3), the unit vector toward the camera where needed
    (:func:`eye_directions`)); across_z: C-ordered copies of the same with the z axis first
    ((nz, nx, ny, ...)), from which a direction swept across z reads its slices in memory order
    (its writes stay in place).
    ``sun`` = (separated bool (K,), axis float64 (3,), g_sun float): the lobes marked separated
    (a sun's unscattered light, a lobe f_hg(axis . w; g_sun) the same in every cell: docs/METHOD.md,
    "Gathered last bounce", Eq. 25e) are transported without their angular factor, which
    multiplies the phase toward the eye instead: their light goes to ``out_sun`` (as ``out``) and
    that product's sum to ``norm_sun`` (as ``norm``), so that the caller can divide by it and
    multiply by the two lobes' exact integral; where none is separated they are not written (and
    may be (lanes, 1, 1, 1, ...) placeholders).
    Direction i goes to lane i mod lanes, and the lanes run in parallel, each sweeping its
    directions one after another (so the sum does not depend on the number of threads). One
    colour has its own sweep (:func:`_sweep_one_colour`): the same arithmetic without the loop
    over channels; so has RGB in a grey medium (:func:`_sweep_grey`).
    dirs float64 (N, 3) unit directions of travel, weights float64 (N,); boundary float64 (N, C),
    the radiance entering the grid along each direction (module docstring); pattern float64 (N,
    P): what a unit fluence of pattern lobe j (g = PATTERN + j) scatters toward direction i, per
    steradian (renderer.pattern_table). medium: the render
    kernel's bundle, on the grid of the lobes (the medium's or a coarser one)."""
    separated, axis, g_sun = sun
    lanes = out.shape[0]
    for lane in nb.prange(lanes):
        for i in range(lane, dirs.shape[0], lanes):
            w = dirs[i]
            f_sun = f_hg(axis[0] * w[0] + axis[1] * w[1] + axis[2] * w[2], g_sun)
            if out.shape[4] == 1:
                _sweep_one_colour(medium, lobes, grids, across_z, w, weights[i], out[lane], norm[lane],
                                  boundary[i, 0], separated, f_sun, out_sun[lane], norm_sun[lane], pattern[i])
            elif _grey(medium[1]):
                _sweep_grey(medium, lobes, grids, across_z, w, weights[i], out[lane], norm[lane], boundary[i],
                            separated, f_sun, out_sun[lane], norm_sun[lane], pattern[i])
            else:
                _sweep(medium, lobes, grids, across_z, w, weights[i], out[lane], norm[lane], boundary[i],
                       separated, f_sun, out_sun[lane], norm_sun[lane], pattern[i])


@nb.njit(fastmath=True, cache=True, nogil=True)
def eye_directions(medium, eye, needed):
    """float64 (nx, ny, nz, 3): the unit vector from each voxel centre toward ``eye`` where
    ``needed`` (0 elsewhere), made once for all the directions of a gather."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    nx, ny, nz = needed.shape
    out = np.zeros((nx, ny, nz, 3))
    for ix in range(nx):
        for iy in range(ny):
            for iz in range(nz):
                if needed[ix, iy, iz]:
                    ex = eye[0] - (origin[0] + ix * voxel[0])
                    ey = eye[1] - (origin[1] + iy * voxel[1])
                    ez = eye[2] - (origin[2] + iz * voxel[2])
                    r = max(math.sqrt(ex * ex + ey * ey + ez * ez), 1e-300)
                    out[ix, iy, iz, 0] = ex / r
                    out[ix, iy, iz, 1] = ey / r
                    out[ix, iy, iz, 2] = ez / r
    return out


@nb.njit(inline="always", fastmath=True, cache=True)
def _slices(medium, grids, across_z, w):
    """How direction w (3 floats) is swept: (a, the axis its slices are taken across, the one
    along which |w| is largest; wa = w[a]; ell = voxel[a] / |wa|, the path between slices;
    (na, nb, nc), the grid's size across a and along the two other axes b < c in order; the
    grids it reads, z first when a = 2 (:func:`gathered_source`); su, sv, the stencils of the
    point upstream of a slice's cells along b and c (:func:`_axis_stencils`))."""
    voxel = medium[6]
    n = grids[0].shape
    w0, w1, w2 = w[0], w[1], w[2]
    a = 0
    if abs(w1) > abs(w0) and abs(w1) >= abs(w2):
        a = 1
    elif abs(w2) > abs(w0) and abs(w2) > abs(w1):
        a = 2
    b = 1 if a == 0 else 0
    c = 1 if a == 2 else 2
    wa = (w0, w1, w2)[a]
    ell = voxel[a] / abs(wa)
    ob = -ell * (w0, w1, w2)[b] / voxel[b]          # the upstream point, in the slice before
    oc = -ell * (w0, w1, w2)[c] / voxel[c]
    # reads at [s, p, q] of the z-first copies when sweeping across z, else in place
    read = across_z if a == 2 else grids
    return a, wa, ell, (n[a], n[b], n[c]), read, _axis_stencils(ob, n[b]), _axis_stencils(oc, n[c])


@nb.njit(inline="always", fastmath=True, cache=True)
def _segment(s_up, sig, path):
    """(T, a_up, a_v) of the path from the point upstream (sigma_t s_up) to the voxel (sig),
    sigma_t linear along it (module docstring): T = exp(-tau), tau = (s_up + sig) / 2 path its
    optical depth, and the weights of the emission per unit length upstream and at the voxel,
    a_up = b_up / sigma_t(up) and a_v = b_v / sigma_t(v), so that the segment adds a_up q(up) +
    a_v q(v) = b_up J(up) + b_v J(v) with the source function J = q / sigma_t linear in optical
    depth:
      b_up = (1 - T (1 + tau)) / tau,  b_v = 1 - T - b_up
    (their series tau (1/2 - tau/3 + tau^2/8), tau (1/2 - tau/6 + tau^2/24) where tau is small).
    Where sigma_t is 0 at one end, J there is the other end's: its weight goes to the other end."""
    tau = 0.5 * (s_up + sig) * path
    if tau < 1e-2:
        t = math.exp(-tau) if tau > 0.0 else 1.0     # no call in empty space
        b_up = tau * (0.5 - tau * (1.0 / 3.0 - tau / 8.0))
        b_v = tau * (0.5 - tau * (1.0 / 6.0 - tau / 24.0))
    else:
        t = math.exp(-tau)
        b_up = (1.0 - t * (1.0 + tau)) / tau
        b_v = 1.0 - t - b_up
    if sig > 0.0:
        if s_up > 0.0:
            return t, b_up / s_up, b_v / sig
        return t, 0.0, (b_up + b_v) / sig
    if s_up > 0.0:
        return t, (b_up + b_v) / s_up, 0.0
    return t, 0.0, 0.0


@nb.njit(inline="always", fastmath=True, cache=True)
def _toward_eye(w0, w1, w2, weight, to_eye, g_grid, rx, ry, rz):
    """weight f_hg(w . to the eye; g) at the voxel read at (rx, ry, rz)."""
    g = g_grid[0, 0, 0] if g_grid.size == 1 else g_grid[rx, ry, rz]
    return weight * f_hg(w0 * to_eye[rx, ry, rz, 0] + w1 * to_eye[rx, ry, rz, 1] + w2 * to_eye[rx, ry, rz, 2], g)


@nb.njit(fastmath=True, cache=True, nogil=True)
def _sweep(medium, lobes, grids, across_z, w, weight, out, norm, boundary, separated, f_sun, out_sun, norm_sun,
           pattern):
    """One direction w (float64 (3,), weight ``weight``): transport slice by slice and add
    weight f_hg(w . to the eye; g) times L_in to ``out`` (nx, ny, nz, C) and the weight
    times f_hg to ``norm`` (nx, ny, nz) where ``needed``; the ``separated`` lobes' light,
    transported apart, times f_sun (their angular factor toward w) to ``out_sun`` and
    ``norm_sun`` (:func:`gathered_source`). grids: (density, albedo, g, slot, needed, to_eye
    (:func:`eye_directions`)); across_z: the same with the z axis first read by a direction
    swept across z (:func:`gathered_source`)."""
    scale, albedo_rgb = medium[1], medium[3]
    n_out = out.shape[3]
    grey = _grey(scale)
    w0, w1, w2 = w[0], w[1], w[2]
    a, wa, ell, (na, nb_, nc_), read, su, sv = _slices(medium, grids, across_z, w)
    density, albedo, g_grid, slot, needed, to_eye = read
    apart = _any(separated)
    # per slice and channel: L_in, the emission per unit length q and sigma_t, then the separated
    # lobes' L_in and q, of the slice before (prev) and this one (cur)
    prev = np.zeros((5, nb_, nc_, n_out))
    cur = np.zeros((5, nb_, nc_, n_out))
    touched_prev = np.zeros((nb_, nc_), np.bool_)      # (:func:`_untouched`, as in _sweep_grey)
    touched_cur = np.zeros((nb_, nc_), np.bool_)
    for ch in range(n_out):
        prev[0, :, :, ch] = cur[0, :, :, ch] = boundary[ch]
    for step in range(na):
        s = step if wa > 0 else na - 1 - step
        for p in range(nb_):
            for q in range(nc_):
                ix, iy, iz = _voxel(a, s, p, q)                 # the voxel, where it is written
                rx, ry, rz = (s, p, q) if a == 2 else (ix, iy, iz)     # where it is read
                rho = density[rx, ry, rz]
                if _untouched(rho, step, su[0][p] and sv[0][q], touched_prev, su[1][p], su[2][p], sv[1][q],
                              sv[2][q]):
                    if touched_cur[p, q]:           # else it holds them from two slices back
                        for ch in range(n_out):
                            cur[0, p, q, ch] = boundary[ch]
                            cur[1, p, q, ch] = cur[2, p, q, ch] = cur[3, p, q, ch] = cur[4, p, q, ch] = 0.0
                        touched_cur[p, q] = False
                    # it holds the entering light and 0 (cur), added toward the eye below
                else:
                    touched_cur[p, q] = True
                    j0, j1, j2, d0, d1, d2, alb = _cell_emission(lobes, slot, albedo, rx, ry, rz, w0, w1, w2, n_out,
                                                                 separated, pattern)
                    path = 0.5 * ell if step == 0 else ell      # from the grid's face: half a slice
                    t = a_up = a_v = 0.0
                    for ch in range(n_out):
                        sig = scale[ch] * rho
                        qv = sig * alb * albedo_rgb[ch] * (j0 if ch == 0 else (j1 if ch == 1 else j2))
                        qd = sig * alb * albedo_rgb[ch] * (d0 if ch == 0 else (d1 if ch == 1 else d2))
                        if step == 0:
                            l_up, q_up, ld_up, qd_up = boundary[ch], qv, 0.0, qd
                        elif su[0][p] and sv[0][q]:
                            l_up = _bilinear(prev, su, sv, p, q, 0, ch)
                            q_up = _bilinear(prev, su, sv, p, q, 1, ch)
                            ld_up = qd_up = 0.0
                            if apart:
                                ld_up = _bilinear(prev, su, sv, p, q, 3, ch)
                                qd_up = _bilinear(prev, su, sv, p, q, 4, ch)
                        else:                           # upstream of the grid: what enters it
                            l_up, q_up, ld_up, qd_up = boundary[ch], 0.0, 0.0, 0.0
                        if ch == 0 or not grey:        # sigma_t's channels differ only in an RGB medium
                            t, a_up, a_v = _segment(sig if step == 0 else _bilinear(prev, su, sv, p, q, 2, ch), sig, path)
                        cur[0, p, q, ch] = l_up * t + q_up * a_up + qv * a_v
                        cur[1, p, q, ch] = qv
                        cur[2, p, q, ch] = sig
                        cur[3, p, q, ch] = ld_up * t + qd_up * a_up + qd * a_v
                        cur[4, p, q, ch] = qd
                if needed[rx, ry, rz]:
                    f = _toward_eye(w0, w1, w2, weight, to_eye, g_grid, rx, ry, rz)
                    norm[ix, iy, iz] += f
                    for ch in range(n_out):
                        out[ix, iy, iz, ch] += f * cur[0, p, q, ch]
                    if apart:
                        norm_sun[ix, iy, iz] += f * f_sun
                        for ch in range(n_out):
                            out_sun[ix, iy, iz, ch] += f * f_sun * cur[3, p, q, ch]
        prev, cur = cur, prev
        touched_prev, touched_cur = touched_cur, touched_prev


@nb.njit(inline="always", fastmath=True, cache=True)
def _cell_emission(lobes, slot, albedo, rx, ry, rz, w0, w1, w2, n_out, separated, pattern):
    """:func:`_emitted` toward (w0, w1, w2) of the voxel read at (rx, ry, rz) and its albedo:
    (j0, j1, j2, d0, d1, d2, albedo), all 0 where it holds no lobes (``slot`` -1)."""
    row = slot[rx, ry, rz]
    if row < 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    j0, j1, j2, d0, d1, d2 = _emitted(lobes, row, w0, w1, w2, n_out, separated, pattern)
    return j0, j1, j2, d0, d1, d2, albedo[0, 0, 0] if albedo.size == 1 else albedo[rx, ry, rz]


@nb.njit(inline="always", fastmath=True, cache=True)
def _emitted(lobes, row, w0, w1, w2, n_out, separated, pattern):
    """The light of lobe row ``row`` toward (w0, w1, w2), per colour (the last two 0 where
    n_out = 1): sum over its lobes of weight f_hg(axis . w; g A), or weight pattern[j] for a
    pattern lobe (g = PATTERN + j; ``pattern`` the row of w), empty lobes passed over; then
    the ``separated`` lobes' weights alone (:func:`gathered_source`), which that sum leaves out."""
    j0 = j1 = j2 = d0 = d1 = d2 = 0.0
    for k in range(lobes.shape[1]):
        l0 = lobes[row, k, 4]
        l1 = lobes[row, k, 5] if n_out == 3 else 0.0
        l2 = lobes[row, k, 6] if n_out == 3 else 0.0
        if l0 == 0.0 and l1 == 0.0 and l2 == 0.0:
            continue
        if separated[k]:
            d0 += l0
            d1 += l1
            d2 += l2
            continue
        gk = lobes[row, k, 3]
        if gk >= PATTERN:
            f = pattern[int(gk - PATTERN)]
        else:
            f = f_hg(lobes[row, k, 0] * w0 + lobes[row, k, 1] * w1 + lobes[row, k, 2] * w2, gk)
        j0 += l0 * f
        j1 += l1 * f
        j2 += l2 * f
    return j0, j1, j2, d0, d1, d2


@nb.njit(inline="always", cache=True)
def _any(flags):
    """Whether any of ``flags`` (bool (K,)) is set."""
    for k in range(flags.shape[0]):
        if flags[k]:
            return True
    return False


@nb.njit(inline="always", cache=True)
def _grey(scale):
    """Whether sigma_t per density is the same in the three channels."""
    return scale[0] == scale[1] and scale[1] == scale[2]


@nb.njit(fastmath=True, cache=True, nogil=True)
def _sweep_grey(medium, lobes, grids, across_z, w, weight, out, norm, boundary, separated, f_sun, out_sun, norm_sun,
                pattern):
    """:func:`_sweep` in RGB (out (nx, ny, nz, 3)) where sigma_t is grey (:func:`_grey`): the same
    arithmetic with the three channels written out, one segment's transmittance for all three
    and the upstream point's bilinear weights made once."""
    scale_0, albedo_rgb = medium[1][0], medium[3]
    w0, w1, w2 = w[0], w[1], w[2]
    b0, b1, b2 = boundary[0], boundary[1], boundary[2]
    a, wa, ell, (na, nb_, nc_), read, su, sv = _slices(medium, grids, across_z, w)
    density, albedo, g_grid, slot, needed, to_eye = read
    apart = _any(separated)
    n_up = 13 if apart else 7          # the separated lobes' quantities are read only if any is
    # L_in (3), q (3), sigma_t, then the separated lobes' L_in (3) and q (3), of the slice
    # before ...
    prev = np.zeros((nb_, nc_, 13))
    cur = np.zeros((nb_, nc_, 13))           # ... and of this one
    up = np.zeros(13)
    # whether a cell holds more than the light entering the grid (:func:`_untouched`); where
    # not, it holds that light and nothing else
    touched_prev = np.zeros((nb_, nc_), np.bool_)
    touched_cur = np.zeros((nb_, nc_), np.bool_)
    for buf in (prev, cur):
        buf[:, :, 0], buf[:, :, 1], buf[:, :, 2] = b0, b1, b2
    for step in range(na):
        s = step if wa > 0 else na - 1 - step
        path = 0.5 * ell if step == 0 else ell      # from the grid's face: half a slice
        for p in range(nb_):
            inside_p, i0, i1, fu = su[0][p], su[1][p], su[2][p], su[3][p]
            for q in range(nc_):
                ix, iy, iz = _voxel(a, s, p, q)
                rx, ry, rz = (s, p, q) if a == 2 else (ix, iy, iz)
                if _untouched(density[rx, ry, rz], step, inside_p and sv[0][q], touched_prev, i0, i1, sv[1][q],
                              sv[2][q]):
                    if touched_cur[p, q]:           # else it holds them from two slices back
                        cur[p, q, 0], cur[p, q, 1], cur[p, q, 2] = b0, b1, b2
                        for n in range(3, n_up):
                            cur[p, q, n] = 0.0
                        touched_cur[p, q] = False
                    l0, l1, l2 = b0, b1, b2             # what it holds, added toward the eye below
                    m0 = m1 = m2 = 0.0
                else:
                    touched_cur[p, q] = True
                    j0, j1, j2, d0, d1, d2, alb = _cell_emission(lobes, slot, albedo, rx, ry, rz, w0, w1, w2, 3,
                                                                 separated, pattern)
                    sig = scale_0 * density[rx, ry, rz]
                    e0, e1, e2 = sig * alb * albedo_rgb[0], sig * alb * albedo_rgb[1], sig * alb * albedo_rgb[2]
                    q0, q1, q2 = e0 * j0, e1 * j1, e2 * j2
                    r0, r1, r2 = e0 * d0, e1 * d1, e2 * d2
                    if step == 0:
                        t, a_up, a_v = _segment(sig, sig, path)
                        up[0], up[1], up[2] = b0, b1, b2
                        up[3], up[4], up[5] = q0, q1, q2
                        up[7], up[8], up[9] = 0.0, 0.0, 0.0
                        up[10], up[11], up[12] = r0, r1, r2
                    elif inside_p and sv[0][q]:
                        k0, k1, fv = sv[1][q], sv[2][q], sv[3][q]
                        e00, e01, e10, e11 = (1 - fu) * (1 - fv), (1 - fu) * fv, fu * (1 - fv), fu * fv
                        for n in range(n_up):
                            up[n] = e00 * prev[i0, k0, n] + e01 * prev[i0, k1, n] + e10 * prev[i1, k0, n] + e11 * prev[i1, k1, n]
                        t, a_up, a_v = _segment(up[6], sig, path)
                    else:                                       # upstream of the grid: what enters it
                        t, a_up, a_v = _segment(0.0, sig, path)
                        up[0], up[1], up[2] = b0, b1, b2
                        for n in range(3, 13):
                            up[n] = 0.0
                    l0 = up[0] * t + up[3] * a_up + q0 * a_v
                    l1 = up[1] * t + up[4] * a_up + q1 * a_v
                    l2 = up[2] * t + up[5] * a_up + q2 * a_v
                    m0 = up[7] * t + up[10] * a_up + r0 * a_v
                    m1 = up[8] * t + up[11] * a_up + r1 * a_v
                    m2 = up[9] * t + up[12] * a_up + r2 * a_v
                    cur[p, q, 0], cur[p, q, 1], cur[p, q, 2] = l0, l1, l2
                    cur[p, q, 3], cur[p, q, 4], cur[p, q, 5] = q0, q1, q2
                    cur[p, q, 6] = sig
                    cur[p, q, 7], cur[p, q, 8], cur[p, q, 9] = m0, m1, m2
                    cur[p, q, 10], cur[p, q, 11], cur[p, q, 12] = r0, r1, r2
                if needed[rx, ry, rz]:
                    f = _toward_eye(w0, w1, w2, weight, to_eye, g_grid, rx, ry, rz)
                    fs = f * f_sun
                    norm[ix, iy, iz] += f
                    out[ix, iy, iz, 0] += f * l0
                    out[ix, iy, iz, 1] += f * l1
                    out[ix, iy, iz, 2] += f * l2
                    if apart:
                        norm_sun[ix, iy, iz] += fs
                        out_sun[ix, iy, iz, 0] += fs * m0
                        out_sun[ix, iy, iz, 1] += fs * m1
                        out_sun[ix, iy, iz, 2] += fs * m2
        prev, cur = cur, prev
        touched_prev, touched_cur = touched_cur, touched_prev


@nb.njit(inline="always", cache=True)
def _untouched(rho, step, inside, touched, i0, i1, k0, k1):
    """Whether a cell of density ``rho`` sees only the light entering the grid along the sweep's
    direction, unchanged: it is empty, and so is the way upstream (``step`` 0, the first slice,
    or the point upstream outside the grid, ``inside`` False) or the four cells of the slice
    before that the point upstream lies between (rows i0, i1, columns k0, k1) hold only that
    light (``touched`` False). Its radiance is then the entering light exactly, with nothing
    emitted and no optical depth: a sweep skips its interpolation and segment."""
    if rho != 0.0:
        return False
    if step == 0 or not inside:
        return True
    return not (touched[i0, k0] or touched[i0, k1] or touched[i1, k0] or touched[i1, k1])


@nb.njit(inline="always", fastmath=True, cache=True)
def _lerp2(buf, k, i0, i1, j0, j1, fu, fv):
    """buf (K, nu, nv) quantity k, bilinear between rows i0, i1 and columns j0, j1 (the
    arithmetic of :func:`_bilinear`, so the same bits)."""
    return ((1 - fu) * ((1 - fv) * buf[k, i0, j0] + fv * buf[k, i0, j1])
            + fu * ((1 - fv) * buf[k, i1, j0] + fv * buf[k, i1, j1]))


@nb.njit(fastmath=True, cache=True, nogil=True)
def _sweep_one_colour(medium, lobes, grids, across_z, w, weight, out, norm, boundary, separated, f_sun, out_sun,
                      norm_sun, pattern):
    """:func:`_sweep` where every lobe has one colour (out (nx, ny, nz, 1)): the lobes' first
    weight transported with sigma_t's first channel, the same arithmetic in the same order
    without the loop over channels (so the same bits), the upstream point's five bilinear
    values on one stencil."""
    scale_0, albedo_0 = medium[1][0], medium[3][0]      # sigma_t per density, albedo: channel 0
    n_lobes = lobes.shape[1]
    w0, w1, w2 = w[0], w[1], w[2]
    a, wa, ell, (na, nb_, nc_), read, su, sv = _slices(medium, grids, across_z, w)
    density, albedo, g_grid, slot, needed, to_eye = read
    apart = _any(separated)
    prev = np.zeros((5, nb_, nc_))          # L_in, q, sigma_t, the separated L_in and q of the slice before ...
    cur = np.zeros((5, nb_, nc_))           # ... and of this one
    touched_prev = np.zeros((nb_, nc_), np.bool_)      # (:func:`_untouched`, as in _sweep_grey)
    touched_cur = np.zeros((nb_, nc_), np.bool_)
    prev[0] = cur[0] = boundary
    for step in range(na):
        s = step if wa > 0 else na - 1 - step
        path = 0.5 * ell if step == 0 else ell      # from the grid's face: half a slice
        for p in range(nb_):
            inside_p, i0, i1, fu = su[0][p], su[1][p], su[2][p], su[3][p]
            for q in range(nc_):
                ix, iy, iz = _voxel(a, s, p, q)
                rx, ry, rz = (s, p, q) if a == 2 else (ix, iy, iz)
                if _untouched(density[rx, ry, rz], step, inside_p and sv[0][q], touched_prev, i0, i1, sv[1][q],
                              sv[2][q]):
                    if touched_cur[p, q]:           # else it holds them from two slices back
                        cur[0, p, q] = boundary
                        cur[1, p, q] = cur[2, p, q] = cur[3, p, q] = cur[4, p, q] = 0.0
                        touched_cur[p, q] = False
                    light, light_sun = boundary, 0.0     # what it holds, added toward the eye below
                else:
                    touched_cur[p, q] = True
                    j = 0.0
                    d = 0.0
                    alb = 0.0
                    row = slot[rx, ry, rz]
                    if row >= 0:
                        for k in range(n_lobes):
                            lk = lobes[row, k, 4]
                            if lk != 0.0:
                                if separated[k]:
                                    d += lk
                                elif lobes[row, k, 3] >= PATTERN:
                                    j += lk * pattern[int(lobes[row, k, 3] - PATTERN)]
                                else:
                                    j += lk * f_hg(lobes[row, k, 0] * w0 + lobes[row, k, 1] * w1
                                                   + lobes[row, k, 2] * w2, lobes[row, k, 3])
                        alb = albedo[0, 0, 0] if albedo.size == 1 else albedo[rx, ry, rz]
                    sig = scale_0 * density[rx, ry, rz]
                    e = sig * alb * albedo_0
                    qv = e * j
                    qd = e * d
                    if step == 0:
                        l_up, q_up, s_up, ld_up, qd_up = boundary, qv, sig, 0.0, qd
                    elif inside_p and sv[0][q]:
                        j0, j1, fv = sv[1][q], sv[2][q], sv[3][q]
                        l_up = _lerp2(prev, 0, i0, i1, j0, j1, fu, fv)
                        q_up = _lerp2(prev, 1, i0, i1, j0, j1, fu, fv)
                        s_up = _lerp2(prev, 2, i0, i1, j0, j1, fu, fv)
                        ld_up = qd_up = 0.0
                        if apart:
                            ld_up = _lerp2(prev, 3, i0, i1, j0, j1, fu, fv)
                            qd_up = _lerp2(prev, 4, i0, i1, j0, j1, fu, fv)
                    else:                                       # upstream of the grid: what enters it
                        l_up, q_up, s_up, ld_up, qd_up = boundary, 0.0, 0.0, 0.0, 0.0
                    t, a_up, a_v = _segment(s_up, sig, path)
                    light = l_up * t + q_up * a_up + qv * a_v
                    light_sun = ld_up * t + qd_up * a_up + qd * a_v
                    cur[0, p, q] = light
                    cur[1, p, q] = qv
                    cur[2, p, q] = sig
                    cur[3, p, q] = light_sun
                    cur[4, p, q] = qd
                if needed[rx, ry, rz]:
                    f = _toward_eye(w0, w1, w2, weight, to_eye, g_grid, rx, ry, rz)
                    norm[ix, iy, iz] += f
                    out[ix, iy, iz, 0] += f * light
                    if apart:
                        norm_sun[ix, iy, iz] += f * f_sun
                        out_sun[ix, iy, iz, 0] += f * f_sun * light_sun
        prev, cur = cur, prev
        touched_prev, touched_cur = touched_cur, touched_prev
