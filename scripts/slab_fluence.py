"""Fluence inside a front-lit slab, voxel by voxel, against the plane-parallel Monte Carlo.

The wide slab of tests/slab.py (``wide_slab_fluence``: 48 x 48 x 4 voxels, two empty voxels
above it, lit by its sun at unit irradiance, solved at 48 cells): popvol's fluence (unscattered
and scattered) at the centre's voxels from the lit face down, against tests/montecarlo.py's
slab_fluence_mc (independent of popvol), the mean over each voxel's depth. Prints a Markdown
table of the Monte Carlo's values and popvol's ratios to them.

    python scripts/slab_fluence.py [--albedo 1] [--g 0.85] [--taus 0.5,2,3.75,10]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import slab_fluence_mc         # noqa: E402
from slab import LIGHT, wide_slab_fluence      # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--albedo", type=float, default=1.0)
    ap.add_argument("--g", type=float, default=0.85)
    ap.add_argument("--taus", default="0.5,2,3.75,10", help="mean free paths per voxel")
    args = ap.parse_args()
    print("| mean free paths per voxel (cap) | Monte Carlo, voxels 1-4 | popvol / Monte Carlo |")
    print("|---|---|---|")
    for tau in (float(t) for t in args.taus.split(",")):
        mc = slab_fluence_mc(-LIGHT[2], args.albedo, args.g, 4 * tau, 32, n_photons=400_000, seed=1)
        mc = mc.reshape(4, 8).mean(axis=1)
        walk, cap = wide_slab_fluence(tau, args.albedo, args.g)
        print(f"| {tau:g} ({cap:.3g}) | " + " / ".join(f"{x:.3f}" for x in mc) + " | "
              + " / ".join(f"x{x:.2f}" for x in walk / mc) + " |", flush=True)


if __name__ == "__main__":
    main()
