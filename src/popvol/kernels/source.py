"""Numba kernel: the combined in-scattering source of one view (docs/METHOD.md, "Rendering").

For a pinhole camera at c the camera ray through a point x has the direction
d(x) = (x - c) / |x - c|, a function of x alone. So every term of L_s(x, -d(x)) / sigma_s(x)
that is lit from the medium's grid,
  sum over suns l:         E_l [walk lobes + diffuse lobe](x, d(x))
  sum over point lights l: I_l  diffuse lobe(x, d(x))
(kernels/render.py, light_in_scattering), can be evaluated once per frame at the medium's
voxel centres into one float32 RGB field, which the ray march then reads with one trilinear
lookup per sample. A point light's walk lobes (its 1/r^2 spike, its spherical domain) stay
per sample. The field is needed only where the march reads fields (pipeline.voxels_seen).

NumPy twin: tests/twins.py (in_scattering_source).
"""
import math

import numba as nb
import numpy as np

from .render import lobe_toward, rest_lobe, walk_lobes


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def in_scattering_source(medium, lights, grid, spherical, eye, needed, out, lanes):
    """Add to ``out`` float32 (nx, ny, nz, 3) at the voxels where ``needed`` (bool (nx, ny, nz))
    L_s / sigma_s toward the camera at ``eye`` (float64 (3,)) of every term lit on the medium's
    grid (module docstring); other voxels are not touched (allocate ``out`` with zeros, or pass
    a source to add to). medium, lights, grid, spherical: the render kernel's bundles
    (render_kernel); the voxel's own g is the phase's anisotropy. The slices i go to ``lanes``
    (numba.get_num_threads()) lanes round-robin (kernels/__init__.py, "Lanes"): the medium
    fills the middle slices, not the outer ones.

    Along a row of voxels (i, j), from its first needed voxel to its last: the view directions
    once (:func:`view_directions`), then per light and channel its walk lobes
    (:func:`walk_terms`) and diffuse lobe (:func:`diffuse_terms`) into a buffer, each a loop
    without branches, which the compiler partly vectorises (on the 128^3 demo cloud, one
    thread: 13 ms against 18 ms with one loop holding both lobes and the branches between
    them), and only the needed voxels are added to ``out``."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits, occupied = medium
    is_point, direction, power, position, unscattered, lobe_a0 = lights
    phi, phia, direct, phid, flux, lobe_cap = grid
    nx, ny, nz = needed.shape
    n_ch = phi.shape[1]
    has_diffuse = phid.shape[0] > 0
    g_const = g_grid.size == 1
    for lane in nb.prange(lanes):
        terms = np.empty(nz)
        view = np.empty((3, nz))
        for i in range(lane, nx, lanes):
            for j in range(ny):
                k0, k1 = _needed_run(needed, i, j)
                if k1 <= k0:
                    continue
                n = k1 - k0
                # the row's g: the constant's one value, or the grid's run
                g = g_grid[0, 0, 0:1] if g_const else g_grid[i, j, k0:k1]
                view_directions((origin[0] + i * voxel[0] - eye[0], origin[1] + j * voxel[1] - eye[1],
                                 origin[2] + k0 * voxel[2] - eye[2]), voxel[2], view[:, :n])
                for l in range(is_point.shape[0]):
                    walk = not is_point[l]          # a point light's walk lobes are lit per sample
                    if not walk and not has_diffuse:
                        continue
                    # without the diffusion stage phid and flux have no rows: row 0's views are made, never read
                    ld = l if has_diffuse else 0
                    for c in range(n_ch):
                        if walk:
                            walk_terms(phi[l, c, i, j, k0:k1], phia[l, c, i, j, k0:k1], direct[l, c, i, j, k0:k1],
                                       (direction[l, 0], direction[l, 1], direction[l, 2]), view[:, :n], g,
                                       g_const, unscattered[l], terms)
                        else:
                            terms[:n] = 0.0
                        if has_diffuse:
                            diffuse_terms(phid[ld, c, i, j, k0:k1], flux[ld, c, 0, i, j, k0:k1],
                                          flux[ld, c, 1, i, j, k0:k1], flux[ld, c, 2, i, j, k0:k1], lobe_cap[l],
                                          view[:, :n], g, g_const, terms)
                        # the RGB power this channel lights (a grey field's one channel lights all three)
                        p0 = power[l, 0] if n_ch == 1 or c == 0 else 0.0
                        p1 = power[l, 1] if n_ch == 1 or c == 1 else 0.0
                        p2 = power[l, 2] if n_ch == 1 or c == 2 else 0.0
                        for k in range(n):
                            if needed[i, j, k0 + k]:
                                out[i, j, k0 + k, 0] += terms[k] * p0
                                out[i, j, k0 + k, 1] += terms[k] * p1
                                out[i, j, k0 + k, 2] += terms[k] * p2


@nb.njit(inline="always", fastmath=True, cache=True)
def view_directions(offset, hz, view):
    """The camera ray's direction d = (x - eye) / |x - eye| at the voxel centres x of a run
    along z, into view float64 (3, n): ``offset`` the first centre less the eye (3 floats), hz
    the voxel's size along z."""
    ex, ey, ez = offset
    for k in range(view.shape[1]):
        dz = ez + k * hz
        inv_r = 1.0 / max(math.sqrt(ex * ex + ey * ey + dz * dz), 1e-300)
        view[0, k] = ex * inv_r
        view[1, k] = ey * inv_r
        view[2, k] = dz * inv_r


@nb.njit(inline="always", fastmath=True, cache=True)
def walk_terms(phi, phia, direct, sun, view, g, g_const, unscattered, terms):
    """terms[k] = render.walk_lobes of the run's fields (float32 (n,)) toward the camera
    (``view`` from :func:`view_directions`; ``sun`` the light's direction of travel), per unit
    power; g: the run's anisotropy (n,), or its one value with ``g_const``. A light without an
    ``unscattered`` part has its one lobe (render.rest_lobe: the same values), ``direct`` not read."""
    s0, s1, s2 = sun
    gc = g[0]
    n = phi.shape[0]
    if unscattered and g_const:     # a loop per case: no branch in any
        for k in range(n):
            terms[k] = walk_lobes(phi[k], phia[k], direct[k], -(s0 * view[0, k] + s1 * view[1, k] + s2 * view[2, k]), gc)
    elif unscattered:
        for k in range(n):
            terms[k] = walk_lobes(phi[k], phia[k], direct[k], -(s0 * view[0, k] + s1 * view[1, k] + s2 * view[2, k]), g[k])
    elif g_const:
        for k in range(n):
            terms[k] = rest_lobe(phi[k], phia[k], -(s0 * view[0, k] + s1 * view[1, k] + s2 * view[2, k]), gc)
    else:
        for k in range(n):
            terms[k] = rest_lobe(phi[k], phia[k], -(s0 * view[0, k] + s1 * view[1, k] + s2 * view[2, k]), g[k])


@nb.njit(inline="always", fastmath=True, cache=True)
def diffuse_terms(phid, jx, jy, jz, cap, view, g, g_const, terms):
    """terms[k] += render.lobe_toward of the run's diffuse fluence and flux (float32 (n,)) toward
    the camera, per unit power; cap: the light's largest diffuse anisotropy; view, g, g_const:
    as :func:`walk_terms`'s."""
    if g_const:
        gc = g[0]
        for k in range(phid.shape[0]):
            terms[k] += lobe_toward(phid[k], jx[k], jy[k], jz[k], view[0, k], view[1, k], view[2, k], gc, cap)
    else:
        for k in range(phid.shape[0]):
            terms[k] += lobe_toward(phid[k], jx[k], jy[k], jz[k], view[0, k], view[1, k], view[2, k], g[k], cap)


@nb.njit(inline="always", cache=True)
def _needed_run(needed, i, j):
    """(the first k where needed[i, j, k], one past the last): an empty range if there is none."""
    nz = needed.shape[2]
    k0 = 0
    while k0 < nz and not needed[i, j, k0]:
        k0 += 1
    k1 = nz
    while k1 > k0 and not needed[i, j, k1 - 1]:
        k1 -= 1
    return k0, k1
