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

from .render import lobe_toward, walk_lobes


@nb.njit(parallel=True, fastmath=True, cache=True)
def in_scattering_source(medium, lights, grid, spherical, eye, needed, out):
    """Add to ``out`` float32 (nx, ny, nz, 3) at the voxels where ``needed`` (bool (nx, ny, nz))
    L_s / sigma_s toward the camera at ``eye`` (float64 (3,)) of every term lit on the medium's
    grid (module docstring); other voxels are not touched (allocate ``out`` with zeros, or pass
    a source to add to). medium, lights, grid, spherical: the render kernel's bundles
    (render_kernel); the voxel's own g is the phase's anisotropy.

    One light and channel at a time along a row of voxels (i, j), so that the inner loop reads
    the fields in order and its lobes (render.walk_lobes, render.lobe_toward) have no branches:
    consecutive voxels overlap in the pipeline. The view direction is recomputed per light,
    which costs less than keeping the row's directions in a buffer."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block = medium
    is_point, direction, power, position, unscattered = lights
    phi, phia, direct, phid, flux, lobe_cap = grid
    nx, ny, nz = needed.shape
    n_ch = phi.shape[1]
    has_diffuse = phid.shape[0] > 0
    for i in nb.prange(nx):
        for j in range(ny):
            k0, k1 = _needed_run(needed, i, j)
            for l in range(is_point.shape[0]):
                walk = not is_point[l]          # a point light's walk lobes are lit per sample
                if not walk and not has_diffuse:
                    continue
                for c in range(n_ch):
                    # the RGB power this channel lights (a grey field's one channel lights all three)
                    p0 = power[l, 0] if n_ch == 1 or c == 0 else 0.0
                    p1 = power[l, 1] if n_ch == 1 or c == 1 else 0.0
                    p2 = power[l, 2] if n_ch == 1 or c == 2 else 0.0
                    for k in range(k0, k1):
                        if not needed[i, j, k]:
                            continue
                        dx = origin[0] + i * voxel[0] - eye[0]
                        dy = origin[1] + j * voxel[1] - eye[1]
                        dz = origin[2] + k * voxel[2] - eye[2]
                        inv_r = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
                        d0, d1, d2 = dx * inv_r, dy * inv_r, dz * inv_r
                        g = g_grid[0, 0, 0] if g_grid.size == 1 else g_grid[i, j, k]
                        v = 0.0
                        if walk:
                            mu = -(direction[l, 0] * d0 + direction[l, 1] * d1 + direction[l, 2] * d2)
                            v = walk_lobes(phi[l, c, i, j, k], phia[l, c, i, j, k], direct[l, c, i, j, k], mu, g)
                        if has_diffuse:
                            v += lobe_toward(phid[l, c, i, j, k], flux[l, c, 0, i, j, k], flux[l, c, 1, i, j, k],
                                             flux[l, c, 2, i, j, k], d0, d1, d2, g, lobe_cap[l])
                        out[i, j, k, 0] += v * p0
                        out[i, j, k, 1] += v * p1
                        out[i, j, k, 2] += v * p2


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
