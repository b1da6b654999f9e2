"""Write docs/figures/viewer.png: a screenshot of `popvol view` on the demo sky scene, taken in
Debian's chromium through Playwright (as tests/test_viewer_browser.py does).

    python scripts/viewer_screenshot.py [SCENE.toml]

Needs the viewer and test extras (pip install '.[viewer,test]') and `apt-get install chromium`.
"""
import os
import shutil
import sys
from pathlib import Path

from playwright.sync_api import sync_playwright

from popvol.viewer.engine import Engine
from popvol.viewer.server import running

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def main():
    scene = Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else Path("examples/demo_sky.toml")
    os.chdir(ROOT)                   # the page shows the scene's path: keep it relative
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    engine = Engine(scene, width=640, height=360)
    out = ROOT / "docs" / "figures" / "viewer.png"
    with running(engine, ROOT / "build") as url, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)
        page = browser.new_page(viewport={"width": 1100, "height": 800})
        page.goto(url)
        page.wait_for_function("() => popvolView.lastFrame && popvolView.lastFrame.level === 'full'",
                               timeout=120_000)
        page.screenshot(path=str(out))
        browser.close()
    print(out)


if __name__ == "__main__":
    main()
