"""Reflected radiance of a front-lit slab as its density grows, against Monte Carlo.

The slab of tests/slab.py: 16 x 16 x 4 voxels of 1/8, albedo 0.9, g 0.5,
a sun along (0.3, -0.4, -1) (so from behind the camera, 148 degrees of scattering), seen
straight down: popvol's radiance at the image centre (its whole image and its single
scattering, ``Solution.single_scattering()``) against tests/montecarlo.py's half_space_mc for a
plane-parallel medium of the slab's optical thickness (independent of popvol), per voxel
optical depth and grid. Prints a Markdown table.

    python scripts/dense_slab.py [--taus 0.25,1,10,100,1e4] [--resolutions 16,32] [--solver sweep] [--pad 0]

``--solver``: experimental.solver (sweep, jacobi, binned or ordinates). ``--pad N``: N layers
of empty voxels above the slab (tests/slab.py), as a volume from a file has around it.
"""
import argparse
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import half_space_mc        # noqa: E402
from slab import ALBEDO, G, LIGHT, VIEW, centre_radiance, slab_depth, slab_scene      # noqa: E402

import popvol     # noqa: E402
from popvol.scene import apply_overrides     # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--taus", default="0.25,1,10,100,1e4", help="optical depths of one voxel")
    ap.add_argument("--resolutions", default="16,32")
    ap.add_argument("--solver", default="sweep", help="experimental.solver")
    ap.add_argument("--pad", type=int, default=0, help="layers of empty voxels above the slab")
    args = ap.parse_args()
    taus = [float(t) for t in args.taus.split(",")]
    resolutions = [int(r) for r in args.resolutions.split(",")]
    print("| mean free paths per voxel | Monte Carlo total (single) | "
          + " | ".join(f"{r} cells: total (single)" for r in resolutions) + " |")
    print("|---" * (2 + len(resolutions)) + "|")
    for tau in taus:
        mc = half_space_mc(LIGHT, VIEW, ALBEDO, G, depth=slab_depth(tau), n_photons=200_000)
        cells = []
        for res in resolutions:
            scene = apply_overrides(slab_scene(tau, res, pad=args.pad), solver=args.solver)
            sol = popvol.solve(scene)
            total = centre_radiance(popvol.render(scene, sol, jitter=False))
            single = centre_radiance(popvol.render(scene, sol.single_scattering(), jitter=False))
            cells.append(f"{total:.4f} (x{total / mc['total']:.2f}) ({single:.5f}, x{single / mc['single']:.3f})")
        print(f"| {tau:g} | {mc['total']:.4f} ({mc['single']:.5f}) | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
