"""Render an image of a solved scene by ray marching (see kernels/render.py for the equations)."""
from __future__ import annotations


import numba
import numpy as np

from .errors import PopvolError
from .kernels.render import render_kernel
from .pipeline import solve
from .results import Solution
from .scene import Scene


def render(scene: Scene, solution: Solution | None = None, jitter: bool = True) -> np.ndarray:
    """Linear HDR image float32 (height, width, 3) of ``scene``.

    ``solution`` is the output of :func:`popvol.solve`; if omitted the scene is solved first.
    Moving only the camera does not need a new solution.
    """
    if solution is None:
        solution = solve(scene)
    cam = scene.camera
    out = np.zeros((cam.height, cam.width, 3), np.float32)
    # rows go to threads one at a time: rows through the medium cost far more than the sky's
    with numba.parallel_chunksize(1):
        render_kernel(*render_inputs(scene, solution, jitter), out)
    if not np.all(np.isfinite(out)):
        raise PopvolError("internal error: the rendered image has non-finite pixels; please report it "
                          f"with the scene ({scene.source})")
    return out


def render_inputs(scene: Scene, solution: Solution, jitter: bool = True) -> tuple:
    """The render kernel's inputs but the image, packed as it takes them (kernels/render.py):
    (medium, lights, grid, spherical, camera, march, background). The one place that packs
    the scene and the solution's fields for the kernel."""
    med = scene.medium
    cam = scene.camera
    m = scene.method
    lo, hi = med.bounds
    # grey per-voxel albedo, or an RGB constant as a (1, 1, 1) grid of 1 times albedo_rgb
    albedo, albedo_rgb = ((med.albedo, np.ones(3)) if med.albedo_per_voxel
                          else (np.ones((1, 1, 1), np.float32), np.asarray(med.albedo, np.float64)))
    medium = (med.density, np.asarray(med.scale, np.float64), albedo, albedo_rgb, med.g_grid(),
              med.origin, med.voxel_size, lo, hi)
    lights = (solution.is_point, np.ascontiguousarray(solution.directions, np.float64),
              np.ascontiguousarray(solution.irradiance, np.float64),
              np.ascontiguousarray(solution.positions, np.float64))
    grid = (solution.phi, solution.phia, solution.direct, solution.phid, solution.flux)
    pts = solution.points
    spherical = (pts.fields, pts.offset, pts.shape, pts.params, pts.frame, pts.full)
    camera = (cam.origin, cam.basis(), float(np.tan(np.radians(cam.fov) / 2)), int(cam.width),
              int(cam.height))
    march = (float(m.step * med.voxel_size.min()), int(m.spp), int(m.seed), bool(jitter))
    return medium, lights, grid, spherical, camera, march, background_map(scene)


def background_map(scene: Scene) -> np.ndarray:
    """float32 (1, 1, 3) constant background, or the environment map (H, 2H, 3)."""
    if scene.environment is not None:
        return scene.environment.radiance
    return np.asarray(scene.background, np.float32).reshape(1, 1, 3)
