"""`popvol bench` as installed: its scenes ship with the package, the volume comes from --data,
a missing volume is reported as skipped with the reason, every figure is min <= median <= max."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from popvol import bench

REPO = Path(__file__).resolve().parents[1]
SHARED_VOLUME = REPO.parent / "shared" / "data" / "volumes" / "npz" / bench.WDAS_VOLUME
WDAS_ROWS = ("wdas_sun", "wdas_sun_lobes", "wdas_sun_sweep", "wdas_sun_walk", "wdas_sun_6", "wdas_sun_sky")


def figures(node):
    """Every {"min", "median", "max", ...} figure in a JSON tree."""
    if isinstance(node, dict):
        if {"min", "median", "max"} <= set(node):
            yield node
        else:
            for v in node.values():
                yield from figures(v)
    elif isinstance(node, list):
        for v in node:
            yield from figures(v)


def test_data_folder_order_and_skip_reasons(tmp_path):
    """--data beats POPVOL_DATA beats the default folders; the volume is found in DIR or DIR/npz;
    a missing one gives a reason naming the file, the folder and where the folder came from."""
    (tmp_path / "env").mkdir()
    assert bench.find_data(tmp_path, environ={"POPVOL_DATA": str(tmp_path / "env")})["from"] == "--data"
    found = bench.find_data(None, environ={"POPVOL_DATA": str(tmp_path / "env")})
    assert found == {"dir": str((tmp_path / "env").resolve()), "from": "POPVOL_DATA",
                     "searched": [str(tmp_path / "env")]}
    work = tmp_path / "a" / "checkout"
    work.mkdir(parents=True)
    nothing = bench.find_data(None, environ={}, cwd=work)
    if nothing["dir"] is None:            # no folder beside popvol's own checkout either
        assert str((tmp_path / "a" / "shared" / "data" / "volumes").resolve()) in nothing["searched"]
        assert "no data folder" in bench.locate(bench.WDAS_VOLUME, nothing)[1]
    (tmp_path / "a" / "shared" / "data" / "volumes" / "npz").mkdir(parents=True)
    found = bench.find_data(None, environ={}, cwd=work)
    assert found["dir"] == str((tmp_path / "a" / "shared" / "data" / "volumes").resolve())
    assert "current directory" in found["from"]
    path, why = bench.locate(bench.WDAS_VOLUME, found)
    assert path is None and bench.WDAS_VOLUME in why and found["dir"] in why
    (Path(found["dir"]) / "npz" / bench.WDAS_VOLUME).write_bytes(b"")
    assert bench.locate(bench.WDAS_VOLUME, found) == (Path(found["dir"]) / "npz" / bench.WDAS_VOLUME, None)
    for name in ("wdas_sun.toml", "wdas_sun_sky.toml"):
        assert f'file = "{bench.WDAS_VOLUME}"' in bench.bench_scene_text(name)


def test_spread():
    assert bench.spread([3.0, 1.0, 2.0, 10.0]) == {"min": 1.0, "median": 2.5, "max": 10.0, "n": 4}


#: run by the installed copy: what it finds from another folder, as JSON
INSTALLED_PROBE = """
import json, sys
from popvol import bench
found = bench.find_data(sys.argv[1])
scenes = {}
for name, (toml, overrides, _, _) in bench.SCENES.items():
    if toml is None:
        continue
    volume = bench.locate(bench.WDAS_VOLUME, found)[0] if bench.needs_volume(toml) else None
    scene = bench.load_bench_scene(toml, volume, **overrides)
    scenes[name] = {"volume": None if volume is None else str(volume), "lights": len(scene.lights),  # a sky is 8 suns
                    "voxels": int((scene.medium.density > 0).sum())}
print(json.dumps({"machine": bench.machine(), "found": found, "scenes": scenes}))
"""


def install_copy(tmp_path) -> Path:
    """pip install --target (no deps, no network; setuptools' build_py where this venv cannot
    build a wheel offline) a copy of the source; returns the folder it went to."""
    src = tmp_path / "src_copy"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.nbi", "*.nbc")
    shutil.copytree(REPO / "src", src / "src", ignore=ignore)
    for f in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / f, src / f)
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                        "--no-build-isolation", "--target", str(site), str(src)],
                       capture_output=True, text=True, cwd=tmp_path)
    if r.returncode != 0 and "bdist_wheel" in r.stderr:
        # this venv's setuptools (< 70.1, no `wheel`) cannot build a wheel offline; build_py
        # lays out the same package and package data as the wheel would
        shutil.rmtree(site, ignore_errors=True)
        r = subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "--quiet",
                            "build_py", "--build-lib", str(site)], capture_output=True, text=True, cwd=src)
    assert r.returncode == 0, r.stderr
    return site


@pytest.mark.skipif(not SHARED_VOLUME.exists(), reason=f"{SHARED_VOLUME} absent (../shared data)")
def test_installed_bench_finds_its_scenes_and_the_volume(tmp_path):
    """An installed copy of popvol, run from another folder with only that install on PYTHONPATH,
    finds every packaged bench scene, the WDAS volume in the --data folder, and says it is
    itself with no commit (the skip reasons of an empty folder:
    test_data_folder_order_and_skip_reasons). It loads the scenes but runs no kernel: compiling
    them all afresh for the copy took five minutes; test_quick_bench_runs_every_scene runs them
    from this tree, whose bench is the same code."""
    site = install_copy(tmp_path)
    assert (site / "popvol" / "bench_scenes" / "wdas_sun_sky.toml").is_file()
    data, cwd = tmp_path / "data", tmp_path / "elsewhere"
    for d in (data, cwd):
        d.mkdir()
    shutil.copy(SHARED_VOLUME, data / bench.WDAS_VOLUME)
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop("POPVOL_DATA", None)
    r = subprocess.run([sys.executable, "-c", INSTALLED_PROBE, str(data)], capture_output=True,
                       text=True, cwd=cwd, env=env)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    m = res["machine"]
    assert Path(m["popvol_path"]).resolve() == (site / "popvol").resolve()    # the installed copy
    assert m["popvol_commit"] == "unknown"
    assert m["cpus"] >= 1 and m["numba_threads"] >= 1 and m["cpu_model"] and m["numpy"] and m["numba"]
    assert res["found"]["from"] == "--data"
    assert set(res["scenes"]) == {name for name, row in bench.SCENES.items() if row[0] is not None}
    for name in WDAS_ROWS:
        assert Path(res["scenes"][name]["volume"]).resolve() == (data / bench.WDAS_VOLUME).resolve()
    assert res["scenes"]["wdas_sun_sky"]["lights"] == 9 and res["scenes"]["wdas_sun"]["lights"] == 1
    assert all(row["voxels"] > 1000 for row in res["scenes"].values())


@pytest.mark.skipif(not SHARED_VOLUME.exists(), reason=f"{SHARED_VOLUME} absent (../shared data)")
def test_quick_bench_runs_every_scene(tmp_path):
    """`popvol bench --quick --data DIR` from another folder: every row runs (the WDAS rows from
    the volume in DIR), with the stages, peak memory and well-ordered figures of 2 runs each."""
    data, cwd = tmp_path / "data", tmp_path / "elsewhere"
    for d in (data, cwd):
        d.mkdir()
    shutil.copy(SHARED_VOLUME, data / bench.WDAS_VOLUME)
    env = {**os.environ}
    env.pop("POPVOL_DATA", None)

    def run(folder, out):
        r = subprocess.run([sys.executable, "-m", "popvol.cli", "bench", "--quick", "--data", str(folder),
                            "--json", str(out)], capture_output=True, text=True, cwd=cwd, env=env)
        assert r.returncode == 0, r.stderr
        return json.loads(out.read_text()), r.stdout

    res, table = run(data, tmp_path / "with.json")
    m = res["machine"]
    assert m["cpus"] >= 1 and m["numba_threads"] >= 1 and m["cpu_model"] and m["numpy"] and m["numba"]
    assert res["quick"] and res["repeat"] == 2 and res["data"]["from"] == "--data"
    for name in ("demo", *WDAS_ROWS):
        row = res["scenes"][name]
        assert "skipped" not in row, row
        assert set(row["seconds"]) == set(bench.STAGES) and row["peak_rss_mb"] > 0
        assert row["image"] == [160, 90]
        assert name in table
    assert res["scenes"]["wdas_sun_sky"]["domains"] == 9
    assert res["scenes"]["wdas_sun"]["method"].startswith("ordinates (18): ")
    assert res["scenes"]["wdas_sun_6"]["method"].startswith("ordinates (6): ")
    assert res["scenes"]["wdas_sun_sweep"]["method"] == "sweep: moment + poisson + diffusion, gather 64"
    assert res["scenes"]["wdas_sun_walk"]["method"] == "sweep: moment + poisson + walk, gather 64"
    assert res["scenes"]["wdas_sun_lobes"]["method"].endswith("gather 0")
    p = res["propagation"][0]
    assert p["stream_cells_per_s"]["median"] > 0 and p["sweep_over_stream"] > 0
    figs = list(figures(res))
    assert len(figs) > 30
    for f in figs:
        assert 0 <= f["min"] <= f["median"] <= f["max"] and f["n"] == 2, f
