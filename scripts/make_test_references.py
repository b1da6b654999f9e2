"""Render the Mitsuba 3 references that tests compare against (run from the repository root):

    python scripts/make_test_references.py [--spp 65536]

tests/fixtures/regression_cloud.exr (+ .json, .npz sidecars): the scene
tests/fixtures/regression_cloud.toml, 64x64, converged far below the regression test's margin
(its noise relMSE is printed and stored beside it). Needs popvol[reference]; the LLVM variant
needs a system libLLVM >= 16 (apt-get install libllvm19).
"""
import argparse
from pathlib import Path

import popvol
from popvol.reference import render_reference

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "fixtures"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=65536)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()
    scene = popvol.load_scene(FIXTURES / "regression_cloud.toml")
    out = FIXTURES / "regression_cloud.exr"
    ref = render_reference(scene, out, args.spp, args.variant, passes=16, resume=False)
    print(f"{out}: {ref.spp} spp, noise relMSE {ref.noise_relmse():.2g}")


if __name__ == "__main__":
    main()
