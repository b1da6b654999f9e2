"""What the light domain's unscattered light costs the image, on the voxels popvol renders on
(run from the repository root; needs popvol[reference] and the scene's reference):

    python scripts/direct_study.py SCENE.toml --reference REF.exr [--voxel-depth 0,0.7] [--resolution 128]

popvol's ``phi_dir`` on the medium's grid is the sun's unscattered light computed on its light
domain (method.resolution) and brought to the voxel centres trilinearly. Here it is replaced,
at every voxel the renderer reads, by a shadow ray toward the sun through the grid's trilinear
density (quarter-voxel steps, stopped past an optical depth of 30; single_study.shadow_ray) and the scattered rest
``phi - phi_dir`` kept, so the two images differ by ``phi_dir`` alone: its single scattering and
the gathered light scattered from it. At each ``--voxel-depth`` (method.voxel_depth: 0, the
medium's own voxels; else the finer grid it makes) the script prints popvol compare's metric for
both, the shadow rays' seconds, and popvol's ``phi_dir`` over the shadow rays' where the latter
is above 1e-3 (mean and median). The scene's first light must be a sun and its medium grey.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numba as nb
import numpy as np

import popvol
from popvol import metrics
from popvol.pipeline import seen_voxels
from popvol.reference import load_reference
from popvol.scene import apply_overrides, load_scene
from single_study import shadow_ray           # scripts/, beside this one


@nb.njit(parallel=True, fastmath=True)
def shadow_rays(density, scale, origin, voxel, lo, hi, back, seen, step, out):
    """out (the grid's shape) = single_study.shadow_ray at each voxel centre where ``seen``:
    exp(-tau) through the trilinear density toward the sun (``back``) to the box's face, in
    steps of ``step``, stopped past an optical depth of 30."""
    nx, ny, nz = density.shape
    for i in nb.prange(nx):
        for j in range(ny):
            for k in range(nz):
                if seen[i, j, k]:
                    x = (origin[0] + i * voxel[0], origin[1] + j * voxel[1], origin[2] + k * voxel[2])
                    out[i, j, k] = shadow_ray(density, scale, origin, voxel, lo, hi, back, x, step, 30.0)


def row(label: str, img, ref, mask) -> str:
    r = metrics.compare(img, ref.image, mask, ref.variance, ref.halves, ref.half_passes)
    b = r["brightness_bands"]
    error = r["relmse_extrapolated"] if r["relmse_extrapolated"] is not None else r["relmse"]
    return (f"{label:28s} relMSE {error:.4f}  x{r['brightness_ratio']:.3f} "
            f"(dim {b['dim']:.3f} / mid {b['mid']:.3f} / bright {b['bright']:.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--reference", required=True)
    ap.add_argument("--voxel-depth", default="0,0.7")
    ap.add_argument("--resolution", type=int, default=None)
    args = ap.parse_args()
    ref = load_reference(args.reference)
    base = load_scene(args.scene)
    if base.lights[0].type != "directional" or not base.lights[0].unscattered:
        raise SystemExit(f"{args.scene}: the first light must be a sun")
    mask = metrics.medium_mask(ref.image, base)
    print(f"{args.scene} against {args.reference} ({ref.spp} spp); relMSE against a noiseless reference where "
          "the reference has halves")
    depths = [float(v) for v in args.voxel_depth.split(",")]
    first = depths[0]
    for depth in depths:
        scene = apply_overrides(base, voxel_depth=depth, resolution=args.resolution)
        solution = popvol.solve(scene)
        med = solution.medium
        lo, hi = med.bounds
        exact = np.zeros(med.shape, np.float32)
        seen = seen_voxels(med)
        if depth == first:                  # compile before timing
            shadow_rays(np.zeros((2, 2, 2), np.float32), 1.0, np.zeros(3), np.ones(3), np.full(3, -0.5),
                        np.full(3, 1.5), np.array([0.0, 1.0, 0.0]), np.ones((2, 2, 2), np.bool_), 0.25,
                        np.zeros((2, 2, 2), np.float32))
        t0 = time.perf_counter()
        shadow_rays(med.density, float(med.scale.max()), med.origin, med.voxel_size, lo, hi,
                    -np.asarray(solution.directions[0], np.float64), seen, 0.25 * float(med.voxel_size.min()), exact)
        seconds = time.perf_counter() - t0
        print(f"voxel_depth {depth:g}: grid {'x'.join(map(str, med.shape))}, shadow rays {seconds:.1f} s")
        print(row("  popvol's phi_dir", popvol.render(scene, solution), ref, mask))
        own = solution.direct[0, 0]
        phi, phia, direct = solution.phi.copy(), solution.phia.copy(), solution.direct.copy()
        for c in range(phi.shape[1]):
            phi[0, c] += exact - own
            phia[0, c] += exact - own
            direct[0, c] = exact
        swapped = dataclasses.replace(solution, phi=phi, phia=phia, direct=direct, cache={})
        print(row("  phi_dir from shadow rays", popvol.render(scene, swapped), ref, mask))
        lit = seen & (exact > 1e-3)
        ratio = own[lit] / exact[lit]
        print(f"  popvol's phi_dir / shadow rays' where the latter > 1e-3: mean {ratio.mean():.3f}, "
              f"median {np.median(ratio):.4f}")


if __name__ == "__main__":
    main()
