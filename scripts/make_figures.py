"""Regenerate the figures in docs/figures (run from the repository root):

    python scripts/make_figures.py

- supplement_fig1.png: f_hg and 2 pi F_hg for g = 0, 0.5, 0.9 (supplement Fig. 1);
- demo.png: the built-in demo scene at 480x270 (what `popvol render -o cloud.png` draws);
- wdas_front.png: examples/wdas_front.toml (the WDAS cloud, sun behind the camera, a sky) at
  480x270, if ../shared data is beside the checkout;
- demo_sky.png: examples/demo_sky.toml (the demo cloud under a sun and a sky) at 480x270;
- demo_envmap.png: examples/demo_envmap.toml (the demo cloud under an HDR map) at 480x270;
- smoke1_point.png: examples/smoke1_point.toml (a point light inside smoke) at 240x320.
"""
from pathlib import Path

import popvol
from popvol.hg import plot_supplement_figure

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "figures"


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    plot_supplement_figure(OUT / "supplement_fig1.png")
    print(OUT / "supplement_fig1.png")
    scenes = {"demo.png": None, "wdas_front.png": ROOT / "examples" / "wdas_front.toml",
              "demo_sky.png": ROOT / "examples" / "demo_sky.toml",
              "demo_envmap.png": ROOT / "examples" / "demo_envmap.toml",
              "smoke1_point.png": ROOT / "examples" / "smoke1_point.toml"}
    for name, path in scenes.items():
        size = (240, 320) if name == "smoke1_point.png" else (480, 270)
        try:
            scene = popvol.load_scene(path, width=size[0], height=size[1])
        except popvol.PopvolError as e:
            print(f"skipped {name}: {e}")
            continue
        image = popvol.render(scene, popvol.solve(scene))
        popvol.write_image(OUT / name, image, scene.method.exposure)
        print(OUT / name)


if __name__ == "__main__":
    main()
