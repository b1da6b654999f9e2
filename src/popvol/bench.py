"""``popvol bench``: throughput figures, measured in one run so their ratios are meaningful.

- propagation: cell updates per second of each solver on the demo cloud's light domain at
  64^3 and 128^3 (a fixed number of iterations, after a warm-up that compiles the kernels),
  and the same for a streaming kernel with the sweep's memory traffic but no arithmetic: the
  ratio sweep / stream says how close the solver is to this machine's memory bandwidth;
- render: camera samples (pixels x spp) per second at 640x360, on the same n^3 demo clouds;
- end to end: the demo scene (load, propagate, render) and, if ../shared data is present, the
  WDAS cloud lit by the sun (examples/wdas_sun.toml).
"""
from __future__ import annotations

import copy
import os
import platform
import statistics
import time
from pathlib import Path

import numba as nb
import numpy as np

from .domains import directional_domain, resample_medium
from .pipeline import solve
from .walk import medium_factors, walk_box
from .renderer import render
from .scene import DEMO_SCENE, load_scene, scene_from_dict

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@nb.njit(parallel=True, fastmath=True, cache=True)
def _stream(R, Ra, Th, Dh, phi, phia):
    """Same loads and stores per cell as a forward sweep, no physics: the bandwidth bound."""
    n0, n1, n2 = R.shape
    for k in range(n0 - 1):
        for i in nb.prange(n1):
            for j in range(n2):
                w = R[k, i, j]
                phi[k, i, j] += w
                phia[k, i, j] += Ra[k, i, j]
                t = Th[k, i, j] * Th[k + 1, i, j]
                R[k + 1, i, j] += 0.5 * w * t
                Ra[k + 1, i, j] += 0.5 * w * t * Dh[k, i, j] * Dh[k + 1, i, j]


def _time(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_propagation(resolution: int, repeat: int, width=640, height=360) -> dict:
    """The demo cloud as an n^3 problem: procedural medium with n voxels across, light domain of
    n cells along its longest side; propagation and render throughput."""
    data = copy.deepcopy(DEMO_SCENE)
    data["medium"]["resolution"] = resolution
    data["method"]["resolution"] = resolution
    data["camera"].update(width=width, height=height)
    scene = scene_from_dict(data, source=f"<demo cloud at {resolution}^3>")
    light = scene.lights[0]
    dom = directional_domain(scene.medium, light.direction, resolution)
    sigma_t, sigma_s, g = resample_medium(scene.medium, dom)
    Th, Dh = medium_factors(sigma_t, sigma_s, g, dom.h, scene.method.decay)
    inj = np.full(dom.shape[1:], dom.h ** 2, np.float32)
    out = {"resolution": resolution, "shape": list(dom.shape), "cells": dom.n_cells}
    for solver, iters in (("sweep", 8), ("jacobi", 8)):
        run = lambda: walk_box(Th, Dh, inj, 1.0, dom.h, solver=solver, tolerance=1e-30, max_iterations=iters)
        walk_box(Th, Dh, inj, 1.0, dom.h, solver=solver, tolerance=1e-30, max_iterations=2)  # compile
        t = _time(run, repeat)
        out[f"{solver}_cell_updates_per_s"] = iters * dom.n_cells / t
    R = np.random.default_rng(0).random(dom.shape, dtype=np.float32)
    arrays = (R, R * 0.5, Th, Dh, np.zeros_like(R), np.zeros_like(R))
    _stream(*arrays)
    t = _time(lambda: _stream(*arrays), repeat)
    out["stream_cells_per_s"] = dom.n_cells / t
    out["sweep_over_stream"] = out["sweep_cell_updates_per_s"] / out["stream_cells_per_s"]
    out["sweep_over_jacobi"] = out["sweep_cell_updates_per_s"] / out["jacobi_cell_updates_per_s"]
    solution = solve(scene)
    render(scene, solution)                                   # compile
    t = _time(lambda: render(scene, solution), repeat)
    out["medium_shape"] = list(scene.medium.shape)
    out["render_pixels"] = [width, height]
    out["render_camera_samples_per_s"] = width * height * scene.method.spp / t
    return out


def bench_scene(scene_path, repeat: int, width=640, height=360, overrides=None) -> dict:
    scene = load_scene(scene_path, width=width, height=height, **(overrides or {}))
    solution = solve(scene)                     # warm-up (compilation, caches)
    render(scene, solution)
    t_solve = []
    t_render = []
    stages = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        solution = solve(scene)
        t1 = time.perf_counter()
        render(scene, solution)
        t_solve.append(t1 - t0)
        t_render.append(time.perf_counter() - t1)
        stages.append(solution.seconds)
    d = solution.domains[0]
    m = scene.method
    return {"scene": str(scene_path or "<demo>"), "method": f"{m.rule} + {m.decay} + {m.isotropic}",
            "domain_shape": list(d.domain.shape),
            "iterations": d.result.iterations, "residual": d.result.residual,
            "diffusion_iterations": d.result.diffusion.iterations if d.result.diffusion else 0,
            "solve_stages_s": {k: statistics.median(st[k] for st in stages) for k in stages[0]},
            "solve_s": statistics.median(t_solve), "render_s": statistics.median(t_render),
            "total_s": statistics.median(np.add(t_solve, t_render)),
            "camera_samples_per_s": width * height * scene.method.spp / statistics.median(t_render)}


def run_benchmarks(quick: bool = False, echo=print) -> dict:
    repeat = 1 if quick else 3
    res = {"machine": {"cpus": os.cpu_count(), "numba_threads": nb.get_num_threads(),
                       "python": platform.python_version(), "numpy": np.__version__,
                       "numba": nb.__version__}}
    res["propagation"] = []
    for n in ((32,) if quick else (64, 128)):
        echo(f"propagation throughput at {n}^3 ...")
        res["propagation"].append(bench_propagation(n, repeat))
    echo("demo scene end to end ...")
    res["demo"] = bench_scene(None, repeat, *((160, 90) if quick else (640, 360)))
    wdas = EXAMPLES / "wdas_sun.toml"
    data = EXAMPLES.parent.parent / "shared" / "data" / "volumes" / "npz" / "wdas_cloud_sixteenth_dense.npz"
    if not quick and wdas.exists() and data.exists():
        echo("WDAS cloud under the sun (128 cells, 640x360) ...")
        res["wdas_sun"] = bench_scene(wdas, repeat)
        res["wdas_sun"]["target_total_s"] = 1.0
        echo("WDAS cloud, the walk alone (isotropic = walk) ...")
        res["wdas_sun_walk"] = bench_scene(wdas, repeat, overrides={"isotropic": "walk"})
    else:
        res["wdas_sun"] = {"skipped": "quick mode" if quick else f"{data} not found"}
    return res
