"""The walk's variants against Mitsuba (run from the repository root, with ../shared beside the
checkout):

    python scripts/walk_study.py [--resolution 64] [--gather N] [--variants KEY,...] [NAME ...]

Variants (KEY: what differs from the default method): "default" (the six-ordinate walk,
kernels/ordinates.py, which walks all of a sun's light; point lights keep the sweeps and the
diffusion stage), "sweep" (one lobe per cell, sweeps + diffusion: experimental.solver =
"sweep"), "binned" (the binned wavefront + diffusion: experimental.solver = "binned",
kernels/binned.py, each cell's light kept in fixed anisotropy bins, so the walk is linear in the
light), "walk" and "binned-walk" (those walks alone), "fine-diffusion" (the sweeps with their
diffusion stage on the domain's own cells, ``diffusion_resolution = 0``, instead of blocks of
them). Default: all six. ``--gather N``: method.gather of every variant (default:
the method's, 64 directions; 0: the fields' lobes light the camera, kernels/gather.py).

NAME: "regression" (tests/fixtures/regression_cloud), a scene of scenes/accuracy/ (reference in
build/accuracy/, made by scripts/accuracy_table.py) or of the gallery (examples/NAME.toml,
reference build/gallery/NAME_ref.exr); scenes without a reference are skipped. Default: the
regression fixture, wdas_angle_090 and the gallery's scenes. Prints the metric of
``popvol compare`` per scene and variant.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import popvol
from popvol import metrics
from popvol.reference import load_reference

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["regression", "wdas_angle_090", "wdas_side", "wdas_front", "wdas_silver", "field_sun", "dragon_sky",
         "demo_dusk"]
VARIANTS = {"default": ("six ordinates, gathered (default)", {}),
            "sweep": ("sweeps + diffusion, gathered", {"solver": "sweep"}),
            "binned": ("binned + diffusion", {"solver": "binned"}),
            "walk": ("sweeps, walk alone", {"solver": "sweep", "isotropic": "walk"}),
            "binned-walk": ("binned, walk alone", {"solver": "binned", "isotropic": "walk"}),
            "fine-diffusion": ("sweeps + diffusion on the domain's own cells", {"solver": "sweep",
                                                                                "diffusion_resolution": 0})}


def case(name: str) -> tuple[Path, Path]:
    if name == "regression":
        return ROOT / "tests" / "fixtures" / "regression_cloud.toml", ROOT / "tests" / "fixtures" / "regression_cloud.exr"
    if (ROOT / "scenes" / "accuracy" / f"{name}.toml").exists():
        return ROOT / "scenes" / "accuracy" / f"{name}.toml", ROOT / "build" / "accuracy" / f"{name}.exr"
    return ROOT / "examples" / f"{name}.toml", ROOT / "build" / "gallery" / f"{name}_ref.exr"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    ap.add_argument("--gather", type=int, default=None, help="method.gather of every variant (default: the method's)")
    ap.add_argument("names", nargs="*", default=NAMES)
    args = ap.parse_args()
    keys = [k for k in args.variants.split(",") if k]
    unknown = [k for k in keys if k not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    print("| scene | variant | relMSE | brightness | dim / mid / bright | iterations | solve + render |")
    print("|---|---|---|---|---|---|---|")
    for name in args.names:
        scene_path, ref_path = case(name)
        if not ref_path.exists():
            print(f"skipped {name}: no {ref_path.relative_to(ROOT)}")
            continue
        ref = load_reference(ref_path)
        h, w = ref.image.shape[:2]
        for label, overrides in (VARIANTS[k] for k in keys):
            if args.gather is not None:
                overrides = {**overrides, "gather": args.gather}
            scene = popvol.load_scene(scene_path, width=w, height=h, resolution=args.resolution, **overrides)
            t0 = time.perf_counter()
            solution = popvol.solve(scene)
            image = popvol.render(scene, solution)
            seconds = time.perf_counter() - t0
            c = metrics.compare(image, ref.image, metrics.medium_mask(ref.image, scene))
            b = c["brightness_bands"]
            print(f"| {name} | {label} | {c['relmse']:.3f} | x{c['brightness_ratio']:.3f} | x{b['dim']:.3f} / "
                  f"x{b['mid']:.3f} / x{b['bright']:.3f} | {solution.domains[0].result.iterations} | "
                  f"{seconds:.1f} s |", flush=True)


if __name__ == "__main__":
    main()
