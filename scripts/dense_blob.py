"""Radiance of a dense Gaussian blob's lit face as its density grows: the accuracy issue's
dense-media table.

A 16^3 Gaussian blob in the unit cube (standard deviation 0.15, voxels below 5 % of the peak
emptied, so it sits in empty space), albedo 0.9, g 0.5, lit by a sun from behind the camera,
seen at 64x36: the mean red radiance of the 4 x 4 pixels at the image centre per density scale
(sigma_t = scale x density, so scale / 16 mean free paths per voxel at the peak) and propagation
grid. An optically thick medium's reflection saturates (it depends on albedo and g, not on
density), so each row should level off as the scale grows. Prints a Markdown table.

    python scripts/dense_blob.py [--scales 8,80,800,8000,40000] [--resolutions 32,64]
"""
import argparse

import numpy as np

import popvol
from popvol.camera import Camera
from popvol.lights import DirectionalLight
from popvol.medium import Medium
from popvol.method import Method
from popvol.scene import Scene

N = 16


def blob_scene(scale: float, resolution: int) -> Scene:
    x = (np.arange(N) + 0.5) / N
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rho = np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / (2 * 0.15**2)).astype(np.float32)
    rho[rho < 0.05] = 0.0
    med = Medium(rho, 1.0 / N, np.full(3, 0.5 / N), scale=scale, albedo=0.9, g=0.5, source="dense blob")
    cam = Camera([0.5, 0.5, 3.0], [0.5, 0.5, 0.5], [0, 1, 0], 30.0, 64, 36)
    return Scene(med, [DirectionalLight([0.2, -0.3, -1.0], 1.0)], cam, np.zeros(3), Method(resolution=resolution))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="8,80,800,8000,40000")
    ap.add_argument("--resolutions", default="32,64")
    args = ap.parse_args()
    scales = [float(s) for s in args.scales.split(",")]
    print("| cells | " + " | ".join(f"scale {s:g} ({s / N:g} mfp/voxel)" for s in scales) + " |")
    print("|---" * (1 + len(scales)) + "|")
    for res in (int(r) for r in args.resolutions.split(",")):
        row = []
        for s in scales:
            scene = blob_scene(s, res)
            row.append(float(popvol.render(scene, popvol.solve(scene), jitter=False)[16:20, 30:34, 0].mean()))
        print(f"| {res} | " + " | ".join(f"{v:.4f}" for v in row) + " |", flush=True)


if __name__ == "__main__":
    main()
