"""Reflected radiance of a front-lit slab as its density grows, against Monte Carlo.

A slab of unit density, 16 x 16 x 4 voxels of 1/8, albedo 0.9, g 0.5,
a sun along (0.3, -0.4, -1) (so from behind the camera, 148 degrees of scattering), seen
straight down: popvol's radiance at the image centre (its whole image and its single
scattering, ``Solution.single_scattering()``) against tests/montecarlo.py's half_space_mc for a
plane-parallel medium of the slab's optical thickness (independent of popvol), per voxel
optical depth and grid. Prints a Markdown table.

    python scripts/dense_slab.py [--taus 0.25,1,10,100,1e4] [--resolutions 16,32]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import half_space_mc        # noqa: E402

import popvol     # noqa: E402
from popvol.camera import Camera        # noqa: E402
from popvol.lights import DirectionalLight      # noqa: E402
from popvol.medium import Medium        # noqa: E402
from popvol.method import Method        # noqa: E402
from popvol.scene import Scene          # noqa: E402

LIGHT = np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0])
ALBEDO, G = 0.9, 0.5
N = 16      # the slab is N x N x N/4 voxels


def slab_scene(scale, resolution, n=N):
    """A slab of unit density, n x n x n/4 voxels of 1/8, its top face z = 0 seen from above."""
    rho = np.ones((n, n, n // 4), np.float32)
    h = 1.0 / 8
    origin = np.array([-n / 16 + h / 2, -n / 16 + h / 2, -n / 32 + h / 2])
    med = Medium(rho, h, origin, scale=scale, albedo=ALBEDO, g=G, source="slab")
    cam = Camera([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], [0, 1, 0], 6.0, 16, 16)
    return Scene(med, [DirectionalLight(LIGHT, 1.0)], cam, np.zeros(3), Method(resolution=resolution))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--taus", default="0.25,1,10,100,1e4", help="optical depths of one voxel")
    ap.add_argument("--resolutions", default="16,32")
    args = ap.parse_args()
    taus = [float(t) for t in args.taus.split(",")]
    resolutions = [int(r) for r in args.resolutions.split(",")]
    print("| mean free paths per voxel | Monte Carlo total (single) | "
          + " | ".join(f"{r} cells: total (single)" for r in resolutions) + " |")
    print("|---" * (2 + len(resolutions)) + "|")
    for tau in taus:
        mc = half_space_mc(LIGHT, [0.0, 0.0, 1.0], ALBEDO, G, depth=tau * (N // 4), n_photons=200_000)
        cells = []
        for res in resolutions:
            scene = slab_scene(tau * 8, res)
            sol = popvol.solve(scene)
            total = float(popvol.render(scene, sol, jitter=False)[6:10, 6:10, 0].mean())
            single = float(popvol.render(scene, sol.single_scattering(), jitter=False)[6:10, 6:10, 0].mean())
            cells.append(f"{total:.4f} (x{total / mc['total']:.2f}) ({single:.5f}, x{single / mc['single']:.3f})")
        print(f"| {tau:g} | {mc['total']:.4f} ({mc['single']:.5f}) | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
