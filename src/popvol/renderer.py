"""Render an image of a solved scene by ray marching (see kernels/render.py for the equations)."""
from __future__ import annotations


import numba
import numpy as np

from .errors import PopvolError
from .kernels.gather import gathered_source
from .kernels.render import render_kernel
from .kernels.source import in_scattering_source
from .pipeline import solve, voxels_seen
from .results import Solution
from .scene import Scene


#: voxels per edge of a block of the coarse occupancy grid (empty-space skipping)
BLOCK = 8
#: samples nearer the camera than this many (smallest) voxels are lit light by light, not from
#: the combined source: there the view direction turns by more than 1/32 rad across a voxel
NEAR_VOXELS = 32.0
#: combined = None chooses the combined source when pixels x spp x lights lit from the grid is
#: at least the voxels it is built on / COMBINED_VOXELS_PER_SAMPLE: building it costs about
#: one sample's per-light lighting per 8 voxels (measured: WDAS + sun, 640x360: 0.17 s combined
#: against 0.21 s light by light; the viewer's 160x90 drafts of it are faster light by light)
COMBINED_VOXELS_PER_SAMPLE = 8


def render(scene: Scene, solution: Solution | None = None, jitter: bool = True,
           combined: bool | None = None, skip: bool = True) -> np.ndarray:
    """Linear HDR image float32 (height, width, 3) of ``scene``.

    ``solution`` is the output of :func:`popvol.solve`; if omitted the scene is solved first.
    Moving only the camera does not need a new solution. ``combined``: light the samples from
    one in-scattering source built for this view (kernels/source.py), else light by light
    (None: whichever costs less, by COMBINED_VOXELS_PER_SAMPLE; the images differ by relMSE
    <= 1e-4, docs/METHOD.md); ``skip``: jump over empty blocks of the medium (the image is bitwise the same).
    With ``method.gather`` > 0 the combined source is always used (it holds the gathered light).
    """
    if solution is None:
        solution = solve(scene)
    cam = scene.camera
    out = np.zeros((cam.height, cam.width, 3), np.float32)
    inputs = render_inputs(scene, solution, jitter, combined, skip)
    # rows go to threads one at a time: rows through the medium cost far more than the sky's
    with numba.parallel_chunksize(1):
        render_kernel(*inputs, out)
    if not np.all(np.isfinite(out)):
        raise PopvolError("internal error: the rendered image has non-finite pixels; please report it "
                          f"with the scene ({scene.source})")
    return out


def render_inputs(scene: Scene, solution: Solution, jitter: bool = True, combined: bool | None = None,
                  skip: bool = True) -> tuple:
    """The render kernel's inputs but the image, packed as it takes them (kernels/render.py):
    (medium, lights, grid, spherical, view, camera, march, background). The one place that
    packs the scene and the solution's fields for the kernel; with ``combined`` it builds the
    view's combined in-scattering source (so its cost is part of rendering), with ``skip`` the
    coarse occupancy grid."""
    med = scene.medium
    cam = scene.camera
    m = scene.method
    lo, hi = med.bounds
    # grey per-voxel albedo, or an RGB constant as a (1, 1, 1) grid of 1 times albedo_rgb
    albedo, albedo_rgb = ((med.albedo, np.ones(3)) if med.albedo_per_voxel
                          else (np.ones((1, 1, 1), np.float32), np.asarray(med.albedo, np.float64)))
    seen = voxels_seen(med.density)
    blocks = occupied_blocks(seen, BLOCK) if skip else np.zeros((0, 0, 0), bool)
    medium = (med.density, np.asarray(med.scale, np.float64), albedo, albedo_rgb, med.g_grid(),
              med.origin, med.voxel_size, lo, hi, blocks, BLOCK)
    lights = (solution.is_point, np.ascontiguousarray(solution.directions, np.float64),
              np.ascontiguousarray(solution.irradiance, np.float64),
              np.ascontiguousarray(solution.positions, np.float64))
    camera = (cam.origin, cam.basis(), float(np.tan(np.radians(cam.fov) / 2)), int(cam.width),
              int(cam.height))
    if m.gather > 0:
        # the scattered light toward the camera gathered on the grid; the samples add the
        # single scattering (docs/METHOD.md, "Gathered last bounce")
        gathered = gather(medium, lights, field_bundles(solution), np.asarray(cam.origin, np.float64), seen,
                          m.gather)
        solution = solution.single_scattering()
        combined = True
    grid, spherical = field_bundles(solution)
    source = np.zeros((0, 0, 0, 3), np.float32)
    grid_lit = int((~solution.is_point).sum()) + (len(solution.is_point) if solution.phid.shape[0] > 0 else 0)
    if combined is None:
        samples = cam.width * cam.height * m.spp * grid_lit
        combined = samples * COMBINED_VOXELS_PER_SAMPLE >= int(seen.sum())
    if combined and grid_lit > 0:
        source = np.zeros(med.density.shape + (3,), np.float32)
        in_scattering_source(medium, lights, grid, spherical, np.asarray(cam.origin, np.float64),
                             seen, source)
    near = float(NEAR_VOXELS * med.voxel_size.min())
    if m.gather > 0:
        source = source + gathered if source.size else gathered
        near = 0.0                        # every sample reads the gathered light from the grid
    view = (source, near)
    march = (float(m.step * med.voxel_size.min()), int(m.spp), int(m.seed), bool(jitter))
    return medium, lights, grid, spherical, view, camera, march, background_map(scene)


def field_bundles(solution: Solution) -> tuple[tuple, tuple]:
    """The solution's fields as the kernels take them: (grid, spherical) (kernels/render.py)."""
    grid = (solution.phi, solution.phia, solution.direct, solution.phid, solution.flux,
            np.ascontiguousarray(solution.lobe_cap, np.float64))
    pts = solution.points
    return grid, (pts.fields, pts.offset, pts.shape, pts.params, pts.frame, pts.full)


def gather_directions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n unit directions on a Fibonacci sphere (float64 (n, 3)) and equal weights 4 pi / n."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], 1), np.full(n, 4.0 * np.pi / n)


def gather(medium, lights, bundles, eye, seen, n_directions: int) -> np.ndarray:
    """float32 (nx, ny, nz, 3): the scattered light gathered toward the camera at ``eye`` from
    ``n_directions`` directions (kernels/gather.py), where ``seen``; 0 elsewhere."""
    grid, spherical = bundles
    dirs, weights = gather_directions(n_directions)
    out = np.zeros(seen.shape + (3,), np.float32)
    norm = np.zeros(seen.shape, np.float64)
    gathered_source(medium, lights, grid, spherical, eye, seen, dirs, weights, out, norm)
    return (out / np.where(norm > 0, norm, 1.0)[..., None]).astype(np.float32)


def occupied_blocks(seen: np.ndarray, block: int) -> np.ndarray:
    """bool (ceil(nx / block), ...): whether block b (voxels [block b, block (b + 1)) along each
    axis) has density > 0 within one voxel of it, from ``seen`` = pipeline.voxels_seen(density).
    Where not, the density's trilinear value is 0 at every point whose clamped cell index lies
    in the block, with a voxel to spare (the stencil of such a point reads voxels
    [block b, block (b + 1)] only)."""
    m = seen
    for axis in range(3):             # any over voxels [block b, block (b + 1)], inclusive
        n = m.shape[axis]
        parts = [np.take(m, np.arange(b, min(b + block + 1, n)), axis=axis).any(axis=axis, keepdims=True)
                 for b in range(0, n, block)]
        m = np.concatenate(parts, axis=axis)
    return np.ascontiguousarray(m)


def background_map(scene: Scene) -> np.ndarray:
    """float32 (1, 1, 3) constant background, or the environment map (H, 2H, 3)."""
    if scene.environment is not None:
        return scene.environment.radiance
    return np.asarray(scene.background, np.float32).reshape(1, 1, 3)
