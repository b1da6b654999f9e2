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

from .render import light_in_scattering


@nb.njit(parallel=True, fastmath=True, cache=True)
def in_scattering_source(medium, lights, grid, spherical, eye, needed, out):
    """Add to ``out`` float32 (nx, ny, nz, 3) at the voxels where ``needed`` (bool (nx, ny, nz))
    L_s / sigma_s toward the camera at ``eye`` (float64 (3,)) of every term lit on the medium's
    grid (module docstring); other voxels are not touched (allocate ``out`` with zeros, or pass
    a source to add to). medium, lights, grid, spherical: the render kernel's bundles
    (render_kernel); the voxel's own g is the phase's anisotropy."""
    density, scale, albedo, albedo_rgb, g_grid, origin, voxel, lo, hi, blocks, block = medium
    is_point, direction, power, position = lights
    phi, phia, direct, phid, flux, lobe_cap = grid
    fields, offset, shape, params, frame, full = spherical
    nx, ny, nz = needed.shape
    has_diffuse = phid.shape[0] > 0
    for i in nb.prange(nx):
        lights_ = (is_point, direction, power, position)
        grid_ = (phi, phia, direct, phid, flux, lobe_cap)
        spherical_ = (fields, offset, shape, params, frame, full)
        for j in range(ny):
            for k in range(nz):
                if not needed[i, j, k]:
                    continue
                x = (origin[0] + i * voxel[0], origin[1] + j * voxel[1], origin[2] + k * voxel[2])
                dx = x[0] - eye[0]
                dy = x[1] - eye[1]
                dz = x[2] - eye[2]
                r = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
                d = (dx / r, dy / r, dz / r)
                g = g_grid[0, 0, 0] if g_grid.size == 1 else g_grid[i, j, k]
                corners = (i, i, j, j, k, k, 0.0, 0.0, 0.0)     # the voxel itself
                s0 = s1 = s2 = 0.0
                for l in range(is_point.shape[0]):
                    point = is_point[l]
                    if point and not has_diffuse:
                        continue
                    e0, e1, e2 = light_in_scattering(lights_, grid_, spherical_, l, corners, x, d, g,
                                                     not point, True)
                    s0 += e0
                    s1 += e1
                    s2 += e2
                out[i, j, k, 0] += s0
                out[i, j, k, 1] += s1
                out[i, j, k, 2] += s2
