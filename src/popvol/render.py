"""Render an image of a solved scene by ray marching (see kernels/render.py for the equations)."""
from __future__ import annotations

import time

import numba
import numpy as np

from .errors import PopvolError
from .kernels.render import render_kernel
from .propagate import Solution, solve
from .scene import Scene
from .spherical import no_point_fields


def render(scene: Scene, solution: Solution | None = None, jitter: bool = True) -> np.ndarray:
    """Linear HDR image float32 (height, width, 3) of ``scene``.

    ``solution`` is the output of :func:`popvol.solve`; if omitted the scene is solved first.
    Moving only the camera does not need a new solution.
    """
    if solution is None:
        solution = solve(scene)
    med = scene.medium
    cam = scene.camera
    m = scene.method
    lo, hi = med.bounds
    step = float(m.step * med.voxel_size.min())
    out = np.zeros((cam.height, cam.width, 3), np.float32)
    # grey per-voxel albedo, or an RGB constant as a (1, 1, 1) grid of 1 times albedo_rgb
    albedo, albedo_rgb = ((med.albedo, np.ones(3)) if med.albedo_per_voxel
                          else (np.ones((1, 1, 1), np.float32), np.asarray(med.albedo, np.float64)))
    pts = solution.points or no_point_fields(len(solution.directions), solution.phi.shape[1])
    # rows go to threads one at a time: rows through the medium cost far more than the sky's
    with numba.parallel_chunksize(1):
        render_kernel(med.density, np.asarray(med.scale, np.float64), albedo, albedo_rgb, med.g_grid(),
                      med.origin, med.voxel_size, lo, hi, solution.phi, solution.phia, solution.direct,
                      solution.phid, solution.flux,
                      np.ascontiguousarray(solution.directions, np.float64),
                      np.ascontiguousarray(solution.irradiance, np.float64),
                      np.ascontiguousarray(solution.positions, np.float64), solution.is_point,
                      pts.fields, pts.offset, pts.shape, pts.params, pts.frame, pts.full,
                      background_map(scene), cam.origin, cam.basis(),
                      float(np.tan(np.radians(cam.fov) / 2)), cam.width, cam.height, step, m.spp,
                      m.seed, jitter, out)
    if not np.all(np.isfinite(out)):
        raise PopvolError("internal error: the rendered image has non-finite pixels; please report it "
                          f"with the scene ({scene.source})")
    return out


def background_map(scene: Scene) -> np.ndarray:
    """float32 (1, 1, 3) constant background, or the environment map (H, 2H, 3)."""
    if scene.environment is not None:
        return scene.environment.radiance
    return np.asarray(scene.background, np.float32).reshape(1, 1, 3)


def render_timed(scene: Scene) -> tuple[np.ndarray, Solution, dict]:
    """Solve and render; returns (image, solution, seconds per stage)."""
    solution = solve(scene)
    t0 = time.perf_counter()
    img = render(scene, solution)
    seconds = dict(solution.seconds)
    seconds["render"] = time.perf_counter() - t0
    return img, solution, seconds
