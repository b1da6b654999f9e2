"""The metric of popvol against a reference (popvol.metrics): relMSE on the pixels that see the
medium with an epsilon from the reference's own brightness, so that it is unchanged when both
images are scaled; brightness ratios overall and in three luminance bands; the reference's
noise in the same metric; the optical-depth mask; ``popvol compare``'s output."""
import json

import numpy as np
import pytest

import popvol
from popvol import metrics
from popvol.camera import Camera
from popvol.errors import PopvolError
from popvol.medium import Medium
from popvol.reference import Reference
from popvol.scene import Scene


@pytest.fixture
def pair(rng):
    """A dim reference (pixels ~1e-3 to 0.1) on a black border, popvol off by up to 30 %, the
    reference's variance of the mean, and the mask of the non-black pixels; all float64."""
    ref = np.zeros((20, 30, 3))
    ref[3:17, 4:26] = 10.0 ** rng.uniform(-3, -1, (14, 22, 1)) * rng.uniform(0.8, 1.2, (14, 22, 3))
    img = ref * rng.uniform(0.7, 1.3, ref.shape)
    var = (0.01 * ref) ** 2 * rng.uniform(0.5, 2.0, ref.shape)
    mask = np.zeros((20, 30), bool)
    mask[3:17, 4:26] = True
    return img, ref, var, mask


@pytest.mark.parametrize("factor", [1e-3, 1e3])
def test_every_metric_is_unchanged_when_both_images_are_scaled(pair, factor):
    img, ref, var, mask = pair
    halves = (ref * 1.05, ref * 0.9)
    base = metrics.compare(img, ref, mask, var, halves, (8, 4))
    scaled = metrics.compare(factor * img, factor * ref, mask, factor ** 2 * var, tuple(factor * h for h in halves),
                             (8, 4))
    for key in ("relmse", "brightness_ratio", "reference_noise_relmse", "relmse_extrapolated",
                "reference_noise_observed"):
        assert scaled[key] == pytest.approx(base[key], rel=1e-12), key
    for name in ("dim", "mid", "bright"):
        assert scaled["brightness_bands"][name] == pytest.approx(base["brightness_bands"][name], rel=1e-12)
    assert scaled["relmse_eps"] == pytest.approx(factor ** 2 * base["relmse_eps"], rel=1e-12)
    # the fallback mask (reference luminance > 1 % of its maximum) scales with the images too
    assert metrics.relmse(factor * img, factor * ref) == pytest.approx(metrics.relmse(img, ref), rel=1e-12)
    np.testing.assert_array_equal(metrics.luminance_mask(factor * ref), metrics.luminance_mask(ref))
    # scaling one image alone is an error of brightness, and the metric sees it
    assert metrics.relmse(factor * img, ref, mask) > 10 * base["relmse"]
    assert metrics.relmse(img, factor * ref, mask) > 10 * base["relmse"]
    assert metrics.brightness_ratio(factor * img, ref, mask) == pytest.approx(factor * base["brightness_ratio"])


def test_relmse_is_the_documented_mean_on_the_mask(pair):
    """Per channel (img - ref)^2 / (ref^2 + eps) averaged over the masked pixels and the channels,
    eps = 0.01 (mean reference luminance on the mask)^2; the black border adds nothing."""
    img, ref, var, mask = pair
    y = ref @ np.array([0.2126, 0.7152, 0.0722])
    eps = 0.01 * y[mask].mean() ** 2
    assert metrics.relmse_eps(ref, mask) == pytest.approx(eps, rel=1e-12)
    expected = np.mean((img[mask] - ref[mask]) ** 2 / (ref[mask] ** 2 + eps))
    assert metrics.relmse(img, ref, mask) == pytest.approx(expected, rel=1e-12)
    assert metrics.noise_relmse(var, ref, mask) == pytest.approx(np.mean(var[mask] / (ref[mask] ** 2 + eps)), rel=1e-12)
    # a uniform 10 % error reads as nearly 0.01 (less only on the dimmest pixels, ref^2 < eps);
    # the old absolute epsilon of 0.01 over the whole frame read it 20 times smaller
    assert 0.006 < metrics.relmse(1.1 * ref, ref, mask) < 0.01
    assert np.mean(0.01 * ref ** 2 / (ref ** 2 + 0.01)) < 0.1 * metrics.relmse(1.1 * ref, ref, mask)
    # the black border is not in the metric: cropping it away changes nothing
    crop = (slice(3, 17), slice(4, 26))
    assert metrics.relmse(img[crop], ref[crop], mask[crop]) == pytest.approx(metrics.relmse(img, ref, mask), rel=1e-12)
    assert metrics.relmse(ref, ref, mask) == 0
    pm = metrics.relmse_map(img, ref, mask)
    assert np.isnan(pm[~mask]).all() and np.nanmean(pm) == pytest.approx(expected, rel=1e-12)


def test_bands_split_the_mask_50_40_10_by_reference_luminance(pair):
    img, ref, var, mask = pair
    b = metrics.bands(ref, mask)
    n = mask.sum()                                          # 308 pixels
    assert [int(b[k].sum()) for k in ("dim", "mid", "bright")] == [n // 2, int(0.9 * n) - n // 2, n - int(0.9 * n)]
    assert not (b["dim"] & b["mid"]).any() and not (b["mid"] & b["bright"]).any()
    assert ((b["dim"] | b["mid"] | b["bright"]) == mask).all()
    y = metrics.luminance(ref)
    assert y[b["dim"]].max() <= y[b["mid"]].min() and y[b["mid"]].max() <= y[b["bright"]].min()
    # the brightest 10 % 20 % too dark, the rest right
    test = ref * np.where(b["bright"], 0.8, 1.0)[..., None]
    r = metrics.band_ratios(test, ref, mask)
    assert r["dim"] == pytest.approx(1.0) and r["mid"] == pytest.approx(1.0) and r["bright"] == pytest.approx(0.8)
    overall = metrics.brightness_ratio(test, ref, mask)
    assert 0.8 < overall < 1.0
    assert overall == pytest.approx((y[mask].sum() - 0.2 * y[b["bright"]].sum()) / y[mask].sum())
    ratio = metrics.ratio_map(test, ref, mask)
    assert np.isnan(ratio[~mask]).all()
    np.testing.assert_allclose(ratio[b["bright"]], 0.8)
    np.testing.assert_allclose(ratio[b["dim"] | b["mid"]], 1.0)


def test_bands_ranked_on_an_independent_half_are_not_biased_by_the_references_noise(rng):
    """popvol's image equal to the truth (a factor 3 between its dimmest and brightest pixels),
    against a reference with 14 % noise per pixel (two halves of 20 % each): ranked
    by the reference itself, its brightest tenth is the pixels whose noise came out high, so the
    truth looks too dark there and too bright in the dim half. Ranked on one independent half
    and measured on the other, the bands are x1 within their own noise; and a real flattening of
    the contrast (the truth to the power 0.6) still shows, a little less (the half's noise mixes
    some pixels of the next band into each: x0.87 in the brightest tenth against x0.84 ranked by
    the truth)."""
    shape = (60, 80, 3)
    truth = np.repeat(10.0 ** rng.uniform(-2.5, -2.0, shape[:2] + (1,)), 3, axis=-1)
    a = truth * (1.0 + 0.2 * rng.standard_normal(shape[:2] + (1,)))
    b = truth * (1.0 + 0.2 * rng.standard_normal(shape[:2] + (1,)))
    ref = 0.5 * (a + b)
    mask = np.ones(shape[:2], bool)
    biased = metrics.band_ratios(truth, ref, mask)
    assert biased["bright"] < 0.95 and biased["dim"] > 1.02
    fair = metrics.band_ratios(truth, ref, mask, halves=(a, b))
    assert all(abs(v - 1.0) < 0.02 for v in fair.values()), fair
    flat = truth ** 0.6 * np.mean(truth) / np.mean(truth ** 0.6)
    exact = metrics.band_ratios(flat, truth, mask)
    assert exact["bright"] < 0.9 and exact["dim"] > 1.08
    seen = metrics.band_ratios(flat, ref, mask, halves=(a, b))
    assert seen["bright"] < 0.9 and seen["dim"] > 1.08
    assert all(abs(seen[k] - exact[k]) < 0.035 for k in exact), (seen, exact)
    c = metrics.compare(truth, ref, mask, halves=(a, b))
    assert c["brightness_bands"] == fair and c["bands_ranked_on"] == "independent halves"
    assert metrics.compare(truth, ref, mask)["bands_ranked_on"] == "the reference"


def test_undefined_metrics_are_nan_and_bad_shapes_an_error(pair):
    img, ref, var, mask = pair
    none = np.zeros_like(mask)
    assert np.isnan(metrics.relmse(img, ref, none)) and np.isnan(metrics.brightness_ratio(img, ref, none))
    black = np.zeros_like(ref)
    assert not metrics.luminance_mask(black).any()
    m = metrics.compare(img, black, mask)
    assert np.isnan(m["relmse"]) and np.isnan(m["brightness_ratio"]) and m["reference_noise_relmse"] is None
    assert m["mask_pixels"] == mask.sum() and m["pixels"] == mask.size
    with pytest.raises(PopvolError, match="differ in size"):
        metrics.relmse(img[:4], ref)
    with pytest.raises(PopvolError, match="mask"):
        metrics.relmse(img, ref, mask[:4])


def test_reference_noise_is_in_the_same_metric(pair):
    img, ref, var, mask = pair
    r = Reference(ref.astype(np.float32), 64, 4, var, {})
    assert r.noise_relmse(mask) == pytest.approx(metrics.noise_relmse(var, ref.astype(np.float32), mask), rel=1e-12)
    # a 1 % standard deviation on pixels well above eps: noise ~1e-4 in relMSE
    assert 2e-5 < r.noise_relmse(mask) < 3e-4
    assert Reference(ref, 1, 1, None, {}).noise_relmse(mask) is None


def box_scene(width=33, height=33, background=(0.0, 0.0, 0.0), scale=2.0):
    """A uniform unit cube of density 1 at the origin, seen from +z at distance 3."""
    med = Medium(np.ones((10, 10, 10), np.float32), 0.1, np.full(3, -0.45), scale=scale)
    cam = Camera(np.array([0.0, 0.3, 3.0]), np.zeros(3), fov=40.0, width=width, height=height)
    return Scene(med, [], cam, background=np.asarray(background, np.float64))


def test_camera_optical_depth_is_scale_times_the_chord_of_a_uniform_box():
    sc = box_scene()
    tau = metrics.camera_optical_depth(sc)
    assert tau.shape == (33, 33) and tau.dtype == np.float64
    d = sc.camera.ray_directions()
    o = sc.camera.origin
    with np.errstate(divide="ignore"):
        ta, tb = (-0.5 - o) / d, (0.5 - o) / d
    t0 = np.maximum(np.minimum(ta, tb).max(-1), 0)
    t1 = np.maximum(ta, tb).min(-1)
    chord = np.maximum(t1 - t0, 0)
    np.testing.assert_allclose(tau, 2.0 * chord, rtol=1e-9, atol=1e-12)
    assert (chord == 0).any() and (chord > 1).any()          # the box and empty sky around it
    np.testing.assert_array_equal(metrics.optical_depth_mask(sc), 2.0 * chord > metrics.MASK_OPTICAL_DEPTH)


def test_optical_depth_mask_picks_the_medium_on_a_sky_where_luminance_cannot():
    """On a bright background the luminance mask takes the sky too; the optical-depth mask
    (what ``popvol compare`` uses, the scene at hand) takes the medium's pixels only."""
    sc = box_scene(background=(0.3, 0.4, 0.6), scale=0.5)
    ref = np.broadcast_to(np.asarray(sc.background), (33, 33, 3)).copy()
    mask = metrics.medium_mask(ref, sc)
    tau = metrics.camera_optical_depth(sc)
    ref *= np.exp(-tau)[..., None]                          # the sky seen through the absorbing box
    assert metrics.luminance_mask(ref).all()
    np.testing.assert_array_equal(metrics.medium_mask(ref, sc), mask)
    assert 0 < mask.sum() < 0.5 * mask.size
    with pytest.raises(PopvolError, match="differ in size"):
        metrics.medium_mask(ref[:10], sc)


def test_comparison_figure_has_the_ratio_map(pair, tmp_path):
    pytest.importorskip("matplotlib")
    img, ref, var, mask = pair
    out = tmp_path / "fig.png"
    metrics.comparison_figure(out, img, ref, 6.0, "test", mask=mask)
    from PIL import Image
    w, h = Image.open(out).size
    assert out.stat().st_size > 2000 and w > 3 * h        # four panels side by side


def test_compare_command_prints_and_writes_the_new_metric(tmp_path, capsys):
    """``popvol compare`` against popvol's own image at half brightness: relMSE from it, ratio
    x2 overall and in every band, no reference noise (no passes stored), and the mask size."""
    pytest.importorskip("skimage")
    from popvol.cli import main
    from popvol.io.images import write_exr
    sc = popvol.load_scene(None, width=24, height=16, resolution=16)
    img = popvol.render(sc, popvol.solve(sc)).astype(np.float64)
    ref = tmp_path / "half.exr"
    write_exr(ref, (0.5 * img).astype(np.float32))
    out_json, fig = tmp_path / "cmp.json", tmp_path / "cmp.png"
    with pytest.raises(SystemExit) as e:
        main(["compare", "--reference", str(ref), "--resolution", "16", "--json", str(out_json),
              "--figure", str(fig)])
    assert e.value.code == 0
    printed = capsys.readouterr().out
    res = json.loads(out_json.read_text())
    assert res["brightness_ratio"] == pytest.approx(2.0, rel=1e-5)
    for name in ("dim", "mid", "bright"):
        assert res["brightness_bands"][name] == pytest.approx(2.0, rel=1e-5)
    mask = metrics.medium_mask(0.5 * img, sc)
    assert res["mask_pixels"] == mask.sum() > 0 and res["pixels"] == 24 * 16
    assert res["relmse"] == pytest.approx(metrics.relmse(img, 0.5 * img, mask), rel=1e-4)
    assert res["reference_noise_relmse"] is None and "optical depth" in res["mask"]
    assert res["relmse_extrapolated"] is None and res["reference_noise_observed"] is None    # no halves
    assert "relMSE" in printed and "x2.000" in printed and "bright 10 % x2.000" in printed
    assert "reference noise n/a" in printed and fig.stat().st_size > 2000


def test_relmse_extrapolated_to_a_noiseless_reference_is_the_error_against_the_truth():
    """A reference of 12 passes (halves of 8 and 4), each the mean of 16 samples of the truth
    times a lognormal of mean 1 and sigma 1.25 (a heavy tail: rare bright samples, as a path
    tracer's fireflies), and an image 10 % off the truth per pixel: its relMSE against the
    reference is about 3 times its relMSE against the truth. Extrapolated from the relMSE
    against the reference and its two halves (e + c / P) it is the error against the truth within
    12 % (measured x0.89-x1.04 over eight seeds), where the relMSE less the noise estimated from
    the passes' variance is 19-31 % too high: that estimate leaves out what the noise does through
    the denominator (ref^2 + eps). Without noise the fit is exact and finds no noise."""
    for seed in range(4):
        rng = np.random.default_rng(seed)
        truth = rng.uniform(0.2, 1.0, (60, 80, 1)) * rng.uniform(0.8, 1.2, (60, 80, 3))
        img = truth * (1.0 + 0.1 * rng.standard_normal(truth.shape))
        mask = np.ones(truth.shape[:2], bool)
        sigma = 1.25
        passes = truth * rng.lognormal(-sigma ** 2 / 2, sigma, (12, 16) + truth.shape).mean(axis=1)
        ref = passes.mean(axis=0)
        halves = (passes[:8].mean(axis=0), passes[8:].mean(axis=0))
        error = metrics.relmse(img, truth, mask)
        assert metrics.relmse(img, ref, mask) > 2.5 * error
        fit = metrics.extrapolated_relmse(img, ref, halves, (8, 4), mask)
        assert fit["relmse"] == pytest.approx(error, rel=0.12), seed
        assert fit["noise"] == pytest.approx(metrics.relmse(img, ref, mask) - error, rel=0.1), seed
        less_variance = metrics.relmse(img, ref, mask) - metrics.noise_relmse(passes.var(axis=0, ddof=1) / 12, ref,
                                                                               mask)
        assert less_variance > 1.15 * error, seed
    exact = metrics.extrapolated_relmse(img, truth, (truth, truth), (8, 4), mask)
    assert exact["relmse"] == pytest.approx(error, rel=1e-9) and exact["noise"] == pytest.approx(0.0, abs=1e-12)
    assert metrics.extrapolated_relmse(img, truth, None, None, mask) == {"relmse": None, "noise": None}


def test_equal_error_spp_follows_the_reference_noise_falling_as_one_over_spp():
    """A reference of N spp with noise relMSE n reaches popvol's error e (against the truth) at
    N n / e spp. Checked against noise made by averaging k independent samples: the
    relMSE of that mean against the truth is the per-sample noise / k."""
    rng = np.random.default_rng(2)
    truth = rng.uniform(0.2, 1.0, (40, 60, 3))
    mask = np.ones(truth.shape[:2], bool)
    sigma = 0.3 * truth                                      # one sample's noise
    def mean_of(k):
        return truth + rng.standard_normal((k,) + truth.shape).mean(axis=0) * sigma
    per_sample = metrics.noise_relmse(sigma ** 2, truth, mask)
    error = 0.01                                             # popvol's error against the truth
    eq = metrics.equal_error(error, per_sample / 64, 64, 64 * 0.5, 2.0)
    k = eq["spp"]
    assert k == pytest.approx(per_sample / error, rel=1e-9)
    measured = np.mean([metrics.relmse(mean_of(int(round(k))), truth, mask) for _ in range(20)])
    assert measured == pytest.approx(error, rel=0.1)
    assert eq["seconds"] == pytest.approx(0.5 * k) and eq["speedup"] == pytest.approx(0.25 * k)
    # unknown: no noise estimate, no timing, or a relMSE the reference's noise could explain
    assert metrics.equal_error(0.1, None, 64, 10.0, 1.0) == {"spp": None, "seconds": None, "speedup": None}
    assert metrics.equal_error(0.1, 0.01, 64, None, 1.0)["seconds"] is None
    assert metrics.equal_error(0.005, 0.01, 64, 10.0, 1.0)["spp"] is None


def test_equal_error_at_extreme_figures_is_finite_or_none_without_warnings():
    """Figures whose quotient overflows (a recorded time of 1e308 s, NumPy scalars as compare
    passes them) give None, not inf and NumPy's multi-line RuntimeWarning."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        eq = metrics.equal_error(np.float64(0.2), np.float64(0.1), 4, np.float64(1e308), 1e-10)
        assert eq == {"spp": pytest.approx(2.0), "seconds": pytest.approx(5e307), "speedup": None}
        eq = metrics.equal_error(np.float64(1e-300), np.float64(1e-310), 2**31 - 1, 1e9, 1e-3)
        assert all(v is None or np.isfinite(v) for v in eq.values())
        assert metrics.equal_error(np.float64(np.inf), np.float64(0.1), 4, 1.0, 1.0)["spp"] is None
        assert metrics.equal_error(np.float64(0.2), np.float64(np.nan), 4, 1.0, 1.0)["spp"] is None


@pytest.mark.parametrize("target, scale", [
    ([0.0, 0.0, 0.0], 2.0),            # the cube in the middle of the view
    ([0.0, 0.3, 6.0], 2.0),            # looking away from it
    ([1.2, 0.0, 0.0], 2.0),            # the cube off the centre of the view
    ([0.0, 0.0, 0.0], 1e-3),           # too thin: optical depth at most 1.03e-3
    ([0.0, 0.0, 0.0], 0.00975),        # only the two longest chords (1.027) pass 0.01
    ([0.0, 0.0, 0.0], 0.0),
])
def test_medium_in_view_is_whether_the_optical_depth_mask_has_a_pixel(target, scale):
    sc = box_scene(width=41, height=23, scale=scale)
    sc.camera = Camera(sc.camera.origin, np.asarray(target), fov=40.0, width=41, height=23)
    mask = metrics.optical_depth_mask(sc)
    assert metrics.medium_in_view(sc) == bool(mask.any())
    if scale == 0.00975:
        assert mask.sum() == 2
