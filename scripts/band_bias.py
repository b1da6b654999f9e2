"""How a noisy reference biases the band ratios when it ranks its own pixels (popvol.metrics).

Renders SCENE twice with Mitsuba 3 (``popvol reference``'s passes, the second time with the
seeds after the first's): a reference R, which keeps two independent halves (``Reference.halves``),
and an image I of the same scene, independent of R. Measures I against R in the three bands of
``popvol compare``: ranked on R itself, and ranked on each half of R and measured against the
other (:func:`popvol.metrics.band_ratios`, as ``popvol compare`` does). I and R render the same
scene, so every band is x1 but for noise; a ratio far from 1 is the ranking's bias. Run from the
repository root:

    python scripts/band_bias.py examples/wdas_front.toml --sun-only --width 160 --height 90 --spp 1024

(``--sun-only`` keeps the scene's first light alone: the sun behind the camera.) Prints both rows.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import popvol
from popvol import metrics
from popvol.reference import render_reference


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel of the reference, and of the image")
    ap.add_argument("--passes", type=int, default=8)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--sun-only", action="store_true", help="keep the scene's first light alone")
    args = ap.parse_args()
    scene = popvol.load_scene(args.scene, width=args.width, height=args.height)
    if args.sun_only:
        scene = dataclasses.replace(scene, lights=scene.lights[:1], environment=None)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "ref.exr"
        ref = render_reference(scene, path, args.spp, args.variant, passes=args.passes)
        more = render_reference(scene, path, args.spp, args.variant, passes=args.passes)   # the next seeds
    image = (more.image * more.passes - ref.image * ref.passes) / (more.passes - ref.passes)
    mask = metrics.medium_mask(ref.image, scene)
    row = lambda r: " / ".join(f"{k} x{v:.3f}" for k, v in r.items())
    print(f"{args.scene}: reference and image of {args.spp} spp each, {int(mask.sum())} medium pixels, "
          f"relMSE {metrics.relmse(image, ref.image, mask):.3f}, the reference's noise {ref.noise_relmse(mask):.3f}")
    print(f"ranked on the reference itself:      {row(metrics.band_ratios(image, ref.image, mask))}")
    print(f"ranked on each half, measured on the other (popvol compare): "
          f"{row(metrics.band_ratios(image, ref.image, mask, ref.halves))}")


if __name__ == "__main__":
    sys.exit(main())
