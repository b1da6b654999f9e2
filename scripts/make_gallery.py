"""Render docs/GALLERY.md and its figures (run from the repository root, with ../shared beside
the checkout):

    python scripts/make_gallery.py                      # popvol only
    python scripts/make_gallery.py --references         # and Mitsuba 3 beside it, where made
    python scripts/make_gallery.py --references --only wdas_side dragon_sky   # these entries;
                                                        # the others' sections kept as they are

Each entry is an example scene rendered by the command the gallery prints, at the size given
below, after one warm-up render (so the time excludes the Numba compile). With
``--references``, a Mitsuba 3 reference of the same scene and size is read from
build/gallery/NAME_ref.exr, made beforehand by

    popvol reference examples/NAME.toml -o build/gallery/NAME_ref.exr --spp 256 --passes 4 \\
        --variant llvm_ad_rgb --width W --height H

and, for the WDAS scenes (1024 spp) and the cumulus field (512), run again with ``--spp 768
--passes 12`` and ``--spp 256 --passes 4`` (a reference is extended with the same 64 samples
per pass), and the dusk cumulus's with ``--spp 1152 --passes 18`` (1536 in all); the figure shows popvol | Mitsuba at the reference's automatic exposure (both
panels the same), with `popvol compare`'s figures in the table.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

import popvol
from popvol import metrics
from popvol.io.images import auto_exposure, read_exr, tonemap
from popvol.reference import load_reference

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "figures" / "gallery"
REFS = ROOT / "build" / "gallery"

#: name, caption, (width, height)
ENTRIES = [
    ("wdas_side", "The WDAS cloud, a sun from the right and a sky", (320, 180)),
    ("wdas_front", "The WDAS cloud, the sun behind the camera and a sky", (320, 180)),
    ("wdas_silver", "The WDAS cloud against the sun (silver lining) and a sky", (320, 180)),
    ("smoke1_point", "OpenVDB's smoke1 lit by a point light inside it", (180, 240)),
    ("dragon_sky", "The dragon fog under a sky alone", (320, 180)),
    ("demo_dusk", "The built-in cumulus at dusk: a low orange sun and a darkening sky", (320, 180)),
    ("field_sun", "A field of small cumulus on tall voxels, the sun behind the camera", (320, 180)),
]


def render(name: str, size: tuple[int, int], tmp: Path) -> tuple[np.ndarray, dict, str]:
    """popvol's linear image of examples/NAME.toml at ``size``, its --stats and its command."""
    exr = tmp / f"{name}.exr"
    cmd = ["popvol", "render", f"examples/{name}.toml", "-o", str(tmp / f"{name}.png"), "--exr", str(exr),
           "--width", str(size[0]), "--height", str(size[1]), "--stats", str(tmp / f"{name}.json")]
    exe = [sys.executable, "-m", "popvol.cli", *cmd[1:]]
    for _ in range(2):                      # the first run compiles or warms the caches
        subprocess.run(exe, check=True, cwd=ROOT, capture_output=True)
    stats = json.loads((tmp / f"{name}.json").read_text())
    shown = " ".join(cmd[:3]) + f" -o {name}.png --width {size[0]} --height {size[1]}"
    return read_exr(exr), stats, shown


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--references", action="store_true", help="add the Mitsuba references of build/gallery")
    ap.add_argument("--only", nargs="+", metavar="NAME", choices=[e[0] for e in ENTRIES],
                    help="render only these entries and keep the others' sections (and figures) from the "
                         "current docs/GALLERY.md")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    kept = kept_sections(ROOT / "docs" / "GALLERY.md") if args.only else {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, caption, size in ENTRIES:
            if args.only and name not in args.only:
                if caption not in kept:
                    ap.error(f"--only: docs/GALLERY.md has no section '{caption}' to keep; run without --only")
                rows.append({"name": name, "kept": kept[caption]})
                continue
            try:
                popvol.load_scene(ROOT / "examples" / f"{name}.toml")
            except popvol.PopvolError as e:
                print(f"skipped {name}: {e}")
                continue
            img, stats, cmd = render(name, size, Path(tmp))
            ref_path = REFS / f"{name}_ref.exr"
            row = {"name": name, "caption": caption, "cmd": cmd, "seconds": stats["seconds"]["total"],
                   "size": size, "lights": len(stats["domains"])}
            if args.references and ref_path.is_file():
                ref = load_reference(ref_path)
                scene = popvol.load_scene(ROOT / "examples" / f"{name}.toml", width=size[0], height=size[1])
                mask = metrics.medium_mask(ref.image, scene)
                row["compare"] = metrics.compare(img, ref.image, mask, ref.variance, ref.halves, ref.half_passes)
                row["spp"] = ref.spp
                e = auto_exposure(ref.image)
                panel = np.concatenate([tonemap(img, e), np.full((size[1], 4, 3), 255, np.uint8),
                                        tonemap(ref.image, e)], axis=1)
            else:
                panel = tonemap(img)
            Image.fromarray(panel).save(OUT / f"{name}.png", optimize=True)
            rows.append(row)
            print(name, f"{row['seconds']:.2f} s", row.get("compare", {}).get("relmse", ""))
    write_markdown(rows)


def kept_sections(path: Path) -> dict:
    """The sections of a gallery page by caption: {caption: its lines, from its "## " heading
    to the next one}."""
    out, caption = {}, None
    for line in path.read_text().splitlines():
        if line.startswith("## "):
            caption = line[3:]
            out[caption] = []
        if caption is not None:
            out[caption].append(line)
    for lines in out.values():            # each ends with its blank line, the last one too
        if lines[-1]:
            lines.append("")
    return out


def write_markdown(rows):
    cpu = next((l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                if l.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else ""
    lines = ["# Gallery", "",
             "Example scenes of `examples/`, rendered by `python scripts/make_gallery.py --references`",
             f"on {os.cpu_count()} cores ({cpu}). PNGs use the default tone curve (ACES 2.0 SDR,",
             "exposure `auto`). Where a Mitsuba 3 reference was rendered (`volpath`, `llvm_ad_rgb`, the",
             "spp given), the figure is **popvol | Mitsuba** at the reference's automatic exposure, and",
             "the figures are those of `popvol compare` on the pixels that see the medium: relMSE with",
             "epsilon = 0.01 x (mean reference luminance)^2, the brightness ratio, and the ratio in the",
             "reference's dimmest 50 % / middle 40 % / brightest 10 % (each half of its passes ranked and",
             "measured against the other), with the reference's own noise in the same relMSE and popvol's",
             "relMSE against a noiseless reference, extrapolated from the reference's two halves",
             "(`popvol compare`). Times are popvol's whole render (load, solve, render, write) after a warm-up",
             "run that compiled the kernels; the WDAS scenes need `../shared/data/volumes`."]
    kept = [r["name"] for r in rows if "kept" in r]
    if kept:
        lines += [f"The entries {', '.join(f'`{k}`' for k in kept)} keep their figures and times from an earlier",
                  "run (`--only`), on a day the same machine may have run at another speed."]
    lines += [""]
    for r in rows:
        if "kept" in r:
            lines += r["kept"]
            continue
        lines += [f"## {r['caption']}", "", f"![{r['name']}](figures/gallery/{r['name']}.png)", "",
                  f"`{r['cmd']}`: {r['size'][0]}x{r['size'][1]}, {r['lights']} light domain(s), "
                  f"{r['seconds']:.1f} s.", ""]
        c = r.get("compare")
        if c:
            b = c["brightness_bands"]
            noise = c["reference_noise_relmse"]
            noiseless = ("" if c["relmse_extrapolated"] is None else
                         f"; against a noiseless reference {c['relmse_extrapolated']:.3f}, extrapolated from the "
                         "reference's halves")
            lines += [f"Against Mitsuba ({r['spp']} spp): relMSE {c['relmse']:.3f} (reference noise "
                      f"{noise:.3f}{noiseless}), brightness x{c['brightness_ratio']:.2f}; dimmest 50 % "
                      f"x{b['dim']:.2f}, middle 40 % x{b['mid']:.2f}, brightest 10 % x{b['bright']:.2f}.", ""]
    (ROOT / "docs" / "GALLERY.md").write_text("\n".join(lines))
    print(ROOT / "docs" / "GALLERY.md")


if __name__ == "__main__":
    main()
