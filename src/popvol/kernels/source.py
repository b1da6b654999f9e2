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

from .render import lobe_toward, walk_lobes


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def in_scattering_source(medium, lights, grid, spherical, eye, needed, out):
    """Add to ``out`` float32 (nx, ny, nz, 3) at the voxels where ``needed`` (bool (nx, ny, nz))
    L_s / sigma_s toward the camera at ``eye`` (float64 (3,)) of every term lit on the medium's
    grid (module docstring); other voxels are not touched (allocate ``out`` with zeros, or pass
    a source to add to). medium, lights, grid, spherical: the render kernel's bundles
    (render_kernel); the voxel's own g is the phase's anisotropy.

    One light and channel at a time along a row of voxels (i, j), from its first needed voxel
    to its last: :func:`row_terms` lights the whole run into a buffer with one branchless
    loop, which the compiler vectorises (about 1.8x faster on the WDAS cloud than testing
    each voxel), and only the needed voxels are added to ``out``."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block_bits = medium
    is_point, direction, power, position, unscattered = lights
    phi, phia, direct, phid, flux, lobe_cap = grid
    nx, ny, nz = needed.shape
    n_ch = phi.shape[1]
    has_diffuse = phid.shape[0] > 0
    g_const = g_grid.size == 1
    for i in nb.prange(nx):
        terms = np.empty(nz)
        for j in range(ny):
            k0, k1 = _needed_run(needed, i, j)
            if k1 <= k0:
                continue
            # the row's g: the constant's one value, or the grid's run
            g = g_grid[0, 0, 0:1] if g_const else g_grid[i, j, k0:k1]
            # the run's voxel centres less the eye along x and y (along z: row_terms)
            ex = origin[0] + i * voxel[0] - eye[0]
            ey = origin[1] + j * voxel[1] - eye[1]
            for l in range(is_point.shape[0]):
                walk = not is_point[l]          # a point light's walk lobes are lit per sample
                if not walk and not has_diffuse:
                    continue
                # without the diffusion stage phid and flux have no rows: row 0's views are made, never read
                ld = l if has_diffuse else 0
                for c in range(n_ch):
                    row_terms(phi[l, c, i, j, k0:k1], phia[l, c, i, j, k0:k1], direct[l, c, i, j, k0:k1],
                              phid[ld, c, i, j, k0:k1], flux[ld, c, 0, i, j, k0:k1], flux[ld, c, 1, i, j, k0:k1],
                              flux[ld, c, 2, i, j, k0:k1], g, g_const, (ex, ey, origin[2], voxel[2], eye[2], k0),
                              (direction[l, 0], direction[l, 1], direction[l, 2]), lobe_cap[l], walk,
                              has_diffuse, terms)
                    # the RGB power this channel lights (a grey field's one channel lights all three)
                    p0 = power[l, 0] if n_ch == 1 or c == 0 else 0.0
                    p1 = power[l, 1] if n_ch == 1 or c == 1 else 0.0
                    p2 = power[l, 2] if n_ch == 1 or c == 2 else 0.0
                    for k in range(k1 - k0):
                        if needed[i, j, k0 + k]:
                            out[i, j, k0 + k, 0] += terms[k] * p0
                            out[i, j, k0 + k, 1] += terms[k] * p1
                            out[i, j, k0 + k, 2] += terms[k] * p2


@nb.njit(inline="always", fastmath=True, cache=True)
def row_terms(phi, phia, direct, phid, jx, jy, jz, g, g_const, eye_offset, sun, cap, walk, diffuse, terms):
    """One light's and channel's term of L_s / sigma_s per unit power (render.walk_lobes if
    ``walk``, plus render.lobe_toward if ``diffuse``) at the voxels k0 .. k0 + n - 1 of a row
    along z, into terms[:n] (float64). phi ... jz: the fields' float32 runs (n,); g: the
    run's g (n,), or its one value with ``g_const``; eye_offset: (ex, ey, oz, hz, eye_z, k0),
    the row's voxel centres less the eye along x and y, and along z the grid's origin, voxel
    size and the eye's coordinate (the centre's offset oz + k hz - eye_z); sun: the light's
    direction of travel; cap: its diffuse lobe's largest anisotropy. The same arithmetic as
    the render kernel's, without a branch per voxel."""
    ex, ey, oz, hz, eye_z, k0 = eye_offset
    s0, s1, s2 = sun
    for k in range(phi.shape[0]):
        dz = oz + (k0 + k) * hz - eye_z
        inv_r = 1.0 / max(math.sqrt(ex * ex + ey * ey + dz * dz), 1e-300)
        d0, d1, d2 = ex * inv_r, ey * inv_r, dz * inv_r
        gk = g[0] if g_const else g[k]
        v = 0.0
        if walk:
            mu = -(s0 * d0 + s1 * d1 + s2 * d2)
            v = walk_lobes(phi[k], phia[k], direct[k], mu, gk)
        if diffuse:
            v += lobe_toward(phid[k], jx[k], jy[k], jz[k], d0, d1, d2, gk, cap)
        terms[k] = v


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
