"""Where a scene's error lives, light by light (run from the repository root; needs
popvol[reference]):

    python scripts/light_split_study.py [SCENE.toml ...] [--spp 2048] [--width 160] [--height 90]
                                        [--resolution 128] [--out build/split]

Each scene is split by its [[lights]] tables into the part lit by its suns and point lights
("sun") and the part lit by its sky or HDR map ("environment"); popvol and Mitsuba 3 are both
linear in the lights, so the parts add up to the scene. Each part is rendered alone by Mitsuba
(``--spp`` samples per pixel in passes of 64, llvm_ad_rgb, into ``--out``, resumed if there) and
by popvol at ``--resolution`` cells with the default method (six ordinates), with the one-lobe
sweeps and their diffusion stage (``solver = "sweep"``), the same with an environment's lights
handed over at a sun's threshold (``environment_handover_scale = 2``, a sun's
``handover_scale``) and the one-lobe walk alone (``isotropic = "walk"``), and measured as ``popvol compare`` does (the
medium pixels of the whole scene): relMSE, brightness and the reference's dim / mid / bright
bands, with the part's reference noise. The default scenes are
the gallery's that have a sky (examples/wdas_side, wdas_front, wdas_silver, dragon_sky,
demo_dusk) and the suite's HDR map (scenes/accuracy/demo_envmap).

Prints one Markdown table.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
from pathlib import Path

import numpy as np

import popvol
from popvol import metrics
from popvol.reference import load_reference, render_reference
from popvol.scene import read_scene_file, scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
SCENES = [ROOT / "examples" / f"{n}.toml" for n in ("wdas_side", "wdas_front", "wdas_silver", "dragon_sky",
                                                    "demo_dusk")] + [ROOT / "scenes" / "accuracy" / "demo_envmap.toml"]
ENVIRONMENT = ("sky", "envmap")
VARIANTS = (("default", {}), ("sweeps", {"solver": "sweep"}),
            ("sweeps, environment at a sun's threshold", {"solver": "sweep", "environment_handover_scale": 2.0}),
            ("walk alone", {"solver": "sweep", "isotropic": "walk"}))
SPP_PER_PASS = 64


def parts(path: Path) -> dict[str, dict]:
    """The scene file's data split by light: {"sun": ..., "environment": ...}, each part only
    where it has lights."""
    data = read_scene_file(path)
    out = {}
    for part, keep in (("sun", lambda t: t not in ENVIRONMENT), ("environment", lambda t: t in ENVIRONMENT)):
        lights = [light for light in data.get("lights", []) if keep(light.get("type"))]
        if lights:
            out[part] = {**copy.deepcopy(data), "lights": lights}
    return out


def scene_of(data: dict, path: Path, part: str, width: int, height: int, resolution: int):
    data = copy.deepcopy(data)
    data["camera"].update(width=width, height=height)
    data.setdefault("method", {})["resolution"] = resolution
    return scene_from_dict(data, source=f"{path} ({part})", base_dir=path.parent)


def measure(img, ref, mask) -> str:
    """relMSE | brightness | dim / mid / bright of ``img`` against the reference image ``ref``."""
    bands = metrics.band_ratios(img, ref, mask)
    return (f"{metrics.relmse(img, ref, mask):.3f} | x{metrics.brightness_ratio(img, ref, mask):.3f} | "
            + " / ".join(f"x{v:.3f}" for v in bands.values()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", default=[str(p) for p in SCENES])
    ap.add_argument("--spp", type=int, default=2048)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--out", default=str(ROOT / "build" / "split"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"Each part at {args.width}x{args.height}, {args.resolution} cells; relMSE, brightness and dim / mid / "
          "bright bands against the part's own Mitsuba reference, on the whole scene's medium pixels.\n")
    print("| scene | part | reference noise | " + " | ".join(f"{label}: relMSE, brightness, bands" for label, _ in VARIANTS)
          + " |")
    print("|---|---|---|" + "---|" * len(VARIANTS))
    for path in map(Path, args.scenes):
        split = parts(path)
        whole = popvol.load_scene(path, width=args.width, height=args.height, resolution=args.resolution)
        refs, images = {}, {}
        for part, data in split.items():
            scene = scene_of(data, path, part, args.width, args.height, args.resolution)
            ref_path = out / f"{path.stem}_{part}.exr"
            ref = load_reference(ref_path) if ref_path.exists() else None
            if ref is None or ref.spp < args.spp:
                more = args.spp - (ref.spp if ref else 0)
                ref = render_reference(scene, ref_path, more, "llvm_ad_rgb", passes=max(1, more // SPP_PER_PASS))
            refs[part] = ref
            images[part] = [popvol.render(dataclasses.replace(scene, method=dataclasses.replace(scene.method, **kw)))
                            for _, kw in VARIANTS]
        # the whole scene's medium pixels, as popvol compare takes them
        total = sum(r.image.astype(np.float64) for r in refs.values())
        mask = metrics.medium_mask(total, whole)
        for part, ref in refs.items():
            noise = ref.noise_relmse(mask)
            cells = " | ".join(measure(img, ref.image, mask) for img in images[part])
            print(f"| {path.stem} | {part} | {noise:.3f} | {cells} |", flush=True)
        if len(refs) > 1:
            cells = " | ".join(measure(sum(images[p][i] for p in refs), total, mask) for i in range(len(VARIANTS)))
            print(f"| {path.stem} | both | - | {cells} |", flush=True)


if __name__ == "__main__":
    main()
