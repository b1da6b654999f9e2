"""Where popvol's error lives, by scattering order (run from the repository root; needs
popvol[reference]):

    python scripts/order_bands.py [SCENE.toml --reference FULL.exr] [--spp 16384] [--out build/orders]

Mitsuba 3's volpath cut at max_depth 2, 3, 5 and 9 renders the light of paths with at most 1, 2,
4 and 8 scattering events; their differences and the full reference split the image into order
bands 1, 2, 3-4, 5-8 and 9+. popvol's own split: its single scattering (the unscattered light
scattered once, :meth:`popvol.Solution.single_scattering`) and the rest (the walk's scattered
light and the diffusion stage's). Missing cut references are rendered into ``--out`` (named
after the scene and the depth; 16384 spp in 8 passes by default); the default scene is the
regression fixture with its 65536-spp reference.

Printed on the pixels that see the medium (popvol compare's mask), in all of them and in the full
reference's dimmest 50 %, middle 40 % and brightest 10 %: each order band's share of the full
reference's luminance, then popvol's single scattering over Mitsuba's order 1 and popvol's rest
over Mitsuba's orders >= 2 (brightness ratios), with the noise (one standard deviation) of each
ratio from the references' passes, and the same for the one-lobe walk alone (``solver = "sweep"``,
``isotropic = "walk"``; its
single scattering is the default's).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import popvol
from popvol import metrics
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
    args = ap.parse_args()
    scene_path = Path(args.scene)
    full_path = Path(args.reference) if args.reference else scene_path.with_suffix(".exr")
    full = load_reference(full_path)
    h, w = full.image.shape[:2]
    scene = popvol.load_scene(scene_path, width=w, height=h)
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
    masks = {"all": mask, **metrics.bands(full.image, mask)}
    solution = popvol.solve(scene)
    single = popvol.render(scene, solution.single_scattering())
    whole = popvol.render(scene, solution)
    walk_scene = popvol.load_scene(scene_path, width=w, height=h, solver="sweep", isotropic="walk")
    walk_whole = popvol.render(walk_scene, popvol.solve(walk_scene))

    levels = [luminance_sums(cuts[d].image, masks) for d in DEPTHS] + [luminance_sums(full.image, masks)]
    var = [variance_sums(cuts[d], masks) for d in DEPTHS] + [variance_sums(full, masks)]
    print(f"{scene_path.name}: {w}x{h}, {int(mask.sum())} pixels see the medium; references "
          + ", ".join(f"max_depth {d} {cuts[d].spp} spp" for d in DEPTHS) + f", full {full.spp} spp")
    print(f"{'band':8s} " + " ".join(f"{'order ' + o:>10s}" for o in ORDER_BANDS)
          + f" {'popvol single / order 1':>26s} {'popvol rest / orders >= 2':>27s} {'walk alone':>10s}")
    p_single, p_whole = luminance_sums(single, masks), luminance_sums(whole, masks)
    p_walk = luminance_sums(walk_whole, masks)
    for name in masks:
        total = levels[-1][name]
        shares = [levels[0][name]] + [levels[i][name] - levels[i - 1][name] for i in range(1, len(levels))]
        o1, multi = levels[0][name], total - levels[0][name]
        r1 = p_single[name] / o1
        rm = (p_whole[name] - p_single[name]) / multi
        s1 = r1 * np.sqrt(var[0][name]) / o1
        sm = rm * np.sqrt(var[0][name] + var[-1][name]) / multi
        rw = (p_walk[name] - p_single[name]) / multi
        print(f"{name:8s} " + " ".join(f"{s / total:10.3f}" for s in shares)
              + f" {r1:17.3f} +- {s1:.3f} {rm:18.3f} +- {sm:.3f} {rw:10.3f}")


if __name__ == "__main__":
    main()
