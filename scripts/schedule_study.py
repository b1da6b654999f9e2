"""How much the walk's image depends on the order in which cells send (run from the repository
root; the gallery's references, build/gallery/NAME_ref.exr, are used where present):

    python scripts/schedule_study.py [NAME ...]        # default: the regression fixture only

The walk merges the packets that meet in a cell by energy-weighted anisotropy (docs/METHOD.md
Eq. 12), and a merged lobe splits differently from its parts, so the converged fields depend on
which packets meet: on the solver (Gauss-Seidel sweeps or the Jacobi wavefront) and on the
Southwell threshold of the sweeps (cells hold their pending power until it exceeds ``fraction``
times the mean, walk.SOUTHWELL_FRACTION, default 2). Each row solves the scene with one
schedule, at the default tolerance and at 1e-4 (converged), and compares the image with the
scene's Mitsuba reference in the metric of ``popvol compare``: a schedule-independent method
would give the same figures in every row at 1e-4.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import popvol
from popvol import metrics, walk
from popvol.reference import load_reference

ROOT = Path(__file__).resolve().parents[1]
SCHEDULES = (("sweeps, threshold 0 (every cell sends)", "sweep", 0.0),
             ("sweeps, threshold 2 (default)", "sweep", 2.0),
             ("sweeps, threshold 16", "sweep", 16.0),
             ("Jacobi wavefront", "jacobi", 2.0))


def cases(names):
    yield ROOT / "tests" / "fixtures" / "regression_cloud.toml", ROOT / "tests" / "fixtures" / "regression_cloud.exr"
    for name in names:
        ref = ROOT / "build" / "gallery" / f"{name}_ref.exr"
        if ref.exists():
            yield ROOT / "examples" / f"{name}.toml", ref
        else:
            print(f"{name}: skipped, no {ref.relative_to(ROOT)}")


def main() -> None:
    default = walk.SOUTHWELL_FRACTION
    print(f"{'scene':16s} {'tolerance':>9s} {'schedule':40s} {'sweeps':>6s} {'solve s':>7s} {'relMSE':>7s} "
          f"{'bright':>7s} {'dim / mid / bright':>20s}")
    for scene_path, ref_path in cases(sys.argv[1:]):
        ref = load_reference(ref_path)
        h, w = ref.image.shape[:2]
        for tolerance in (popvol.Method().tolerance, 1e-4):
            for label, solver, fraction in SCHEDULES:
                walk.SOUTHWELL_FRACTION = fraction
                try:
                    scene = popvol.load_scene(scene_path, width=w, height=h, tolerance=tolerance, solver=solver)
                    t0 = time.perf_counter()
                    solution = popvol.solve(scene)
                    seconds = time.perf_counter() - t0
                finally:
                    walk.SOUTHWELL_FRACTION = default
                image = popvol.render(scene, solution)
                mask = metrics.medium_mask(ref.image, scene)
                b = metrics.band_ratios(image, ref.image, mask)
                sweeps = sum(d["iterations"] for d in solution.stats()["domains"])
                print(f"{scene_path.stem:16s} {tolerance:9.0e} {label:40s} {sweeps:6d} {seconds:7.2f} "
                      f"{metrics.relmse(image, ref.image, mask):7.4f} x{metrics.brightness_ratio(image, ref.image, mask):6.3f} "
                      f"x{b['dim']:.3f} / x{b['mid']:.3f} / x{b['bright']:.3f}", flush=True)


if __name__ == "__main__":
    main()
