"""Point lights outside and above their medium, walked by the one-lobe sweeps and by the
ordinates, against Mitsuba: what chose experimental.point_walk = "auto" (docs/METHOD.md, "A point
light's ordinates", "Which lights").

Three lamps: the WDAS cloud of the accuracy suite (scenes/accuracy/wdas_angle_090.toml, its
camera and medium) lit by a point light 0.9 of its box's diagonal above and to the right of it
(its spherical domain a cone of 33 degrees) and by one in front of it, below and to the left (41
degrees); and the cumulus field of `popvol bench` (bench_scenes/field_point.toml) lit by one 0.7
above its top, near enough for the whole sphere. The references are rendered once into
build/point_lamps/ (Mitsuba 3, llvm_ad_rgb, 8 passes) and extended to --spp. Prints a Markdown
table: relMSE against a noiseless reference (popvol.metrics, as docs/ACCURACY.md), brightness
and the dim / mid / bright bands.

    python scripts/point_lamps.py [--spp 1024] [--resolutions 64,128]
"""
import argparse
import dataclasses
from pathlib import Path

import popvol
from popvol import metrics
from popvol.lights import PointLight
from popvol.reference import load_reference, render_reference

REPO = Path(__file__).resolve().parent.parent
WDAS = REPO / "scenes" / "accuracy" / "wdas_angle_090.toml"
FIELD = Path(popvol.__file__).parent / "bench_scenes" / "field_point.toml"
LAMPS = {
    "wdas_lamp_above": (WDAS, PointLight([378.58, 591.85, -42.66], [1.10e6, 1.06e6, 0.97e6])),
    "wdas_lamp_front": (WDAS, PointLight([-179.3, -58.8, 462.1], [1.10e6, 1.06e6, 0.97e6])),
    "field_lamp_above": (FIELD, PointLight([0.3, 1.2, -0.3], [1.0, 0.96, 0.9])),
}
WALKS = {"sweeps": "sweep", "ordinates": "ordinates"}


def lamp_scene(key: str, **overrides):
    path, light = LAMPS[key]
    scene = popvol.load_scene(path, **overrides)
    return dataclasses.replace(scene, lights=[light])


def reference(key: str, spp: int, folder: Path):
    path = folder / f"{key}.exr"
    ref = load_reference(path) if path.exists() else None
    if ref is None or ref.spp < spp:
        more = spp - (ref.spp if ref else 0)
        print(f"{key}: reference, {more} spp ...", flush=True)
        ref = render_reference(lamp_scene(key), path, more, "llvm_ad_rgb", passes=8)
    return ref


def measure(key: str, ref, resolution: int, walk: str) -> dict:
    h, w = ref.image.shape[:2]
    scene = lamp_scene(key, width=w, height=h, resolution=resolution, point_walk=walk)
    image = popvol.render(scene, popvol.solve(scene))
    c = metrics.compare(image, ref.image, metrics.medium_mask(ref.image, scene), ref.variance, ref.halves,
                        ref.half_passes)
    c["error"] = c["relmse"] if c["relmse_extrapolated"] is None else c["relmse_extrapolated"]
    return c


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--resolutions", default="64,128")
    ap.add_argument("--references", type=Path, default=REPO / "build" / "point_lamps")
    args = ap.parse_args()
    args.references.mkdir(parents=True, exist_ok=True)
    print("| scene | cells | " + " | ".join(WALKS) + " |")
    print("|---|---|" + "---|" * len(WALKS))
    for key in LAMPS:
        ref = reference(key, args.spp, args.references)
        for res in (int(r) for r in args.resolutions.split(",")):
            cells = []
            for walk in WALKS.values():
                c = measure(key, ref, res, walk)
                b = c["brightness_bands"]
                cells.append(f"{c['error']:.3f}, x{c['brightness_ratio']:.3f} "
                             f"(x{b['dim']:.2f} / x{b['mid']:.2f} / x{b['bright']:.2f})")
            print(f"| {key} | {res} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
