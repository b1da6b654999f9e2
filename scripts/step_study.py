"""The ray-march step (method.step, in voxels of the medium) against a step four times finer:
what each step changes in the image, in the metric of ``popvol compare``, and what it costs
(run from the repository root, with ../shared beside the checkout):

    python scripts/step_study.py [--steps 0.5 1 2] [--width 320] [--height 180]

Every scene of examples/ that loads here, and the regression fixture, is solved once at its own
method resolution and rendered at each step and at the finest step / 4 (the reference, also
jittered). Columns: relMSE on the pixels that see the medium, brightness ratio overall and in
the brightest 10 %, and the render's seconds (best of 3, 2 cores).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import popvol
from popvol import metrics
from popvol.errors import PopvolError

ROOT = Path(__file__).resolve().parents[1]


def scenes():
    yield from sorted((ROOT / "examples").glob("*.toml"))
    yield ROOT / "tests" / "fixtures" / "regression_cloud.toml"


def render(scene, solution, step):
    s = dataclasses.replace(scene, method=dataclasses.replace(scene.method, step=step))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        image = popvol.render(s, solution)
        best = min(best, time.perf_counter() - t0)
    return image, best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    args = ap.parse_args()
    fine = min(args.steps) / 4
    print(f"reference: step {fine:g} voxel; {args.width}x{args.height}")
    print(f"{'scene':22s} {'step':>5s} {'relMSE':>9s} {'bright':>8s} {'top10%':>8s} {'render s':>9s}")
    for path in scenes():
        try:
            scene = popvol.load_scene(path, width=args.width, height=args.height)
        except PopvolError as e:
            print(f"{path.stem:22s} skipped: {e}")
            continue
        solution = popvol.solve(scene)
        ref, _ = render(scene, solution, fine)
        mask = metrics.medium_mask(ref, scene)
        for step in args.steps:
            image, seconds = render(scene, solution, step)
            print(f"{path.stem:22s} {step:5g} {metrics.relmse(image, ref, mask):9.2e} "
                  f"{metrics.brightness_ratio(image, ref, mask):8.5f} "
                  f"{metrics.band_ratios(image, ref, mask)['bright']:8.5f} {seconds:9.3f}")


if __name__ == "__main__":
    main()
