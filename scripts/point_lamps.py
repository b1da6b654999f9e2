"""Point lights outside and inside their medium, walked by the one-lobe sweeps and by the
ordinates, against Mitsuba: what chose experimental.point_walk = "auto" (docs/METHOD.md, "A point
light's ordinates", "Which lights").

Three lamps outside: the WDAS cloud of the accuracy suite (scenes/accuracy/wdas_angle_090.toml,
its camera and medium) lit by a point light 0.9 of its box's diagonal above and to the right of
it (its spherical domain a cone of 33 degrees) and by one in front of it, below and to the left
(41 degrees); and the cumulus field of `popvol bench` (bench_scenes/field_point.toml) lit by one
0.7 above its top, near enough for the whole sphere. Lamps inside (whole-sphere domains), each
with the medium's g set to several values: the suite's point-lit smoke
(scenes/accuracy/smoke1_point.toml, g = 0, 0.3, 0.6, 0.85), the bench's point-lit field (its own
light, g = 0.3, 0.6, 0.85) and the WDAS cloud lit from a point inside it (g = 0.3, 0.877). The
references are rendered once into build/point_lamps/ (Mitsuba 3, llvm_ad_rgb, 8 passes) and
extended to --spp. Prints a Markdown table: relMSE against a noiseless reference
(popvol.metrics, as docs/ACCURACY.md), brightness, the dim / mid / bright bands and the solve's
seconds.

    python scripts/point_lamps.py [--spp 1024] [--resolutions 64,128] [--lamps smoke_inside,wdas_lamp]
"""
import argparse
import dataclasses
import time
from pathlib import Path

import popvol
from popvol import metrics
from popvol.lights import PointLight
from popvol.reference import load_reference, render_reference

REPO = Path(__file__).resolve().parent.parent
WDAS = REPO / "scenes" / "accuracy" / "wdas_angle_090.toml"
FIELD = Path(popvol.__file__).parent / "bench_scenes" / "field_point.toml"
SMOKE = REPO / "scenes" / "accuracy" / "smoke1_point.toml"
#: key: (scene, light (None: the scene's own), the medium's g (None: the scene's))
LAMPS = {
    "wdas_lamp_above": (WDAS, PointLight([378.58, 591.85, -42.66], [1.10e6, 1.06e6, 0.97e6]), None),
    "wdas_lamp_front": (WDAS, PointLight([-179.3, -58.8, 462.1], [1.10e6, 1.06e6, 0.97e6]), None),
    "field_lamp_above": (FIELD, PointLight([0.3, 1.2, -0.3], [1.0, 0.96, 0.9]), None),
}
#: lights inside their medium (whole-sphere domains), each at several anisotropies
INSIDE = {
    "smoke_inside": (SMOKE, None, (0.0, 0.3, 0.6, 0.85)),
    "field_inside": (FIELD, None, (0.3, 0.6, 0.85)),
    "wdas_inside": (WDAS, PointLight([-10.0, 40.0, 10.0], [4.0e4, 3.9e4, 3.6e4]), (0.3, 0.877)),
}
for _key, (_path, _light, _gs) in INSIDE.items():
    for _g in _gs:
        LAMPS[f"{_key}_g{_g:g}"] = (_path, _light, _g)
WALKS = {"sweeps": "sweep", "ordinates": "ordinates"}


def lamp_scene(key: str, **overrides):
    path, light, g = LAMPS[key]
    scene = popvol.load_scene(path, **overrides)
    if light is not None:
        scene = dataclasses.replace(scene, lights=[light])
    if g is not None:
        scene = dataclasses.replace(scene, medium=dataclasses.replace(scene.medium, g=g))
    return scene


def reference(key: str, spp: int, folder: Path):
    path = folder / f"{key}.exr"
    ref = load_reference(path) if path.exists() else None
    if ref is None or ref.spp < spp:
        more = spp - (ref.spp if ref else 0)
        # a reference is extended with passes of its own size (popvol.reference requires it)
        passes = 8 if ref is None else max(1, more // ref.meta["spp_per_pass"])
        print(f"{key}: reference, {more} spp ...", flush=True)
        ref = render_reference(lamp_scene(key), path, more, "llvm_ad_rgb", passes=passes)
    return ref


def measure(key: str, ref, resolution: int, walk: str) -> dict:
    h, w = ref.image.shape[:2]
    scene = lamp_scene(key, width=w, height=h, resolution=resolution, point_walk=walk)
    t = time.perf_counter()
    solution = popvol.solve(scene)
    seconds = time.perf_counter() - t
    image = popvol.render(scene, solution)
    c = metrics.compare(image, ref.image, metrics.medium_mask(ref.image, scene), ref.variance, ref.halves,
                        ref.half_passes)
    c["error"] = c["relmse"] if c["relmse_extrapolated"] is None else c["relmse_extrapolated"]
    c["solve_seconds"] = seconds
    return c


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--resolutions", default="64,128")
    ap.add_argument("--references", type=Path, default=REPO / "build" / "point_lamps")
    ap.add_argument("--lamps", default="", help="comma-separated prefixes of the lamps to measure (default: all)")
    args = ap.parse_args()
    args.references.mkdir(parents=True, exist_ok=True)
    prefixes = [p for p in args.lamps.split(",") if p]
    print("| scene | cells | " + " | ".join(WALKS) + " |")
    print("|---|---|" + "---|" * len(WALKS))
    for key in LAMPS:
        if prefixes and not any(key.startswith(p) for p in prefixes):
            continue
        ref = reference(key, args.spp, args.references)
        for res in (int(r) for r in args.resolutions.split(",")):
            cells = []
            for walk in WALKS.values():
                c = measure(key, ref, res, walk)
                b = c["brightness_bands"]
                cells.append(f"{c['error']:.3f}, x{c['brightness_ratio']:.3f} "
                             f"(x{b['dim']:.2f} / x{b['mid']:.2f} / x{b['bright']:.2f}), "
                             f"solve {c['solve_seconds']:.2f} s")
            print(f"| {key} | {res} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
