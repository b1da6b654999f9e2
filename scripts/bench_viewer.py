"""Speed of `popvol view` on the WDAS cloud (examples/wdas_sun.toml, 1/16 resolution).

Targets (issue #5, on 2 cores): camera-only updates at >= 10 frames per second at 320x180, and
a sun move fully re-propagated and shown in <= 250 ms.

Measured in two ways, both after a warm-up:
- engine: Engine.frame() called directly (propagation + rendering + PNG encoding);
- websocket: through the real server on 127.0.0.1, a client that sends one message and waits
  for its frame (adds JSON, base64 and the socket; the browser's PNG decode is not counted).

"fully re-propagated" means propagated at the view's own resolution (what Save writes), not
the coarser draft propagation shown while dragging; both are reported. The frame that shows it
first is the preview (the view's size and propagation, without the gathered last bounce); the
full frame, gather included, follows it from the same solution: both are reported.

    python scripts/bench_viewer.py [--json OUT.json] [--scene examples/wdas_sun.toml] [--repeats N]

Prints the figures as JSON (and writes them to --json).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numba

from popvol.viewer.engine import DRAFT, FULL, PREVIEW, Engine
from popvol.viewer.server import running

REPO = Path(__file__).resolve().parents[1]


def summary(seconds: list[float]) -> dict:
    return {"median_ms": 1000 * statistics.median(seconds), "max_ms": 1000 * max(seconds),
            "min_ms": 1000 * min(seconds), "n": len(seconds)}


def camera_frames(engine: Engine, level: str, n: int) -> dict:
    """n camera-only frames (the azimuth moves 1 degree each): frames per second."""
    s = engine.initial
    engine.frame(s, FULL)                                  # the solution is at hand
    times = []
    for i in range(n):
        t = time.perf_counter()
        f = engine.frame(replace(s, camera_azimuth=s.camera_azimuth + i + 1), level)
        times.append(time.perf_counter() - t)
        assert not f.propagated
    out = summary(times)
    out["fps"] = 1.0 / statistics.median(times)
    out["size"] = [f.width, f.height]
    return out


def sun_moves(engine: Engine, level: str, n: int) -> dict:
    """n sun moves of 3 degrees each (every one propagates anew): time to the frame."""
    s = engine.initial
    engine.frame(replace(s, sun_azimuth=s.sun_azimuth - 3.0), level)     # warm-up, not timed
    times, prop = [], []
    for i in range(n):
        s = replace(s, sun_azimuth=s.sun_azimuth + 3.0)
        t = time.perf_counter()
        f = engine.frame(s, level)
        times.append(time.perf_counter() - t)
        prop.append(f.seconds["propagate"])
        assert f.propagated
    out = summary(times)
    out["propagate_median_ms"] = 1000 * statistics.median(prop)
    out["size"] = [f.width, f.height]
    out["cells"] = f.resolution
    return out


def websocket_figures(engine: Engine, n: int) -> dict:
    """Closed loop through the server: send one change, wait for its frame, repeat."""
    from websockets.sync.client import connect
    out = {}
    with running(engine, ".", refine_delay=0.2) as url:
        with connect(url.replace("http", "ws", 1) + "ws", origin=url.rstrip("/")) as ws:
            init = json.loads(ws.recv())
            s = init["settings"]
            json.loads(ws.recv())                                   # the first full frame

            def round_trip(changes, level):
                t = time.perf_counter()
                ws.send(json.dumps({"type": "set", "settings": changes}))
                while True:
                    m = json.loads(ws.recv(timeout=30))
                    if m["type"] == "frame" and m["level"] == level:
                        return time.perf_counter() - t, m

            cam = [round_trip({"camera_azimuth": s["camera_azimuth"] + i + 1}, DRAFT)[0] for i in range(n)]
            out["camera_draft"] = {**summary(cam), "fps": 1.0 / statistics.median(cam)}
            time.sleep(0.5)                                         # let the refinement pass
            while True:                                             # drain it
                try:
                    ws.recv(timeout=0.3)
                except TimeoutError:
                    break
            sun, preview, full = [], [], []
            for i in range(max(3, n // 3)):
                # directions not solved before (the engine keeps the last few solutions)
                dt, m = round_trip({"sun_azimuth": s["sun_azimuth"] - 3.0 * (i + 1) - 0.5}, DRAFT)
                assert m["propagated"]
                sun.append(dt)
                t = time.perf_counter()
                while True:                                         # the refinements follow by themselves
                    m = json.loads(ws.recv(timeout=30))
                    if m["type"] == "frame" and m["level"] == PREVIEW:
                        preview.append(time.perf_counter() - t + dt)
                    if m["type"] == "frame" and m["level"] == FULL:
                        full.append(time.perf_counter() - t + dt)
                        break
            out["sun_draft_shown"] = summary(sun)
            if preview:
                out["sun_preview_shown_after_stop"] = {**summary(preview), "note": "includes the 200 ms pause "
                                                       "that tells the server input has stopped"}
            out["sun_full_shown_after_stop"] = {**summary(full), "note": "includes the 200 ms pause "
                                                "that tells the server input has stopped"}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(REPO / "examples" / "wdas_sun.toml"))
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--repeats", type=int, default=30, help="camera frames per measurement (sun moves: a third)")
    ap.add_argument("--resolution", type=int, default=64, help="the view's propagation cells")
    ap.add_argument("--draft-resolution", type=int, default=32)
    a = ap.parse_args(argv)
    if not Path(a.scene).is_file():
        print(f"bench_viewer: {a.scene} not found (the WDAS example needs ../shared/data/volumes)", file=sys.stderr)
        return 2
    log = lambda s: print(s, file=sys.stderr, flush=True)
    n = a.repeats
    # full view 640x360 (drafts 320x180), and a full view of 320x180 itself
    big = Engine(a.scene, width=640, height=360, resolution=a.resolution, draft_resolution=a.draft_resolution)
    small = Engine(a.scene, width=320, height=180, resolution=a.resolution, draft_resolution=a.draft_resolution)
    log("warming up (kernels, first solutions)")
    for e in (big, small):
        e.frame(e.initial, DRAFT)
        e.frame(e.initial, FULL)
    res = {"scene": str(a.scene), "machine": {"cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(),
                                               "python": platform.python_version()},
           "view": {"size": list(big.size[FULL]), "draft_size": list(big.size[DRAFT]),
                    "method": vars(big.method), "draft_method": vars(big.draft_method)}}
    log("engine: camera-only frames")
    res["engine"] = {
        "camera_draft_320x180": camera_frames(big, DRAFT, n),
        "camera_preview_320x180": camera_frames(small, PREVIEW, n),
        "camera_full_320x180": camera_frames(small, FULL, n),
        "camera_full_640x360": camera_frames(big, FULL, max(5, n // 3)),
    }
    log("engine: sun moves")
    res["engine"].update({
        "sun_draft_320x180": sun_moves(big, DRAFT, max(5, n // 3)),
        "sun_preview_320x180": sun_moves(small, PREVIEW, max(5, n // 3)),
        "sun_full_320x180": sun_moves(small, FULL, max(5, n // 3)),
        "sun_full_640x360": sun_moves(big, FULL, max(5, n // 3)),
    })
    log("websocket round trips")
    res["websocket_640x360_view"] = websocket_figures(big, n)
    e = res["engine"]
    res["targets"] = {
        "camera_only_fps_at_320x180": {"target": ">= 10", "draft": e["camera_draft_320x180"]["fps"],
                                       "preview": e["camera_preview_320x180"]["fps"],
                                       "full_quality": e["camera_full_320x180"]["fps"],
                                       "through_websocket": res["websocket_640x360_view"]["camera_draft"]["fps"]},
        "sun_move_fully_repropagated_ms_at_320x180": {"target": "<= 250",
                                                      "median": e["sun_preview_320x180"]["median_ms"],
                                                      "max": e["sun_preview_320x180"]["max_ms"],
                                                      "with_the_gather_median": e["sun_full_320x180"]["median_ms"]},
    }
    text = json.dumps(res, indent=2)
    if a.json:
        Path(a.json).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
