"""``popvol bench``: throughput figures, measured in one run so their ratios are meaningful.

Every figure is min / median / max over ``repeat`` runs (default 5) after a warm-up run that
compiles the kernels and fills the caches.

- propagation: cell updates per second of each solver on the demo cloud's light domain at
  64^3 and 128^3 (a fixed number of iterations), and of a streaming kernel with the sweep's
  loads and stores but no physics (:func:`_stream`): the ratio sweep / stream says how close the
  solver is to this machine's memory bandwidth; render throughput in camera samples
  (pixels x spp) per second at 640x360 on the same clouds (the ray march, without the gather);
- scenes, end to end, per stage (load, resample, propagate, diffusion, fields, render, total):
  the built-in demo, the WDAS cloud under the sun (default method, without the gathered last
  bounce, with six ordinates, with the one-lobe sweeps and their diffusion stage, and the
  one-lobe walk alone) and under sun + 8-direction sky, and the procedural field of small
  cumulus under the sun at 256 cells (with eighteen and six ordinates) and lit by a point light
  inside it at 128 and 256 cells (96x64); the render stage includes the gather. Beside them the
  sweeps' work rate per second of the propagate stage: with ordinates, packets sent (up to 18
  or 6 per cell and sweep; the tail's on wider cells included, walk.walk_the_tail); with one
  lobe, cells that sent a packet (the throughput rows count every cell a sweep visits, sending
  or not). The WDAS scenes ship with popvol
  (``popvol/bench_scenes``) and name their volume by file name only; it is looked up in the
  data folder (:func:`find_data`).
  A scene whose volume is missing or unreadable is reported as skipped, with the reason.
- peak memory of each row: the process's resident-set high-water mark (VmHWM) over the row's
  timed runs, reset before the row through ``/proc/self/clear_refs``; elsewhere than Linux,
  ``ru_maxrss``, the peak of the whole process so far.
- the machine: CPU model, logical CPUs, physical cores, Numba's threads and threading layer,
  versions, popvol's git commit when run from a checkout.
"""
from __future__ import annotations

import ctypes
import gc
import importlib.metadata
import importlib.resources
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numba as nb
import numpy as np

from .domains import directional_domain, resample_medium
from .errors import PopvolError
from .pipeline import solve
from .walk import medium_factors, walk_box
from .renderer import render
from .scene import DEMO_SCENE, apply_overrides, load_scene, scene_from_dict

#: The volume the WDAS bench scenes read, looked up in DIR and DIR/npz of the data folder.
WDAS_VOLUME = "wdas_cloud_sixteenth_dense.npz"
#: Bytes each streaming-kernel cell moves at the least: reads R, Ra, Th, Dh, phi, phia and
#: writes R, Ra, phi, phia (float32; the k+1 rows are read again from cache at the next k).
STREAM_BYTES_PER_CELL = 40
SCHEMA = 2

#: Rows of the scene table: name -> (packaged scene or None for the demo, overrides,
#: quick overrides, description).
SCENES = {
    "demo": (None, {}, {"width": 160, "height": 90, "resolution": 64},
             "built-in demo cloud under the sun"),
    "wdas_sun": ("wdas_sun.toml", {}, {"width": 160, "height": 90, "resolution": 64},
                 "WDAS cloud under the sun, default method"),
    "wdas_sun_lobes": ("wdas_sun.toml", {"gather": 0}, {"width": 160, "height": 90, "resolution": 64},
                       "WDAS cloud under the sun, without the gathered last bounce (gather = 0)"),
    "wdas_sun_sweep": ("wdas_sun.toml", {"solver": "sweep"}, {"width": 160, "height": 90, "resolution": 64},
                       "WDAS cloud under the sun, one-lobe sweeps with the diffusion stage (solver = sweep)"),
    "wdas_sun_walk": ("wdas_sun.toml", {"solver": "sweep", "isotropic": "walk"},
                      {"width": 160, "height": 90, "resolution": 64},
                      "WDAS cloud under the sun, the one-lobe walk alone (solver = sweep, isotropic = walk)"),
    "wdas_sun_6": ("wdas_sun.toml", {"ordinates": 6}, {"width": 160, "height": 90, "resolution": 64},
                   "WDAS cloud under the sun, six ordinates (ordinates = 6)"),
    "wdas_sun_sky": ("wdas_sun_sky.toml", {},
                     {"width": 160, "height": 90, "resolution": 64, "environment_resolution": 32},
                     "WDAS cloud under sun + 8-direction sky (9 domains)"),
    "field_sun_256": ("field_sun.toml", {"resolution": 256}, {"resolution": 48},
                      "procedural cumulus field under the sun at 256 cells"),
    "field_sun_256_6": ("field_sun.toml", {"resolution": 256, "ordinates": 6}, {"resolution": 48},
                        "procedural cumulus field under the sun at 256 cells, six ordinates"),
    "field_point": ("field_point.toml", {}, {"resolution": 32},
                    "procedural cumulus field lit by a point light inside it (full-sphere domain)"),
    "field_point_256": ("field_point.toml", {"resolution": 256}, {"resolution": 48},
                        "the same at 256 cells"),
}
#: per scene row: the solve's stages (summed over its light domains, which overlap where they
#: are solved side by side, pipeline.side_by_side), then the solve's own wall time, the render's
#: and the whole frame's
STAGES = ("load", "resample", "propagate", "diffusion", "fields", "solve", "render", "total")


# -- figures ------------------------------------------------------------------------------------

def spread(values) -> dict:
    """min / median / max (and n) of repeated measurements."""
    v = sorted(float(x) for x in values)
    return {"min": v[0], "median": statistics.median(v), "max": v[-1], "n": len(v)}


def _times(fn, repeat) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


# -- memory -------------------------------------------------------------------------------------

def _status_kb(key: str) -> int | None:
    try:
        m = re.search(rf"^{key}:\s+(\d+) kB", Path("/proc/self/status").read_text(), re.M)
    except OSError:
        return None
    return int(m.group(1)) if m else None


def _trim_heap() -> None:
    """Hand the C heap's free memory back to the system (glibc's malloc_trim; nothing elsewhere),
    so that a row's peak does not carry what earlier rows freed but the allocator kept (arenas
    of the threads that solved light domains side by side)."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _reset_peak() -> bool:
    """Reset this process's resident-set high-water mark (Linux >= 4.0); False if not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


class _Peak:
    """``with _Peak() as p: ...`` then p.figures(): the peak resident set over the block."""

    def __enter__(self):
        gc.collect()
        _trim_heap()
        self.per_row = _reset_peak()
        self.base = _status_kb("VmRSS")
        return self

    def __exit__(self, *exc):
        hwm = _status_kb("VmHWM") if self.per_row else None
        if hwm is None:
            hwm = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss    # kB on Linux
            if sys.platform == "darwin":
                hwm //= 1024
        self.peak = hwm

    def figures(self) -> dict:
        return {"peak_rss_mb": self.peak / 1024,
                "rss_base_mb": None if self.base is None else self.base / 1024}


MEMORY_METHOD = ("peak_rss_mb: the process's resident-set high-water mark (VmHWM) over the row's "
                 "timed runs, reset before the row (/proc/self/clear_refs) once the heap's free "
                 "memory is handed back (malloc_trim); it includes the interpreter, NumPy, Numba "
                 "and the compiled kernels, rss_base_mb at the reset")
MEMORY_FALLBACK = "peak_rss_mb: ru_maxrss, the peak of the whole process up to the row's end"


# -- the machine --------------------------------------------------------------------------------

def _cpu_info() -> tuple[str, int | None]:
    """CPU model name and physical core count from /proc/cpuinfo (platform's words elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine() or "unknown", None
    m = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    cores = set()
    for block in text.split("\n\n"):
        phys = re.search(r"^physical id\s*:\s*(\d+)", block, re.M)
        core = re.search(r"^core id\s*:\s*(\d+)", block, re.M)
        if phys and core:
            cores.add((phys.group(1), core.group(1)))
    return (m.group(1).strip() if m else platform.processor() or "unknown"), (len(cores) or None)


def _git_commit() -> dict:
    """popvol's commit when the package is the ``src/popvol`` of a git checkout, else unknown."""
    pkg = Path(__file__).resolve().parent
    repo = pkg.parents[1]
    if pkg != repo / "src" / "popvol" or not (repo / ".git").exists():
        return {"commit": "unknown", "dirty": None}
    try:
        commit = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return {"commit": "unknown", "dirty": None}
    return {"commit": commit or "unknown", "dirty": bool(dirty) if commit else None}


def machine() -> dict:
    model, cores = _cpu_info()
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        affinity = None
    try:
        version = importlib.metadata.version("popvol")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    git = _git_commit()
    return {"cpu_model": model, "cpus": os.cpu_count(), "physical_cores": cores,
            "cpus_usable": affinity, "numba_threads": nb.get_num_threads(),
            "numba_threading_layer": None,          # known once a parallel kernel ran
            "platform": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "numba": nb.__version__, "popvol": version,
            "popvol_commit": git["commit"], "popvol_dirty": git["dirty"],
            "popvol_path": str(Path(__file__).resolve().parent)}


# -- the data folder ----------------------------------------------------------------------------

def data_candidates(cwd: Path | None = None) -> list[tuple[Path, str]]:
    """Default data folders, in order: ../shared/data/volumes beside the current directory, the
    same from the current directory's parents' level (a checkout's subfolder), and beside
    popvol's own checkout when popvol runs from one."""
    cwd = Path.cwd() if cwd is None else Path(cwd)
    out = [(cwd / ".." / "shared" / "data" / "volumes", "../shared/data/volumes from the current directory"),
           (cwd / "shared" / "data" / "volumes", "shared/data/volumes in the current directory")]
    pkg = Path(__file__).resolve().parent
    if pkg.parent.name == "src" and (pkg.parents[1] / "pyproject.toml").exists():
        out.append((pkg.parents[2] / "shared" / "data" / "volumes", "../shared/data/volumes beside popvol's checkout"))
    return out


def find_data(data: str | Path | None = None, environ=None, cwd: Path | None = None) -> dict:
    """The data folder: ``data`` (--data), else $POPVOL_DATA, else the first of
    :func:`data_candidates` that exists. {"dir": str or None, "from": how it was chosen,
    "searched": [folders tried]}."""
    environ = os.environ if environ is None else environ
    if data is not None:
        return {"dir": str(Path(data).resolve()), "from": "--data", "searched": [str(data)]}
    if environ.get("POPVOL_DATA"):
        return {"dir": str(Path(environ["POPVOL_DATA"]).resolve()), "from": "POPVOL_DATA",
                "searched": [environ["POPVOL_DATA"]]}
    tried = []
    for path, how in data_candidates(cwd):
        tried.append(str(path.resolve()))
        if path.is_dir():
            return {"dir": str(path.resolve()), "from": how, "searched": tried}
    return {"dir": None, "from": None, "searched": tried}


def locate(name: str, data: dict) -> tuple[Path | None, str | None]:
    """(path of data file ``name``, None) or (None, why it is missing)."""
    if data["dir"] is None:
        return None, (f"{name}: no data folder (give --data DIR or set POPVOL_DATA; searched "
                      + ", ".join(data["searched"]) + ")")
    d = Path(data["dir"])
    if not d.is_dir():
        return None, f"{name}: data folder {d} ({data['from']}) is not a folder"
    from .io.files import why_not_file
    for p in (d / name, d / "npz" / name):
        if p.is_file():
            return p, None
        if p.is_symlink() or p.exists():           # there, but not a file it can read
            return None, f"{p} ({data['from']}) {why_not_file(p)}"
    return None, f"{name} not found in {d} or {d / 'npz'} ({data['from']})"


def bench_scene_text(name: str) -> str:
    return (importlib.resources.files("popvol") / "bench_scenes" / name).read_text()


def needs_volume(name: str) -> bool:
    """Whether packaged bench scene ``name`` reads its medium from a file (else procedural)."""
    return tomllib.loads(bench_scene_text(name))["medium"]["type"] == "file"


def load_bench_scene(name: str, volume: Path | None, **overrides):
    """A packaged bench scene, with its medium read from ``volume`` if it reads one."""
    doc = tomllib.loads(bench_scene_text(name))
    if volume is not None:
        doc["medium"]["file"] = str(volume)
    scene = scene_from_dict(doc, source=f"popvol/bench_scenes/{name}",
                            base_dir=volume.parent if volume is not None else ".")
    return apply_overrides(scene, **overrides) if overrides else scene


# -- the rows -----------------------------------------------------------------------------------

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



def bench_propagation(resolution: int, repeat: int, width=640, height=360) -> dict:
    """The demo cloud as an n^3 problem: procedural medium with n voxels across, light domain of
    n cells along its longest side; propagation, streaming and render throughput (the ray march's:
    gather = 0, since the gathered last bounce costs per frame, not per sample)."""
    data = {**DEMO_SCENE, "medium": {**DEMO_SCENE["medium"], "resolution": resolution},
            "method": {**DEMO_SCENE["method"], "resolution": resolution, "gather": 0},
            "camera": {**DEMO_SCENE["camera"], "width": width, "height": height}}
    scene = scene_from_dict(data, source=f"<demo cloud at {resolution}^3>")
    light = scene.lights[0]
    dom = directional_domain(scene.medium, light.direction, resolution, crop=False)   # the whole n^3 box
    sigma_t, sigma_s, g = resample_medium(scene.medium, dom)
    Th, Dh = medium_factors(sigma_t, sigma_s, g, dom.h, scene.method.decay)
    inj = np.full(dom.shape[1:], dom.h ** 2, np.float32)
    R = np.random.default_rng(0).random(dom.shape, dtype=np.float32)
    arrays = (R, R * 0.5, Th, Dh, np.zeros_like(R), np.zeros_like(R))
    solution = solve(scene)
    for solver in ("sweep", "jacobi"):                                        # compile
        walk_box(Th, Dh, inj, 1.0, dom.h, solver=solver, tolerance=1e-30, max_iterations=2)
    _stream(*arrays)
    render(scene, solution)
    out = {"resolution": resolution, "shape": list(dom.shape), "cells": dom.n_cells}
    iters = 8
    with _Peak() as peak:
        for solver in ("sweep", "jacobi"):
            t = _times(lambda: walk_box(Th, Dh, inj, 1.0, dom.h, solver=solver, tolerance=1e-30,
                                        max_iterations=iters), repeat)
            out[f"{solver}_cell_updates_per_s"] = spread(iters * dom.n_cells / x for x in t)
        t = _times(lambda: _stream(*arrays), repeat)
        out["stream_cells_per_s"] = spread(dom.n_cells / x for x in t)
        out["stream_bytes_per_s"] = spread(STREAM_BYTES_PER_CELL * dom.n_cells / x for x in t)
        t = _times(lambda: render(scene, solution), repeat)
        out["render_camera_samples_per_s"] = spread(width * height * scene.method.spp / x for x in t)
    med = lambda k: out[k]["median"]
    out["sweep_over_stream"] = med("sweep_cell_updates_per_s") / med("stream_cells_per_s")
    out["sweep_over_jacobi"] = med("sweep_cell_updates_per_s") / med("jacobi_cell_updates_per_s")
    out["iterations_per_run"] = iters
    out["medium_shape"] = list(scene.medium.shape)
    out["image"] = [width, height]
    out.update(peak.figures())
    return out


def bench_scene(load, repeat: int, source: str) -> dict:
    """End to end, per stage: ``load()`` gives the scene (timed as the load stage), then solve and
    render; a warm-up run first."""
    scene = load()
    solution = solve(scene)
    render(scene, solution)
    del solution
    stages = {k: [] for k in STAGES}
    sends = []                              # cells sent per second of the propagate stage
    with _Peak() as peak:
        for _ in range(repeat):
            t0 = time.perf_counter()
            scene = load()
            t1 = time.perf_counter()
            solution = solve(scene)
            t2 = time.perf_counter()
            render(scene, solution)
            t3 = time.perf_counter()
            stages["load"].append(t1 - t0)
            for k in ("resample", "propagate", "diffusion", "fields"):
                stages[k].append(solution.seconds[k])
            stages["solve"].append(t2 - t1)
            stages["render"].append(t3 - t2)
            stages["total"].append(t3 - t0)
            sent = sum(ds.result.cells_sent + (ds.result.tail.cells_sent if ds.result.tail else 0)
                       for ds in solution.domains)
            if sent:
                sends.append(sent / solution.seconds["propagate"])
    d = [ds.result for ds in solution.domains]
    m, cam = scene.method, scene.camera
    solver = f"{m.solver} ({m.ordinates})" if m.solver == "ordinates" else m.solver
    return {"scene": source, "method": f"{solver}: {m.rule} + {m.decay} + {m.isotropic}, gather {m.gather}",
            "image": [cam.width, cam.height], "resolution": m.resolution,
            "environment_resolution": m.environment_resolution,
            "domains": len(solution.domains), "domain_shape": list(solution.domains[0].domain.shape),
            "iterations": [r.iterations for r in d], "residual": max(r.residual for r in d),
            "cells_sent": [r.cells_sent for r in d],
            "tail_iterations": [r.tail.iterations if r.tail else 0 for r in d],
            "tail_cells_sent": [r.tail.cells_sent if r.tail else 0 for r in d],
            "cells_sent_per_s": spread(sends) if sends else None,
            "diffusion_iterations": [r.diffusion.iterations if r.diffusion else 0 for r in d],
            "seconds": {k: spread(v) for k, v in stages.items()},
            "camera_samples_per_s": spread(cam.width * cam.height * m.spp / x for x in stages["render"]),
            **peak.figures()}


def run_benchmarks(quick: bool = False, repeat: int | None = None, data: str | Path | None = None,
                   echo=print) -> dict:
    """Every row, in one process; see the module's docstring. ``quick``: 2 runs, 32^3
    propagation, scenes at 160x90 and 64 cells (a smoke test, not comparable figures)."""
    repeat = repeat or (2 if quick else 5)
    if repeat < 1:
        raise ValueError("repeat must be >= 1")
    res = {"schema": SCHEMA, "quick": quick, "repeat": repeat, "machine": machine(),
           "memory": MEMORY_METHOD if _reset_peak() else MEMORY_FALLBACK}
    if quick:
        res["note"] = ("--quick: 2 runs unless --repeat, propagation at 32^3, scenes at 160x90 with "
                       "64-cell domains (the sky's 32): a smoke test, not comparable with full figures")
    found = find_data(data)
    res["data"] = found
    echo(f"data folder: {found['dir'] or 'none found'}" + (f" ({found['from']})" if found["from"] else ""))
    res["propagation"] = []
    for n in ((32,) if quick else (64, 128)):
        echo(f"propagation throughput at {n}^3, {repeat} runs ...")
        res["propagation"].append(bench_propagation(n, repeat, *((160, 90) if quick else (640, 360))))
    res["scenes"] = {}
    for name, (toml, overrides, quick_overrides, what) in SCENES.items():
        ov = {**overrides, **(quick_overrides if quick else {})}
        if toml is None:
            load, source = (lambda ov=ov: load_scene(None, **ov)), "<demo scene>"
        elif not needs_volume(toml):
            load = lambda toml=toml, ov=ov: load_bench_scene(toml, None, **ov)
            source = f"popvol/bench_scenes/{toml}"
        else:
            volume, why = locate(WDAS_VOLUME, found)
            if volume is None:
                res["scenes"][name] = {"description": what, "skipped": why}
                echo(f"{name}: skipped: {why}")
                continue
            load = lambda toml=toml, volume=volume, ov=ov: load_bench_scene(toml, volume, **ov)
            source = f"popvol/bench_scenes/{toml} with {volume}"
        echo(f"{name}: {what}, {repeat} runs ...")
        if toml is not None and needs_volume(toml):
            try:                            # a volume that cannot be read skips its rows, as a missing one does
                load()
            except PopvolError as e:
                res["scenes"][name] = {"description": what, "skipped": str(e)}
                echo(f"{name}: skipped: {e}")
                continue
        row = {"description": what, **bench_scene(load, repeat, source)}
        if name == "wdas_sun" and not quick:
            row["target_total_s"] = 1.0
        res["scenes"][name] = row
    try:
        res["machine"]["numba_threading_layer"] = nb.threading_layer()
    except ValueError:
        pass
    return res


# -- the terminal -------------------------------------------------------------------------------

def _fmt(f: dict, scale=1.0, spec=".3g") -> str:
    return f"{f['median'] * scale:{spec}} ({f['min'] * scale:{spec}}-{f['max'] * scale:{spec}})"


def print_report(res: dict, console) -> None:
    """The figures as small tables (rich), one column per size or scene (at most five scenes a
    table): median (min-max) over the runs."""
    from rich.table import Table
    mc = res["machine"]
    cores = f", {mc['physical_cores']} cores" if mc["physical_cores"] else ""
    commit = mc["popvol_commit"][:10] + (" (uncommitted changes)" if mc["popvol_dirty"] else "")
    console.print(f"[bold]{mc['cpu_model']}[/]: {mc['cpus']} logical CPUs{cores}, Numba {mc['numba']} "
                  f"with {mc['numba_threads']} threads ({mc['numba_threading_layer'] or '?'}); "
                  f"Python {mc['python']}, NumPy {mc['numpy']}; popvol {mc['popvol']} {commit}")
    d = res["data"]
    console.print(f"data: {d['dir'] or 'none found'}" + (f" ({d['from']})" if d["from"] else ""))
    console.print(f"median (min-max) over {res['repeat']} runs"
                  + ("; --quick: small sizes, not comparable with full figures" if res["quick"] else ""))

    prop = res["propagation"]
    t = Table(title="throughput", title_justify="left")
    t.add_column("")
    for p in prop:
        t.add_column(f"{p['resolution']}^3", justify="right")
    for label, key, scale in (("sweep, M cell updates/s", "sweep_cell_updates_per_s", 1e-6),
                              ("jacobi, M cell updates/s", "jacobi_cell_updates_per_s", 1e-6),
                              ("stream, M cells/s", "stream_cells_per_s", 1e-6),
                              ("stream, GB/s", "stream_bytes_per_s", 1e-9),
                              ("render, M camera samples/s", "render_camera_samples_per_s", 1e-6)):
        t.add_row(label, *[_fmt(p[key], scale) for p in prop])
    t.add_row("sweep / stream (medians)", *[f"{p['sweep_over_stream']:.2f}" for p in prop])
    t.add_row("peak MB", *[f"{p['peak_rss_mb']:.0f}" for p in prop])
    console.print(t)

    measured = [(k, r) for k, r in res["scenes"].items() if "skipped" not in r]
    per_table = 5                    # scene columns per table, so that a terminal shows their names
    for start in range(0, len(measured), per_table):
        rows = dict(measured[start:start + per_table])
        t = Table(title="scenes end to end, seconds", title_justify="left")
        t.add_column("")
        for name in rows:
            t.add_column(name, justify="right")
        t.add_row("image, cells", *[f"{r['image'][0]}x{r['image'][1]}, {r['resolution']}"
                                    + (f" ({r['domains']} domains)" if r["domains"] > 1 else "")
                                    for r in rows.values()])
        for k in STAGES:
            t.add_row(k, *[_fmt(r["seconds"][k], spec=".2f") for r in rows.values()])
        t.add_row("sweeps (+ tail's)", *[f"{max(r['iterations'])}" + (f" (+{max(r['tail_iterations'])})"
                                                                     if max(r["tail_iterations"]) else "")
                                        for r in rows.values()])
        t.add_row("sweeps, M cells sent/s", *[_fmt(r["cells_sent_per_s"], 1e-6) if r["cells_sent_per_s"] else "-"
                                             for r in rows.values()])
        t.add_row("peak MB", *[f"{r['peak_rss_mb']:.0f}" for r in rows.values()])
        console.print(t)
    for name, row in res["scenes"].items():
        if "skipped" in row:
            console.print(f"[yellow]{name}: skipped: {row['skipped']}[/]", soft_wrap=True)
