"""`popvol view` in a real browser: Debian's chromium driven by Playwright (installed by
.ci/run; never `playwright install`). Skips with the reason when either is missing."""
import base64
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("starlette", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("uvicorn", reason="the viewer extra is not installed (pip install '.[viewer]')")
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install '.[test]')")

from test_viewer import write_sequence_scene, write_small_scene

import popvol
from popvol.viewer.engine import Engine
from popvol.viewer.server import running

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                                "(apt-get install chromium; .ci/run does it)")


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    folder = tmp_path_factory.mktemp("browser")
    engine = Engine(write_small_scene(folder), width=96, height=54, resolution=24, draft_resolution=12)
    saves = folder / "saves"
    saves.mkdir()
    with running(engine, saves, refine_delay=0.2) as url:
        yield url, engine, saves


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def page(browser, viewer):
    url = viewer[0]
    page = browser.new_page(viewport={"width": 1000, "height": 700})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    wait_full_frame(page, after=0)
    yield page
    page.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


def wait_full_frame(page, after: int):
    """Wait until the page shows a full-quality frame of a version > ``after`` - 1."""
    page.wait_for_function(f"() => popvolView.lastFrame && popvolView.lastFrame.level === 'full' "
                           f"&& popvolView.lastFrame.version >= {after}", timeout=60_000)
    return page.evaluate("() => popvolView.lastFrame.version")


def shown_pixels(page) -> np.ndarray:
    """The pixels of the image the page shows, uint8 (H, W, 3), decoded from its data URL."""
    from PIL import Image
    src = page.get_attribute("#view", "src")
    assert src.startswith("data:image/png;base64,")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1]))).convert("RGB"))


def changed_pixels(a: np.ndarray, b: np.ndarray) -> int:
    """How many pixels differ by more than 2 levels in some channel."""
    return int((np.abs(a.astype(int) - b).max(axis=2) > 2).sum())


def drag(page, selector, start, end, steps=8):
    """Press at ``start`` (fractions of the element's box), move to ``end``, release."""
    box = page.locator(selector).bounding_box()

    def at(f):
        return box["x"] + f[0] * box["width"], box["y"] + f[1] * box["height"]

    page.mouse.move(*at(start))
    page.mouse.down()
    for i in range(1, steps + 1):
        t = i / steps
        page.mouse.move(*at((start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))))
        page.wait_for_timeout(15)
    page.mouse.up()


def test_dragging_the_sun_changes_image_and_readout(page, viewer):
    _, engine, _ = viewer
    before_img = shown_pixels(page)
    before_text = page.inner_text("#readout")
    before_sun = page.evaluate("() => popvolView.settings.sun_azimuth")
    version = page.evaluate("() => popvolView.lastFrame.version")
    solves = engine.solves
    drag(page, "#sky", (0.5, 0.8), (0.85, 0.4))
    # the preview propagates at the view's 24 cells; the full frame then reuses its solution
    page.wait_for_function(f"() => popvolView.lastFrame.level === 'preview' && popvolView.lastFrame.version > {version}",
                           timeout=60_000)
    preview_text = page.inner_text("#readout")
    assert re.search(r"preview 96×54 .*\npropagation \d+ ms \(24 cells\)", preview_text), preview_text
    assert "preview (gathering the last bounce)" in page.inner_text("#status")
    wait_full_frame(page, after=version + 1)
    after_text = page.inner_text("#readout")
    assert after_text != before_text
    assert re.search(r"propagation 0 ms \(reused\)", after_text), after_text
    assert re.search(r"rendering \d+ ms", after_text)
    assert engine.solves > solves
    assert page.evaluate("() => popvolView.lastFrame.settings.sun_azimuth") != before_sun
    after_img = shown_pixels(page)
    assert after_img.shape == before_img.shape == (54, 96, 3)
    assert changed_pixels(after_img, before_img) > 100


def test_orbit_and_zoom_only_render(page, viewer):
    _, engine, _ = viewer
    before = shown_pixels(page)
    version = page.evaluate("() => popvolView.lastFrame.version")
    solves = engine.solves
    drag(page, "#view", (0.3, 0.5), (0.7, 0.6))
    version = wait_full_frame(page, after=version + 1)
    orbited = shown_pixels(page)
    assert changed_pixels(orbited, before) > 100
    box = page.locator("#view").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.wheel(0, 400)
    wait_full_frame(page, after=version + 1)
    assert changed_pixels(shown_pixels(page), orbited) > 100
    assert engine.solves == solves                              # camera moves never propagate
    assert "0 ms (reused)" in page.inner_text("#readout")


def test_malformed_message_shows_an_error_and_the_page_keeps_working(page):
    page.evaluate("() => popvolView.socket.send('{not json')")
    page.wait_for_selector("#error:not([hidden])")
    assert "not valid JSON" in page.inner_text("#error")
    page.evaluate("() => popvolView.socket.send(JSON.stringify({type: 'set', settings: {g: 1}}))")
    page.wait_for_function("() => document.getElementById('error').textContent.includes('must be a finite number in (-1, 1)')")
    version = page.evaluate("() => popvolView.lastFrame.version")
    page.locator("#density").fill("0.5")                        # a slider: 10^0.5 x density
    wait_full_frame(page, after=version + 1)
    assert page.evaluate("() => popvolView.lastFrame.settings.density") == pytest.approx(10**0.5)


def test_saved_toml_renders_the_image_the_page_shows(page, viewer):
    _, _, saves = viewer
    page.locator("#albedo").fill("0.7")
    page.locator("#exposure").fill("1.5")
    page.wait_for_function("() => { const f = popvolView.lastFrame; return f.level === 'full' && "
                           "f.settings.albedo === 0.7 && f.settings.exposure === 1.5; }", timeout=60_000)
    shown = shown_pixels(page)
    page.click("#save")
    page.wait_for_function("() => document.getElementById('saved').textContent.startsWith('saved ')")
    toml = Path(re.search(r"and (\S+\.toml)$", page.inner_text("#saved")).group(1))
    assert toml.parent == saves
    scene = popvol.load_scene(toml)
    assert scene.medium.albedo[0] == 0.7 and scene.method.exposure == 1.5
    from popvol.io.images import tonemap
    image = popvol.render(scene, popvol.solve(scene))
    assert np.array_equal(tonemap(image, scene.method.exposure), shown)


@pytest.fixture(scope="module")
def seq_viewer(tmp_path_factory):
    folder = tmp_path_factory.mktemp("browser-seq")
    engine = Engine(write_sequence_scene(folder), resolution=16, draft_resolution=8)
    with running(engine, folder, refine_delay=0.2) as url:
        yield url, engine


def test_a_sequence_shows_the_frame_slider_and_play_advances_the_frame(browser, page, seq_viewer):
    assert page.locator("#sequence-controls").is_hidden()             # the still scene: no controls
    assert page.locator("#play").is_hidden()
    url, engine = seq_viewer
    seq = browser.new_page(viewport={"width": 1000, "height": 700})
    errors = []
    seq.on("pageerror", lambda e: errors.append(str(e)))
    try:
        seq.goto(url)
        wait_full_frame(seq, after=0)
        assert seq.locator("#frame").is_visible() and seq.locator("#play").is_visible()
        slider = seq.locator("#frame")
        assert [slider.get_attribute(a) for a in ("min", "max", "step")] == ["1", "5", "2"]
        assert seq.inner_text("#frame-out") == "1"
        assert seq.inner_text("#readout").startswith("frame 1 of 1-5:2 · full")
        seq.click("#play")
        # the frame number shown advances 1 -> 3 -> 5 and loops back to 1
        seq.wait_for_function("""() => {
            const seen = (window.seenFrames ||= []);
            const n = Number(document.getElementById('frame-out').textContent);
            if (seen[seen.length - 1] !== n) seen.push(n);
            return seen.join(',').includes('3,5,1');
        }""", timeout=60_000)
        assert re.match(r"frame [135] of 1-5:2 · draft 24×14", seq.inner_text("#readout"))
        seq.click("#play")                                                # pause: the full frame follows
        assert seq.get_attribute("#play", "aria-pressed") == "false"
        shown = int(seq.inner_text("#frame-out"))
        seq.wait_for_function(f"() => popvolView.lastFrame.level === 'full' && popvolView.lastFrame.frame === {shown}",
                              timeout=60_000)
        assert seq.inner_text("#readout").startswith(f"frame {shown} of 1-5:2 · full 48×28")
        assert not errors, f"JavaScript errors on the page: {errors}"
    finally:
        seq.close()
