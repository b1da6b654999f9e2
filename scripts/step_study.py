"""The ray-march step (method.step, in voxels of the medium) against a step four times finer:
what each step changes in the image, in the metric of ``popvol compare``, and what it costs
(run from the repository root, with ../shared beside the checkout):

    python scripts/step_study.py [--steps 0.5 1 2] [--max-steps 8] [--width 320] [--height 180]
                                 [--scenes NAME ...] [--seeds N]

Every scene of examples/ that loads here, and the regression fixture, is solved once at its own
method resolution and rendered at each step, with each ``--max-steps`` (method.max_step: how
many steps one sample may span in thin blocks), and at the finest step / 4 with one sample
per step (the reference), all with one jittered sample per pixel (hashed from method.seed;
the default at spp = 1 is the pixel centre). Columns: relMSE on the pixels that see the medium,
brightness ratio overall and in the brightest 10 %, and the render's seconds (best of 3, 2 cores). With ``--seeds N`` each
step is rendered with method.seed 0 .. N-1 (other sub-pixel and along-ray offsets) and the
columns are the mean and standard deviation over the seeds: popvol's own 1-spp sampling noise.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

import popvol
from popvol import metrics
from popvol.errors import PopvolError

ROOT = Path(__file__).resolve().parents[1]


def scenes(names):
    paths = sorted((ROOT / "examples").glob("*.toml")) + [ROOT / "tests" / "fixtures" / "regression_cloud.toml"]
    return [p for p in paths if not names or p.stem in names]


def render(scene, solution, step, seed=0, repeat=3, max_step=1):
    method = dataclasses.replace(scene.method, step=step, seed=seed, max_step=max_step)
    s = dataclasses.replace(scene, method=method)
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        image = popvol.render(s, solution, jitter=True)    # the seeds' offsets, as at spp > 1
        best = min(best, time.perf_counter() - t0)
    return image, best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--max-steps", type=int, nargs="+", default=[popvol.Method().max_step])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--scenes", nargs="+", default=None, help="example names (default: all, and the fixture)")
    ap.add_argument("--seeds", type=int, default=1)
    args = ap.parse_args()
    fine = min(args.steps) / 4
    print(f"reference: step {fine:g} voxel; {args.width}x{args.height}")
    print(f"{'scene':22s} {'step':>5s} {'max':>3s} {'relMSE':>9s} {'bright':>8s} {'top10%':>8s} {'render s':>9s}")
    for path in scenes(args.scenes):
        try:
            scene = popvol.load_scene(path, width=args.width, height=args.height)
        except PopvolError as e:
            print(f"{path.stem:22s} skipped: {e}")
            continue
        solution = popvol.solve(scene)
        ref, _ = render(scene, solution, fine)
        mask = metrics.medium_mask(ref, scene)
        for step in args.steps:
            for max_step in args.max_steps:
                rows = []
                for seed in range(args.seeds):
                    image, seconds = render(scene, solution, step, seed, 3 if seed == 0 else 1, max_step)
                    rows.append((metrics.relmse(image, ref, mask), metrics.brightness_ratio(image, ref, mask),
                                 metrics.band_ratios(image, ref, mask)["bright"], seconds))
                r = np.array(rows)
                head = f"{path.stem:22s} {step:5g} {max_step:3d}"
                if args.seeds == 1:
                    print(f"{head} {r[0, 0]:9.2e} {r[0, 1]:8.5f} {r[0, 2]:8.5f} {r[0, 3]:9.3f}")
                else:
                    print(f"{head} {r[:, 0].mean():9.2e} {r[:, 1].mean():.4f}+-{r[:, 1].std():.4f} "
                          f"{r[:, 2].mean():.4f}+-{r[:, 2].std():.4f} {r[0, 3]:9.3f}")


if __name__ == "__main__":
    main()
