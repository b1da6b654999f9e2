"""Render the Mitsuba 3 references that tests compare against (run from the repository root):

    python scripts/make_test_references.py [NAME ...]

tests/fixtures/NAME.exr (+ .json, .npz sidecars) of the scene tests/fixtures/NAME.toml, each
converged far below its test's margin (its noise relMSE is printed and stored beside it):
regression_cloud (64x64, 65536 spp; tests/test_regression.py) and sky_cloud (64x64, 16384 spp;
tests/test_environment.py); all of them without NAME.
Needs popvol[reference]; the LLVM variant needs a system libLLVM >= 16 (apt-get install libllvm19).
"""
import argparse
from pathlib import Path

import popvol
from popvol.reference import render_reference

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "fixtures"
#: the fixtures and their samples per pixel
SPP = {"regression_cloud": 65536, "sky_cloud": 16384}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("names", nargs="*", help=f"fixtures to render: {', '.join(sorted(SPP))} (default: all)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()
    unknown = sorted(set(args.names) - set(SPP))
    if unknown:
        ap.error(f"no fixture {', '.join(unknown)}; there are {', '.join(sorted(SPP))}")
    for name in args.names or sorted(SPP):
        scene = popvol.load_scene(FIXTURES / f"{name}.toml")
        out = FIXTURES / f"{name}.exr"
        ref = render_reference(scene, out, SPP[name], args.variant, passes=16, resume=False)
        print(f"{out}: {ref.spp} spp, noise relMSE {ref.noise_relmse():.2g}")


if __name__ == "__main__":
    main()
