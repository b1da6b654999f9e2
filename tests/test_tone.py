"""Tone curves of the PNG (ACES 2.0 through OpenColorIO, or clip) and the auto exposure."""
import math
import subprocess
import sys
import warnings

import numpy as np
import pytest

from popvol.errors import PopvolError
from popvol.io import images


def grey(values) -> np.ndarray:
    """float32 (1, N, 3) grey pixels."""
    v = np.asarray(values, np.float64).reshape(1, -1, 1)
    return np.repeat(v, 3, axis=2).astype(np.float32)


def srgb(x):
    """sRGB encoding written out here (IEC 61966-2-1), independent of popvol's."""
    x = np.asarray(x, np.float64)
    out = np.empty_like(x)
    lo = x <= 0.0031308
    out[lo] = 12.92 * x[lo]
    out[~lo] = 1.055 * x[~lo] ** (1 / 2.4) - 0.055
    return out


# -- tone "clip": the formula popvol had before, bit for bit ----------------------------------

@pytest.mark.parametrize("exposure", [0.0, 0.5, -2.0, 3.25])
def test_clip_is_exposure_clip_and_srgb(exposure):
    img = np.random.default_rng(3).gamma(0.7, 0.6, (9, 13, 3)).astype(np.float32)
    expected = np.round(srgb(np.clip(img.astype(np.float64) * 2.0**exposure, 0, 1)) * 255).astype(np.uint8)
    np.testing.assert_array_equal(images.tonemap(img, exposure, "clip"), expected)


# -- tone "aces": OpenColorIO's ACES 2.0 SDR sRGB view -----------------------------------------

def test_aces_is_monotone_maps_black_to_black_and_rolls_off_highlights():
    ramp = np.concatenate([[0.0], np.geomspace(1e-4, 1e4, 4000)])
    out = images.tonemap(grey(ramp), 0.0, "aces")[0, :, 0].astype(int)
    assert out[0] == 0
    assert np.all(np.diff(out) >= 0)
    assert out[-1] == 255 and 200 < out[np.searchsorted(ramp, 2.0)] < 255
    # highlights at 1x, 2x, 4x, 8x: clip shows them all as white, ACES keeps them apart
    hi = grey([1.0, 2.0, 4.0, 8.0])
    assert images.tonemap(hi, 0.0, "clip")[0, :, 0].tolist() == [255] * 4
    aces = images.tonemap(hi, 0.0, "aces")[0, :, 0].tolist()
    assert len(set(aces)) == 4 and max(aces) < 255, aces


def test_aces_mid_grey_shows_at_ten_percent_of_white():
    """ACES 2.0's SDR output puts scene mid grey 0.18 at 10 nits of a 100-nit display: display
    linear 0.1, sRGB-encoded 0.349, code 89 (the cg-config's sRGB display is piecewise sRGB)."""
    code = images.tonemap(grey([0.18]), 0.0, "aces")[0, 0, 0]
    assert abs(int(code) - round(srgb(0.1) * 255)) <= 1, code


def test_aces_is_neutral_on_greys():
    out = images.tonemap(grey(np.geomspace(1e-3, 100, 300)), 0.0, "aces")
    assert np.array_equal(out[..., 0], out[..., 1]) and np.array_equal(out[..., 0], out[..., 2])


def test_aces_is_chunked_alike_and_survives_huge_exposures(monkeypatch):
    img = np.random.default_rng(5).gamma(0.7, 0.6, (37, 29, 3)).astype(np.float32)
    whole = images.tonemap(img, 0.3, "aces")
    monkeypatch.setattr(images, "_CHUNK", 100)
    np.testing.assert_array_equal(images.tonemap(img, 0.3, "aces"), whole)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.all(images.tonemap(img * 1e30, 64.0, "aces")[img.max(-1) > 0] == 255)


def test_unknown_tone_is_refused():
    with pytest.raises(PopvolError, match="tone 'filmic' is unknown"):
        images.tonemap(grey([0.5]), 0.0, "filmic")
    with pytest.raises(PopvolError, match="'bright' must be a number of stops or 'auto'"):
        images.tonemap(grey([0.5]), "bright")


# -- auto exposure ----------------------------------------------------------------------------

def test_auto_places_the_99th_percentile_of_lit_luminance_at_the_target():
    rng = np.random.default_rng(7)
    img = rng.gamma(1.0, 0.3, (40, 50, 3)).astype(np.float32)
    img[:10] = 0                                     # black background: not metered
    y = img[10:].astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    for tone in ("aces", "clip"):
        want = math.log2(images.AUTO_TARGET[tone] / np.percentile(y, 99))
        assert images.auto_exposure(img, tone=tone) == pytest.approx(want, abs=1e-9)
    # NaN and inf are ignored; a mask narrows the metered pixels
    bad = img.copy()
    bad[0, 0] = np.nan
    bad[0, 1] = np.inf
    assert images.auto_exposure(bad) == pytest.approx(images.auto_exposure(img), abs=1e-12)
    mask = np.zeros(img.shape[:2], bool)
    mask[20:] = True
    want = math.log2(1.44 / np.percentile(y[10:], 99))
    assert images.auto_exposure(img, mask) == pytest.approx(want, abs=1e-9)


def test_auto_is_scale_free():
    img = np.random.default_rng(11).gamma(0.8, 0.5, (30, 40, 3)).astype(np.float32)
    for tone in ("aces", "clip"):
        ref = images.tonemap(img, "auto", tone).astype(int)
        for k in (1e-3, 1e3):
            out = images.tonemap((img * k).astype(np.float32), "auto", tone).astype(int)
            assert np.abs(out - ref).max() <= 1, (tone, k)


def test_all_black_image_is_black_without_warning(tmp_path):
    black = np.zeros((6, 8, 3), np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert images.auto_exposure(black) == 0.0
        assert images.auto_exposure(np.full((2, 2, 3), np.nan)) == 0.0
        for tone in images.TONES:
            assert not images.tonemap(black, "auto", tone).any()
        images.write_image(tmp_path / "black.png", black)
    from PIL import Image
    assert not np.asarray(Image.open(tmp_path / "black.png")).any()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0])
def test_writers_refuse_bad_pixels_before_tone_mapping(tmp_path, bad):
    img = np.ones((3, 4, 3), np.float32)
    img[1, 2, 0] = bad
    for name in ("x.png", "x.exr"):
        with pytest.raises(PopvolError, match=r"image has 1 pixels that are NaN, infinite, negative or beyond "
                                              r"float32's range \(first at row 1, column 2"):
            images.write_image(tmp_path / name, img)
        assert not (tmp_path / name).exists()


@pytest.mark.parametrize("image, options, words", [
    (np.full((2, 2, 3), 1e39), {}, "beyond float32's range"),           # was written as inf in the EXR
    (np.zeros((0, 5, 3)), {}, "image has no pixels"),
    (np.zeros((2, 2, 3), complex), {}, "must hold real numbers, not complex128"),
    (np.zeros((2, 2, 3), object), {}, "must hold real numbers, not object"),
    (np.ones((2, 2, 3)), {"exposure": float("nan")}, "exposure = nan must be 'auto' or a finite number"),
    (np.ones((2, 2, 3)), {"exposure": 1e6}, "[-64, 64]"),
    (np.ones((2, 2, 3)), {"exposure": None}, "exposure = None"),
    (np.ones((2, 2, 3)), {"exr": "x.png"}, "must name an .exr file"),
    (np.ones((2, 2, 3)), {"exr": 5}, "write_image: exr must be a file name (str or Path), not int"),
])
def test_write_image_refuses_what_it_cannot_write_in_one_line(tmp_path, image, options, words):
    """write_image from the API: each bad image or argument is one PopvolError line (they were
    TypeErrors, OverflowErrors, silent black or white PNGs and an EXR of inf), nothing written."""
    with pytest.raises(PopvolError) as e:
        images.write_image(tmp_path / "x.png", image, **options)
    assert words in str(e.value) and "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_the_exposure_range_is_the_knobs():
    """io.images.EXPOSURE_STOPS, what write_image takes, is method.exposure's range."""
    from popvol.method import KNOB
    assert KNOB["exposure"].allowed == (-images.EXPOSURE_STOPS, images.EXPOSURE_STOPS)


def test_write_image_with_an_exr_that_is_a_folder_replaces_nothing(tmp_path):
    """An ``exr`` that names a folder: refused, naming it, before the PNG is replaced (the PNG
    was replaced, then the rename of the EXR failed, against the promise that neither is)."""
    images.write_image(tmp_path / "keep.png", np.ones((2, 2, 3)))
    before = (tmp_path / "keep.png").read_bytes()
    (tmp_path / "sub.exr").mkdir()
    with pytest.raises(PopvolError, match=r"sub.exr: is a folder, not a file"):
        images.write_image(tmp_path / "keep.png", np.full((2, 2, 3), 0.25), exr=tmp_path / "sub.exr")
    assert (tmp_path / "keep.png").read_bytes() == before


def test_exr_stays_linear_whatever_the_tone(tmp_path):
    img = np.random.default_rng(2).gamma(0.7, 3.0, (5, 7, 3)).astype(np.float32)
    images.write_image(tmp_path / "a.exr", img, exposure=3.0, tone="aces")
    np.testing.assert_array_equal(images.read_exr(tmp_path / "a.exr"), img)


# -- the knobs ---------------------------------------------------------------------------------

def test_exposure_and_tone_knobs():
    from popvol.method import KNOB, Method, method_tables
    m = Method()
    assert (m.exposure, m.tone) == ("auto", "aces")
    k = KNOB["exposure"]
    assert k.check("auto", "s") == "auto" and k.check(2, "s") == 2.0
    for bad in ("Auto", "1.5", 65, True, None, float("nan")):
        with pytest.raises(PopvolError, match=r"^s: method\.exposure = .* must be 'auto' or a finite number in \[-64, 64\]$"):
            k.check(bad, "s")
    with pytest.raises(PopvolError, match=r"method\.tone = 'agx' must be one of 'aces', 'clip'"):
        KNOB["tone"].check("agx", "s")
    assert method_tables(Method())["method"]["exposure"] == "auto"
    assert method_tables(Method(exposure=1))["method"]["exposure"] == 1.0


def test_comparison_figure_tone_maps_both_images_with_the_reference_s_exposure(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from popvol import metrics
    seen = []
    real = images.tonemap
    monkeypatch.setattr(images, "tonemap", lambda rgb, exposure="auto", tone="aces":
                        seen.append((exposure, tone)) or real(rgb, exposure, tone))
    rng = np.random.default_rng(4)
    ref = rng.gamma(1.0, 0.3, (12, 16, 3)).astype(np.float32)
    img = 3 * ref                                    # brighter: its own auto would differ
    metrics.comparison_figure(tmp_path / "f.png", img, ref, "auto", "t", tone="clip")
    assert seen == [(images.auto_exposure(ref, tone="clip"), "clip")] * 2


# -- command line ------------------------------------------------------------------------------

SCENE = """
[medium]
type = "procedural"
resolution = 16
[[lights]]
direction = [-0.6, -0.7, 0.3]
irradiance = 3.0
[background]
radiance = [0.2, 0.3, 0.5]
[camera]
width = 40
height = 24
[method]
resolution = 16
"""


def popvol(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "popvol.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd)


def test_cli_tone_and_exposure_options(tmp_path):
    from PIL import Image
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    r = popvol("render", scene, "-o", tmp_path / "aces.png", "--exr", tmp_path / "lin.exr")
    assert r.returncode == 0, r.stderr
    for args, name in ((["--tone", "clip"], "clip.png"), (["--exposure", "auto", "--tone", "aces"], "auto.png"),
                       (["--exposure", "-1.5"], "num.png")):
        r = popvol("render", scene, "-o", tmp_path / name, *args)
        assert r.returncode == 0, r.stderr
    px = {n: np.asarray(Image.open(tmp_path / f"{n}.png")) for n in ("aces", "clip", "auto", "num")}
    lin = images.read_exr(tmp_path / "lin.exr")
    assert np.array_equal(px["aces"], px["auto"])                      # the defaults: auto, aces
    assert np.array_equal(px["aces"], images.tonemap(lin, "auto", "aces"))
    assert np.array_equal(px["clip"], images.tonemap(lin, "auto", "clip"))
    assert np.array_equal(px["num"], images.tonemap(lin, -1.5, "aces"))
    assert not np.array_equal(px["aces"], px["clip"])
    for args, msg in ((["--exposure", "abc"], "--exposure = 'abc' must be 'auto' or a finite number in [-64, 64]"),
                      (["--exposure", "99"], "--exposure = 99.0 must be 'auto' or a finite number in [-64, 64]"),
                      (["--tone", "agx"], "--tone = 'agx' must be one of 'aces', 'clip'")):
        r = popvol("render", scene, "-o", tmp_path / "x.png", *args)
        assert r.returncode == 2 and r.stderr.strip() == f"popvol: error: popvol render: {msg}", r.stderr
        assert not (tmp_path / "x.png").exists()


def test_viewer_on_an_auto_scene_saves_a_view_that_renders_the_same_png(tmp_path):
    pytest.importorskip("tomli_w")
    from dataclasses import replace
    from PIL import Image
    from popvol.viewer.engine import FULL, Engine
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    e = Engine(scene, resolution=16, draft_resolution=8)
    assert e.initial.exposure == 0.0 and e.exposure_auto
    s = replace(e.initial, exposure=0.5, density=2.0)
    f = e.frame(s, FULL)
    assert f.exposure == pytest.approx(0.5 + images.auto_exposure(f.image))
    png, toml = e.save(s, tmp_path)
    r = popvol("render", toml, "-o", tmp_path / "again.png")
    assert r.returncode == 0, r.stderr
    saved = np.asarray(Image.open(png))
    assert np.array_equal(saved, np.asarray(Image.open(tmp_path / "again.png")))
    assert np.array_equal(saved, images.tonemap(f.image, f.exposure))


def test_aces_table_is_within_one_code_of_the_exact_transform():
    """tonemap applies ACES as a 65^3 table (io/images.py); OpenColorIO's exact transform is the
    independent reference: greys over 27 stops and cloud-like tints (+-40 % per channel) land on
    the same code or the next one."""
    rng = np.random.default_rng(3)
    greys = np.repeat(np.geomspace(1e-4, 1e4, 2000)[:, None], 3, axis=1)
    tints = np.geomspace(1e-3, 300, 6000)[:, None] * rng.uniform(0.6, 1.4, (6000, 3))
    x = np.concatenate([greys, tints]).astype(np.float32)[None]
    exact = np.round(np.clip(images.aces_exact(x), 0.0, 1.0) * 255).astype(int)
    table = images.tonemap(x, 0.0, "aces").astype(int)
    assert np.abs(table - exact).max() <= 1
    assert (table != exact).mean() < 0.15
