"""A white cloud under a uniform sky, which should render at the sky's radiance: the pixels that
see it, per walk, density and grid.

The scene of tests/test_gather.py (``sky_scene``: a 16 x 12 x 16 blob, albedo 1, g 0.6 by default,
under a uniform sky of radiance 1 split into ``--lights`` lights, the last scattering gathered from
64 directions). A medium that absorbs nothing leaves an isotropic radiance field unchanged, so every
pixel that sees it should be about 1. Prints a Markdown table: mean (min-max) over the pixels
whose camera ray crosses an optical depth above 0.05.

    python scripts/white_medium.py [--scales 8,12,30] [--resolutions 16] [--ordinates 18,6] [--g 0.6] [--lights 32]

``--resolutions``: cells of the light domains (the medium stays 16 x 12 x 16 voxels, and a domain
has no more cells than the medium has voxels along it).
``--scales``: density scales (the densest voxel is 0.125 x the scale mean free paths across; above
Medium.transport_depth_cap(), 2 at g 0.6 and 6.7 at g 0.85, it is capped for light transport:
docs/METHOD.md, "Optically thick voxels"). ``--lights``: the lights the sky is split into (with
few, the split itself darkens the cloud: docs/METHOD.md, "Environment lights").
"""
import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import popvol                                # noqa: E402
from popvol import metrics                   # noqa: E402
from popvol.scene import apply_overrides     # noqa: E402
from test_gather import sky_scene            # noqa: E402


def pixels(scale: float, resolution: int, ordinates: int, g: float, lights: int):
    """The red channel of the pixels that see the cloud, float32 (n,)."""
    scene = sky_scene((1.0, 1.0, 1.0), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), lights=lights, albedo=1.0, g=g,
                      scale=scale, resolution=16)
    scene = apply_overrides(scene, resolution=resolution, gather=64, ordinates=ordinates)
    img = popvol.render(scene, popvol.solve(scene))
    return img[metrics.camera_optical_depth(scene) > 0.05][:, 0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="8,12,30")
    ap.add_argument("--resolutions", default="16")
    ap.add_argument("--ordinates", default="18,6")
    ap.add_argument("--g", type=float, default=0.6, help="the cloud's g")
    ap.add_argument("--lights", type=int, default=32, help="lights the sky is split into")
    args = ap.parse_args()
    resolutions = [int(x) for x in args.resolutions.split(",")]
    ordinates = [int(x) for x in args.ordinates.split(",")]
    print("| scale | densest voxel, mean free paths | " + " | ".join(
        f"{o} ordinates, {n} cells" for o in ordinates for n in resolutions) + " |")
    print("|---" * (2 + len(ordinates) * len(resolutions)) + "|")
    for scale in (float(x) for x in args.scales.split(",")):
        cells = []
        for o in ordinates:
            for n in resolutions:
                v = pixels(scale, n, o, args.g, args.lights)
                cells.append(f"{v.mean():.3f} ({v.min():.3f}-{v.max():.3f})")
        depth = sky_scene((1.0,) * 3, (1.0,) * 3, (1.0,) * 3, albedo=1.0, g=args.g, scale=scale,
                          resolution=16).medium.max_voxel_optical_depth()
        print(f"| {scale:g} | {depth:.2f} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
