"""Would extrapolating over the light domain's cell mend what converges at first order in it?
(run from the repository root; needs popvol[reference] and the scene's reference):

    python scripts/richardson_study.py SCENE.toml --reference REF.exr [--resolution 64,128,256]

The cumulus field's multiply scattered light converges from below at first order in the
light-domain cell (docs/METHOD.md, "Where the method is biased"). If the whole image did, the
Richardson extrapolation 2 I(2n) - I(n) of the images at n and 2n cells would remove that error
for the price of one more solve at half the cells. Printed in popvol compare's metric (relMSE
against a noiseless reference where the reference has halves; the brightness and its ratio in
the dimmest 50 % / middle 40 % / brightest 10 %): the image at each resolution and the
extrapolation from each pair of consecutive ones.
"""
from __future__ import annotations

import argparse

import popvol
from popvol import metrics
from popvol.reference import load_reference
from popvol.scene import apply_overrides, load_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--reference", required=True)
    ap.add_argument("--resolution", default="64,128,256")
    args = ap.parse_args()
    base = load_scene(args.scene)
    ref = load_reference(args.reference)
    mask = metrics.medium_mask(ref.image, base)

    def row(label, img):
        m = metrics.compare(img, ref.image, mask, ref.variance, ref.halves, ref.half_passes)
        b = m["brightness_bands"]
        error = m["relmse_extrapolated"] if m["relmse_extrapolated"] is not None else m["relmse"]
        print(f"{label:>14s}  relMSE {error:.4f}  x{m['brightness_ratio']:.3f} "
              f"(dim {b['dim']:.3f} / mid {b['mid']:.3f} / bright {b['bright']:.3f})", flush=True)

    resolutions = [int(r) for r in args.resolution.split(",")]
    images = {}
    for n in resolutions:
        scene = apply_overrides(base, resolution=n)
        images[n] = popvol.render(scene, popvol.solve(scene))
        row(f"{n} cells", images[n])
    for n, m in zip(resolutions, resolutions[1:]):
        row(f"2 I{m} - I{n}", 2 * images[m] - images[n])


if __name__ == "__main__":
    main()
