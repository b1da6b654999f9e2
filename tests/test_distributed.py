"""Frames on Dask distributed (popvol.distributed): a real LocalCluster of two worker processes.

Tiny scenes (a procedural cumulus of resolution 10 whose time runs with the frame, 32x18
pixels, method resolution 16, 8 frames), so a test costs the cluster's start (~5 s on 2 cores)
and a second or two of rendering; the workers load the Numba kernels from the on-disk cache.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed", reason="Dask distributed is not installed "
                                          "(pip install 'popvol[distributed]')")

from popvol import PopvolError  # noqa: E402
from popvol import distributed as pd  # noqa: E402
from popvol.io.images import read_exr  # noqa: E402
from popvol.sequence import render_run, render_sequence  # noqa: E402

FRAMES = list(range(8))
SCENE = """
[medium]
type = "procedural"
resolution = 10
scale = 30.0

[[lights]]
type = "directional"
direction = [-0.9, -0.4, -0.35]
irradiance = [5.0, 4.85, 4.5]

[camera]
origin = [0.0, 0.1, 2.4]
target = [0.0, 0.72, 0.0]
fov = 40.0
width = 32
height = 18

[method]
resolution = 16
exposure = 0.0

[sequence]
frames = "0-7"
fps = 2                  # the cloud moves visibly from frame to frame
"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> str:
    p = tmp_path_factory.mktemp("dask_scene") / "scene.toml"
    p.write_text(SCENE)
    return str(p)


@pytest.fixture(scope="module")
def serial(scene, tmp_path_factory):
    """The serial run, warm start off, in this process: {frame: linear image}."""
    out = tmp_path_factory.mktemp("serial")
    res = render_run(scene, FRAMES, str(out / "f_####.exr"), {"warm_start": False})
    return {r["frame"]: read_exr(r["path"]) for r in res}


@pytest.fixture(scope="module")
def client():
    c = pd.local_client(2)
    yield c
    c.close()


def _check_runs(results, frames, runs):
    """Every frame once, and each run a contiguous slice of ``frames`` made in one process."""
    assert [r["frame"] for r in results] == frames
    by_run: dict[int, list[dict]] = {}
    for r in results:
        by_run.setdefault(r["run"], []).append(r)
    assert len(by_run) == runs
    chunks = [[r["frame"] for r in by_run[i]] for i in sorted(by_run)]
    assert sum(chunks, []) == frames                    # in order, no gaps, no overlaps
    assert max(map(len, chunks)) - min(map(len, chunks)) <= 1
    for rs in by_run.values():
        assert len({(r["worker"], r["pid"]) for r in rs}) == 1
    return by_run


def test_two_workers_bitwise_equal_serial_and_contiguous(client, scene, serial, tmp_path):
    out = tmp_path / "f_####.exr"
    seen = []
    res = pd.run_on_cluster(client, scene, FRAMES, str(out), {"warm_start": False},
                            progress=lambda done, total: seen.append((done, total)))
    by_run = _check_runs(res, FRAMES, 2)
    assert len({rs[0]["pid"] for rs in by_run.values()}) == 2       # both workers took a run
    assert os.getpid() not in {r["pid"] for r in res}
    for r in res:
        assert not r["skipped"]
        img = read_exr(r["path"])
        assert np.array_equal(img, serial[r["frame"]]), r["frame"]
    assert seen and seen[-1] == (len(FRAMES), len(FRAMES))
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    # a second run finds every frame written: all skipped, nothing rendered again
    again = pd.run_on_cluster(client, scene, FRAMES, str(out), {"warm_start": False}, progress=False)
    assert all(r["skipped"] for r in again)


def test_render_sequence_with_client_png_equals_serial(client, scene, tmp_path):
    from PIL import Image
    a = render_sequence(scene, "0-5", str(tmp_path / "s_##.png"), warm_start=False)
    b = render_sequence(scene, "0-5", str(tmp_path / "d_##.png"), warm_start=False, client=client)
    assert [r["frame"] for r in b] == list(range(6))
    for ra, rb in zip(a, b):
        with Image.open(ra["path"]) as ia, Image.open(rb["path"]) as ib:
            assert np.array_equal(np.asarray(ia), np.asarray(ib)), ra["frame"]


def test_warm_start_within_tolerance(client, scene, serial, tmp_path):
    res = pd.run_on_cluster(client, scene, FRAMES, str(tmp_path / "w_####.exr"), {}, progress=False)
    _check_runs(res, FRAMES, 2)
    for r in res:
        img, ref = read_exr(r["path"]), serial[r["frame"]]
        assert np.abs(img - ref).mean() <= 1e-2 * ref.mean(), r["frame"]


def test_numba_threads_per_worker(client, scene, tmp_path):
    want = pd.numba_threads_for(2)
    assert want == max(1, pd.cpu_count() // 2)

    def probe():
        import numba
        return numba.config.NUMBA_NUM_THREADS, numba.get_num_threads()

    assert set(client.run(probe).values()) == {(want, want)}
    # the local cluster's workers run without Dask's MALLOC_TRIM_THRESHOLD_ (pd.LOCAL_CONFIG)
    assert set(client.run(lambda: "MALLOC_TRIM_THRESHOLD_" in os.environ).values()) == {False}
    res = pd.run_on_cluster(client, scene, [0, 1], str(tmp_path / "n_#.exr"),
                            {"warm_start": False}, progress=False)
    assert {r["numba_threads"] for r in res} == {want}


def test_more_runs_than_workers_and_bad_input(client, scene, tmp_path):
    res = pd.run_on_cluster(client, scene, FRAMES[:5], str(tmp_path / "r_#.exr"),
                            {"warm_start": False}, runs=3, progress=False)
    _check_runs(res, FRAMES[:5], 3)
    # a bad option fails the same way anywhere: one PopvolError line, not retried
    with pytest.raises(PopvolError, match="options") as e:
        pd.run_on_cluster(client, scene, [0], str(tmp_path / "x_#.exr"), {"nonsense": 1},
                          progress=False)
    assert "\n" not in str(e.value)


def test_split_runs():
    assert pd.split_runs([1, 2, 3, 4, 5], 2) == [[1, 2, 3], [4, 5]]
    assert pd.split_runs([1, 2], 5) == [[1], [2]]
    assert pd.split_runs(list(range(10)), 3) == [[0, 1, 2, 3], [4, 5, 6], [7, 8, 9]]


@pytest.mark.slow
def test_worker_killed_mid_run_costs_a_retry(scene, serial, tmp_path):
    """SIGKILL the worker of run 0 once its first frame is on disk: the run is retried on a
    worker, skips the frames already written, and every frame exists once, readable and
    bitwise equal to the serial frames."""
    out = tmp_path / "k_####.exr"
    frames = FRAMES
    c = pd.local_client(2)
    try:
        pids = c.run(os.getpid)
        box: dict = {}

        def go():
            try:
                box["res"] = pd.run_on_cluster(c, scene, frames, str(out), {"warm_start": False},
                                               progress=False)
            except BaseException as e:  # noqa: BLE001
                box["err"] = e

        t = threading.Thread(target=go)
        t.start()
        first = tmp_path / "k_0000.exr"
        deadline = time.monotonic() + 120
        while not first.exists() and t.is_alive() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert first.exists(), box
        victim = [a for a, keys in c.processing().items()
                  if any(str(k).startswith("popvol-run-0-") for k in keys)]
        assert victim, "run 0 finished before the kill; make its frames slower"
        os.kill(pids[victim[0]], signal.SIGKILL)
        t.join(300)
        assert not t.is_alive()
        assert "err" not in box, box.get("err")
        res = box["res"]
    finally:
        c.close()
    assert [r["frame"] for r in res] == frames
    run0 = [r for r in res if r["run"] == 0]
    assert all(r["pid"] != pids[victim[0]] for r in run0)          # redone elsewhere
    assert run0[0]["skipped"]                                       # frame 0 was kept
    assert not all(r["skipped"] for r in run0)                     # the rest was rendered
    names = sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".exr" and
                   not p.name.startswith("."))
    assert names == [f"k_{f:04d}.exr" for f in frames]
    for r in res:
        assert np.array_equal(read_exr(r["path"]), serial[r["frame"]]), r["frame"]


def test_connect_bad_address_is_one_line():
    t = time.monotonic()
    with pytest.raises(PopvolError, match="cannot reach the Dask scheduler") as e:
        pd.connect("tcp://127.0.0.1:9", timeout=1)
    assert "\n" not in str(e.value)
    assert time.monotonic() - t < 30
    with pytest.raises(PopvolError, match="empty"):
        pd.connect("  ")


def test_missing_package_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(PopvolError, match=r"pip install 'popvol\[distributed\]'") as e:
        pd.local_client(2)
    assert "\n" not in str(e.value)
    monkeypatch.undo()
    with pytest.raises(PopvolError, match="workers"):
        pd.local_client(0)


def test_host_of_address():
    assert pd._host("tcp://10.0.0.5:4321") == "10.0.0.5"
    assert pd._host("tls://[::1]:8786") == "[::1]"
    assert pd._host("inproc://x/1/2") == "x"
