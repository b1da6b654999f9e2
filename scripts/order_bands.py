"""Where popvol's error lives, by scattering order (run from the repository root; needs
popvol[reference]):

    python scripts/order_bands.py [SCENE.toml --reference FULL.exr] [--spp 16384] [--out build/orders]

Mitsuba 3's volpath cut at max_depth 2, 3, 5 and 9 renders the light of paths with at most 1, 2,
4 and 8 scattering events; their differences and the full reference split the image into order
bands 1, 2, 3-4, 5-8 and 9+. popvol's own split: its single scattering (the unscattered light
scattered once, :meth:`popvol.Solution.single_scattering`), its second order (the gathered last
bounce of that light alone: the solution reduced to its unscattered light but still gathered,
docs/METHOD.md "Gathered last bounce"; a scene lit by suns and point lights only) and the rest
(the gather of the walk's scattered light and the diffusion stage's, orders >= 3). Missing cut
references are rendered into ``--out`` (named after the scene and the depth; 16384 spp in 8
passes by default); the default scene is the regression fixture with its 65536-spp reference.
``--gather`` and ``--gather-resolution`` set the method's (to see the gather's quadrature
converge: its second order is the transport of the single scattering, exact as its directions
and blocks are refined).

Printed on the pixels that see the medium (popvol compare's mask), in all of them and in the full
reference's dimmest 50 %, middle 40 % and brightest 10 %: each order band's share of the full
reference's luminance, then the brightness ratios popvol / Mitsuba of order 1, order 2, orders
>= 3 and orders >= 2, with the noise (one standard deviation) of each ratio from the references'
passes, and orders >= 2 for the one-lobe walk alone (``solver = "sweep"``, ``isotropic =
"walk"``; its single scattering is the default's). Without the gather (``--gather 0``) popvol's
orders 2 and >= 3 are not apart, and those columns are left out. Where the full reference has two
independent halves (``Reference.halves``), the bands are ranked on one half and the full
reference's light in them measured on the other, as ``popvol compare`` does: ranked on the image
they are measured on, a few thousand spp of a dense cloud let its fireflies fill the brightest
tenth (the WDAS cloud at density x10 and 128 spp in 8 passes: its orders >= 3 there x0.57 ranked on itself,
x1.12 ranked on one half). ``--resolution 64,128,256`` repeats popvol's columns at each light-domain
resolution (default: the scene's), so that convergence shows. ``--halve-voxels`` solves and
renders the scene's medium on cubes half as wide as its voxels' smallest side (its density
trilinear at their centres, the same box), so that the gather, which never takes blocks finer
than the voxels, and the march's interpolation between voxel centres are refined too.
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import popvol
from popvol import metrics
from popvol.kernels.sampling import resample
from popvol.reference import load_reference, render_reference

ROOT = Path(__file__).resolve().parents[1]
DEPTHS = (2, 3, 5, 9)
ORDER_BANDS = ("1", "2", "3-4", "5-8", "9+")


def luminance_sums(img, masks) -> dict:
    y = metrics.luminance(img)
    return {name: float(y[m].sum()) for name, m in masks.items()}


def variance_sums(ref, masks) -> dict:
    if ref.variance is None:
        return {name: float("nan") for name in masks}
    v = np.asarray(ref.variance, np.float64) @ np.square(metrics.LUMINANCE)     # the variance of the luminance
    return {name: float(v[m].sum()) for name, m in masks.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "tests" / "fixtures" / "regression_cloud.toml"))
    ap.add_argument("--reference", default=None, help="the full reference (default: the fixture's)")
    ap.add_argument("--spp", type=int, default=16384)
    ap.add_argument("--out", default=str(ROOT / "build" / "orders"))
    ap.add_argument("--gather", type=int, default=None, help="method.gather (default: the scene's)")
    ap.add_argument("--gather-resolution", type=int, default=None, help="method.gather_resolution")
    ap.add_argument("--halve-voxels", action="store_true", help="the medium on cubes half as wide as its voxels' smallest side")
    ap.add_argument("--resolution", default=None, help="popvol's light-domain resolutions, comma-separated "
                    "(default: the scene's)")
    args = ap.parse_args()
    scene_path = Path(args.scene)
    full_path = Path(args.reference) if args.reference else scene_path.with_suffix(".exr")
    full = load_reference(full_path)
    h, w = full.image.shape[:2]
    method = {k: v for k, v in (("gather", args.gather), ("gather_resolution", args.gather_resolution))
              if v is not None}
    scene = popvol.load_scene(scene_path, width=w, height=h, **method)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cuts = {}
    for depth in DEPTHS:
        path = out / f"{scene_path.stem}_d{depth}.exr"
        if not path.exists():
            print(f"rendering {path} (max_depth {depth}, {args.spp} spp) ...", flush=True)
            render_reference(scene, path, args.spp, "llvm_ad_rgb", passes=8, max_depth=depth, resume=False)
        cuts[depth] = load_reference(path)

    mask = metrics.medium_mask(full.image, scene)
    # ranked on one half, measured on the other (module docstring); the other half's variance
    # is the full reference's times passes / its passes
    halves, half_passes = full.halves, full.half_passes
    if halves is not None and half_passes is not None:
        masks = {"all": mask, **metrics.bands(halves[0], mask)}
        full_level = luminance_sums(halves[1], masks)
        full_var = {k: v * full.passes / half_passes[1] for k, v in variance_sums(full, masks).items()}
        ranked = f"bands ranked on one half of the full reference ({half_passes[0]} passes), measured on the other"
    else:
        masks = {"all": mask, **metrics.bands(full.image, mask)}
        full_level, full_var = luminance_sums(full.image, masks), variance_sums(full, masks)
        ranked = "bands ranked on the full reference itself (it has no halves)"
    levels = [luminance_sums(cuts[d].image, masks) for d in DEPTHS] + [full_level]
    var = [variance_sums(cuts[d], masks) for d in DEPTHS] + [full_var]
    gathered = scene.method.gather > 0
    print(f"{scene_path.name}: {w}x{h}, {int(mask.sum())} pixels see the medium; references "
          + ", ".join(f"max_depth {d} {cuts[d].spp} spp" for d in DEPTHS) + f", full {full.spp} spp; {ranked}")
    resolutions = ([int(r) for r in args.resolution.split(",")] if args.resolution
                   else [scene.method.resolution])
    for resolution in resolutions:
        print_orders(scene_path, w, h, dict(method, resolution=resolution), masks, levels, var, gathered,
                     args.halve_voxels)


def halved(medium):
    """``medium`` on cubes half as wide as its voxels' smallest side (:func:`on_cubes`)."""
    return on_cubes(medium, float(np.min(medium.voxel_size)) / 2, "--halve-voxels")


def on_cubes(medium, cell: float, what: str):
    """``medium`` on cubes of side ``cell`` over the same box (each voxel side a whole number of
    them, else SystemExit naming ``what``), its density sampled at their centres as a light
    domain samples it (kernels.sampling.resample, an unrotated domain of cubic cells: trilinear,
    clamped to the edge in the outer half voxel)."""
    voxel = np.asarray(medium.voxel_size, np.float64)
    ratio = voxel / cell
    if not np.allclose(ratio, np.round(ratio), rtol=1e-6):
        raise SystemExit(f"{what}: {medium.source} has voxels of {voxel.tolist()}, "
                         f"not whole multiples of {cell:g}")
    lo = medium.origin - voxel / 2                   # the corner of the medium's box
    shape = tuple(int(n * r) for n, r in zip(medium.density.shape, np.round(ratio).astype(int)))
    density = np.empty(shape, np.float32)
    resample(np.ascontiguousarray(medium.density, np.float32), 1.0 / voxel, np.asarray(medium.origin, np.float64),
             np.eye(3), lo, cell, shape, True, density)
    return dataclasses.replace(medium, density=density, voxel_size=np.full(3, cell), origin=lo + cell / 2)


def print_orders(scene_path, w, h, method, masks, levels, var, gathered, halve: bool = False) -> None:
    """popvol's order bands at the method's overrides ``method`` against Mitsuba's ``levels`` (the
    cut references' and the full one's luminance sums per band) and their variances ``var``;
    ``halve``: on :func:`halved` voxels."""
    scene = popvol.load_scene(scene_path, width=w, height=h, **method)
    if halve:
        scene = dataclasses.replace(scene, medium=halved(scene.medium))
    solution = popvol.solve(scene)
    single = popvol.render(scene, solution.single_scattering())
    # the unscattered light alone, gathered: orders 1 and 2 (the gather scatters it once more)
    two = popvol.render(scene, dataclasses.replace(solution.single_scattering(), single=False)) if gathered else None
    whole = popvol.render(scene, solution)
    walk_scene = popvol.load_scene(scene_path, width=w, height=h, solver="sweep", isotropic="walk", **method)
    if halve:
        walk_scene = dataclasses.replace(walk_scene, medium=scene.medium)
    walk_whole = popvol.render(walk_scene, popvol.solve(walk_scene))

    print(f"\npopvol at {scene.method.resolution} cells" + (" on cubes half as wide as the voxels' smallest side:" if halve else ":"))
    columns = ["order 1", "order 2", "orders >= 3"] if gathered else ["order 1"]
    print(f"{'band':8s} " + " ".join(f"{'order ' + o:>10s}" for o in ORDER_BANDS)
          + "".join(f" {'popvol / ' + c:>27s}" for c in columns + ["orders >= 2"]) + f" {'walk alone':>10s}")
    p_single, p_whole = luminance_sums(single, masks), luminance_sums(whole, masks)
    p_two = luminance_sums(two, masks) if gathered else None
    p_walk = luminance_sums(walk_whole, masks)
    for name in masks:
        total = levels[-1][name]
        shares = [levels[0][name]] + [levels[i][name] - levels[i - 1][name] for i in range(1, len(levels))]
        o1, o2, multi = levels[0][name], levels[1][name] - levels[0][name], total - levels[0][name]
        # (popvol's part, Mitsuba's, the variance of Mitsuba's) per column
        parts = [(p_single[name], o1, var[0][name])]
        if gathered:
            parts += [(p_two[name] - p_single[name], o2, var[0][name] + var[1][name]),
                      (p_whole[name] - p_two[name], total - levels[1][name], var[1][name] + var[-1][name])]
        parts.append((p_whole[name] - p_single[name], multi, var[0][name] + var[-1][name]))
        cells = []
        for p, m, v in parts:
            r = p / m
            cells.append(f"{r:20.3f} +- {r * np.sqrt(v) / m:.3f}")
        rw = (p_walk[name] - p_single[name]) / multi
        print(f"{name:8s} " + " ".join(f"{s / total:10.3f}" for s in shares) + " " + " ".join(cells) + f" {rw:10.3f}")


if __name__ == "__main__":
    main()
