"""Reflected radiance of a front-lit slab as its density grows, against Monte Carlo.

The slab of tests/slab.py: 16 x 16 x 4 voxels of 1/8, albedo 0.9, g 0.5,
a sun along (0.3, -0.4, -1) (so from behind the camera, 148 degrees of scattering), seen
straight down: popvol's radiance at the image centre (its whole image and its single
scattering, ``Solution.single_scattering()``) against tests/montecarlo.py's half_space_mc for a
plane-parallel medium of the slab's optical thickness (independent of popvol), per voxel
optical depth and grid. Prints a Markdown table.

    python scripts/dense_slab.py [--taus 0.25,1,10,100,1e4] [--resolutions 16,32] [--solver sweep] [--pad 0] [--gather 64]
    python scripts/dense_slab.py --cube [--taus 0.25,0.5,1,10,1e4]

``--solver``: experimental.solver (sweep, jacobi, binned or ordinates). ``--pad N``: N layers
of empty voxels above the slab (tests/slab.py), as a volume from a file has around it.
``--gather``: method.gather (0: the fields' lobes light the camera).
``--cube``: instead, the single scattering of tests/slab.py's cube filling its grid (lit through
three faces, seen from a corner, 16 cells) against its independent integral
(cube_single_scattering), over the pixels that see it: the ratio of the sums, and the worst,
10th and 90th percentile pixels.
"""
import argparse
import sys
from pathlib import Path

import numpy as np


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import half_space_mc        # noqa: E402
from slab import (ALBEDO, G, LIGHT, VIEW, centre_radiance, cube_single_scattering, dense_cube_scene,   # noqa: E402
                  slab_depth, slab_scene)

import popvol     # noqa: E402
from popvol.scene import apply_overrides     # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--taus", default="0.25,1,10,100,1e4", help="optical depths of one voxel")
    ap.add_argument("--resolutions", default="16,32")
    ap.add_argument("--solver", default="sweep", help="experimental.solver")
    ap.add_argument("--pad", type=int, default=0, help="layers of empty voxels above the slab")
    ap.add_argument("--gather", type=int, default=64, help="method.gather (0: the lobes light the camera)")
    ap.add_argument("--cube", action="store_true", help="the cube filling its grid instead (single scattering)")
    args = ap.parse_args()
    taus = [float(t) for t in args.taus.split(",")]
    if args.cube:
        cube_table(taus)
        return
    resolutions = [int(r) for r in args.resolutions.split(",")]
    print("| mean free paths per voxel | Monte Carlo total (single) | "
          + " | ".join(f"{r} cells: total (single)" for r in resolutions) + " |")
    print("|---" * (2 + len(resolutions)) + "|")
    for tau in taus:
        mc = half_space_mc(LIGHT, VIEW, ALBEDO, G, depth=slab_depth(tau), n_photons=200_000)
        cells = []
        for res in resolutions:
            scene = apply_overrides(slab_scene(tau, res, pad=args.pad), solver=args.solver, gather=args.gather)
            sol = popvol.solve(scene)
            total = centre_radiance(popvol.render(scene, sol, jitter=False))
            single = centre_radiance(popvol.render(scene, sol.single_scattering(), jitter=False))
            cells.append(f"{total:.4f} (x{total / mc['total']:.2f}) ({single:.5f}, x{single / mc['single']:.3f})")
        print(f"| {tau:g} | {mc['total']:.4f} ({mc['single']:.5f}) | " + " | ".join(cells) + " |", flush=True)


def cube_table(taus) -> None:
    """Print the cube's single scattering against its integral, per optical depth of a voxel."""
    print("| mean free paths per voxel | popvol / integral | worst pixel | 10th / 90th percentile |")
    print("|---|---|---|---|")
    for tau in taus:
        scene = dense_cube_scene(tau)
        exact = cube_single_scattering(scene)
        img = popvol.render(scene, popvol.solve(scene).single_scattering(), jitter=False).astype(np.float64)
        seen = exact[..., 0] > 0.02 * exact[..., 0].max()
        ratio = img[seen, 0] / exact[seen, 0]
        p10, p90 = np.percentile(ratio, [10, 90])
        worst = ratio[np.argmax(np.abs(ratio - 1))]
        print(f"| {tau:g} | x{img[seen].sum() / exact[seen].sum():.4f} | x{worst:.3f} | x{p10:.3f} / x{p90:.3f} |",
              flush=True)


if __name__ == "__main__":
    main()
