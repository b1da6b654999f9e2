"""How much of popvol's error against Mitsuba is its own sampling noise (run from the repository
root, with the suite's references in build/accuracy/, made by scripts/accuracy_table.py):

    python scripts/spp_study.py [SCENE ...] [--resolution 128] [--spp 1,4,16]

SCENE: names of scenes/accuracy/ (default: every one whose reference exists). One solution per
scene at ``--resolution`` cells, rendered at the reference's size with each ``--spp`` (hashed
sub-pixel and along-ray offsets, the default's sampling at more than one) and once without
jitter (pixel centres and segment midpoints, one sample: the default at spp = 1), each
measured against the reference in popvol compare's metric (relMSE, brightness, the dimmest
50 % / middle 40 % / brightest 10 %), and the first spp's image against the last's (its own
noise, if the last is converged).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import popvol
from popvol import metrics
from popvol.reference import load_reference

ROOT = Path(__file__).resolve().parents[1]


def row(label: str, img, ref, mask) -> str:
    b = metrics.band_ratios(img, ref, mask)
    return (f"| {label} | {metrics.relmse(img, ref, mask):.4f} | x{metrics.brightness_ratio(img, ref, mask):.3f} | "
            + " / ".join(f"x{b[k]:.3f}" for k in ("dim", "mid", "bright")) + " |")


def suite_cases(names: list[str], resolution: int, columns: int = 4):
    """(name, reference, scene at the reference's size and ``resolution`` cells, medium mask)
    of each scenes/accuracy/ NAME (all whose reference exists if ``names`` is empty); a row
    of ``columns`` cells for each scene without a reference."""
    names = names or sorted(p.stem for p in (ROOT / "build" / "accuracy").glob("*.exr"))
    for name in names:
        ref_path = ROOT / "build" / "accuracy" / f"{name}.exr"
        if not ref_path.exists():
            print(f"| {name}: no {ref_path.relative_to(ROOT)} |" + " |" * (columns - 1))
            continue
        ref = load_reference(ref_path)
        h, w = ref.image.shape[:2]
        scene = popvol.load_scene(ROOT / "scenes" / "accuracy" / f"{name}.toml", width=w, height=h,
                                  resolution=resolution)
        yield name, ref, scene, metrics.medium_mask(ref.image, scene)


def study_args(doc: str, option: str, default: str):
    """The arguments of a study over the suite: SCENE ..., --resolution and ``option``, a
    comma-separated list of integers; returns (args, that list)."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument(option, default=default)
    args = ap.parse_args()
    return args, [int(s) for s in getattr(args, option[2:].replace("-", "_")).split(",")]


def main() -> None:
    args, spps = study_args(__doc__, "--spp", "1,4,16")
    print("| scene, sampling | relMSE | brightness | dim / mid / bright |")
    print("|---|---|---|---|")
    for name, ref, scene, mask in suite_cases(args.scenes, args.resolution):
        noise = metrics.noise_relmse(ref.variance, ref.image, mask) if ref.variance is not None else float("nan")
        solution = popvol.solve(scene)
        images = {}
        for spp in spps:
            scene.method.spp = spp
            images[spp] = popvol.render(scene, solution, jitter=True)
            print(row(f"{name}, {spp} spp", images[spp], ref.image, mask))
        scene.method.spp = 1
        print(row(f"{name}, pixel centres (no jitter, the default at 1 spp)", popvol.render(scene, solution),
                  ref.image, mask))
        print(f"| {name}: reference noise {noise:.4f}; {spps[0]} spp against {spps[-1]} spp "
              f"{metrics.relmse(images[spps[0]], images[spps[-1]], mask):.4f} | | | |")


if __name__ == "__main__":
    main()
