"""Regression guard (a change detector) for the default method: its error against a converged
Mitsuba 3 reference of one small cloud, pinned at the figures popvol itself last measured.

The figures are in the metric of ``popvol compare`` (popvol.metrics): on the pixels whose camera
ray crosses the medium, the scale-free relMSE (eps = 0.01 x the squared mean reference luminance
there), the brightness ratio popvol / reference there, and the same ratio in three bands of the
reference's luminance (dimmest 50 %, middle 40 %, brightest 10 % of those pixels). Measured with
the default method (the eighteen-ordinate walk for the sun, every order walked, the last
scattering gathered from 64 directions, the sun's lobe apart, 128 cells, one sample at each
pixel centre; the walk's faint packets and its last light, once under 20 % of it is in flight,
on blocks of 2^3 cells): relMSE 0.0105, brightness x1.042, bands dim x0.976, mid x1.061, bright
x1.051 (with the last 10 % on the blocks and every packet sent on the walk's own cells, before
docs/METHOD.md's "The walk's tail on wider cells" left the faint ones for the blocks: 0.0105,
x1.036, x0.971 / x1.055 / x1.045; the whole walk on its own cells, ``tail = 0``: 0.0106,
x1.036, x0.970 / x1.055 / x1.046; before that
with each gathered segment's emission the mean of its ends', before docs/METHOD.md Eq. 25f:
0.0107, x1.036, x0.971 / x1.055 / x1.045; with the sun's lobe gathered with the rest, before
Eq. 25e: 0.0101, x1.030, x0.965 / x1.048 / x1.040). Six ordinates (``ordinates = 6``) relMSE
0.0093, x1.067 (x1.019 / x1.078 / x1.081); the one-lobe sweeps with their diffusion stage
(``solver = "sweep"``) relMSE 0.0137, x0.928 (x1.031 / x0.916 / x0.860); walking alone
(``isotropic = "walk"``) relMSE 0.569, brightness x1.67.

These are popvol's own earlier output, not an independent bound on its accuracy. The accuracy
GOAL is relMSE <= 0.03 and every band ratio within 5 % of 1 (GOAL_*); this scene misses it
narrowly, by its middle 40 % (x1.061; README, "What it computes, and where it is biased"). The guard's margins are
derived from the goal: relMSE may rise by half the goal's whole budget (RELMSE_GUARD, about the
measured figure again) plus the reference's own noise; the overall and band ratios may move by
0.6 x the goal's 5 % (BAND_GUARD, 0.03) either way. popvol's image is deterministic (one sample
at each pixel centre, thread-count-independent sweep bands), so the margins are far above rounding: a change
that makes the default measurably worse, or a band measurably better, must update MEASURED_*.
The accuracy itself, scene by scene, is in docs/ACCURACY.md.

tests/fixtures/regression_cloud.exr is made by scripts/make_test_references.py (65536 spp; its
own noise in the same metric 5.9e-4, about 1/15 of the relMSE pinned here).
"""
from pathlib import Path

import pytest

import popvol
from popvol import metrics
from popvol.reference import load_reference

FIXTURES = Path(__file__).resolve().parent / "fixtures"

#: the accuracy goal (missed by this scene, narrowly)
GOAL_RELMSE, GOAL_BAND = 0.03, 0.05
#: regression guard margins, derived from the goal
RELMSE_GUARD, BAND_GUARD = 0.5 * GOAL_RELMSE, 0.6 * GOAL_BAND
#: popvol's last measured figures for the default method (module docstring)
MEASURED_RELMSE, MEASURED_BRIGHTNESS = 0.0105, 1.042
MEASURED_BANDS = {"dim": 0.976, "mid": 1.061, "bright": 1.051}
MEASURED_WALK_RELMSE = 0.569


@pytest.fixture(scope="module")
def reference():
    return load_reference(FIXTURES / "regression_cloud.exr")


@pytest.fixture(scope="module")
def mask(reference):
    return metrics.medium_mask(reference.image, popvol.load_scene(FIXTURES / "regression_cloud.toml"))


def render(**overrides):
    scene = popvol.load_scene(FIXTURES / "regression_cloud.toml", **overrides)
    return popvol.render(scene, popvol.solve(scene))


def test_default_method_regression_guard_against_mitsuba(reference, mask):
    """Regression guard: relMSE at most RELMSE_GUARD + the reference's noise above, and the
    brightness ratio overall and in each band within BAND_GUARD of, the figures popvol measured
    for the default method (MEASURED_*; the module docstring says why these and not the GOAL)."""
    img = render()
    m = metrics.compare(img, reference.image, mask, reference.variance)
    b = m["brightness_bands"]
    print(f"relMSE {m['relmse']:.4f}, brightness x{m['brightness_ratio']:.3f} (dim x{b['dim']:.3f}, "
          f"mid x{b['mid']:.3f}, bright x{b['bright']:.3f}), reference noise {m['reference_noise_relmse']:.2g}, "
          f"{m['mask_pixels']} medium pixels")
    assert m["relmse"] <= MEASURED_RELMSE + RELMSE_GUARD + m["reference_noise_relmse"]
    assert m["brightness_ratio"] == pytest.approx(MEASURED_BRIGHTNESS, abs=BAND_GUARD)
    for name, measured in MEASURED_BANDS.items():
        assert b[name] == pytest.approx(measured, abs=BAND_GUARD), name


def test_default_is_far_better_than_the_walk_alone(reference, mask):
    """The one-lobe walk alone (the papers' POP: one lobe per cell, no diffusion stage) errs far
    more on the same reference: measured relMSE 0.569, brightness x1.67, against the default's
    0.0105."""
    walk = metrics.relmse(render(solver="sweep", isotropic="walk"), reference.image, mask)
    assert walk > 5 * MEASURED_RELMSE


def test_fixture_reference_loads_and_names_its_scene_portably(reference, mask):
    """The committed reference loads with its sidecars (65536 spp in 16 passes), its noise in
    the same metric is far below the pinned relMSE, and its metadata names the scene relative
    to the fixture folder, not by a path of the machine that rendered it. The optical-depth mask
    holds the luminance mask's pixels (black background) and a thin fringe more."""
    assert (reference.spp, reference.passes) == (65536, 16)
    assert reference.noise_relmse(mask) < 0.1 * MEASURED_RELMSE        # 5.9e-4: about 1/15 of it
    lum = metrics.luminance_mask(reference.image)
    assert (lum & ~mask).sum() == 0 and lum.sum() <= mask.sum() <= 1.1 * lum.sum()
    scene = Path(reference.meta["scene"])
    assert not scene.is_absolute() and (FIXTURES / scene).is_file()


def test_compare_prints_the_equal_error_speed_up(tmp_path):
    """popvol compare on the fixture: the Mitsuba reference's noise (16 passes) and recorded
    time give the samples per pixel it would need to be as close as popvol is, and the time."""
    import json
    import subprocess
    import sys
    out = tmp_path / "c.json"
    r = subprocess.run([sys.executable, "-m", "popvol.cli", "compare", str(FIXTURES / "regression_cloud.toml"),
                        "--reference", str(FIXTURES / "regression_cloud.exr"), "--json", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    eq, spp = res["equal_error"], res["reference_spp"]
    error = res["relmse"] - res["reference_noise_relmse"]
    assert eq["spp"] == pytest.approx(spp * res["reference_noise_relmse"] / error, rel=1e-9)
    assert eq["seconds"] == pytest.approx(res["reference_seconds"] / spp * eq["spp"], rel=1e-9)
    assert eq["speedup"] == pytest.approx(eq["seconds"] / res["popvol_seconds"], rel=1e-9)
    assert "equal error: the reference would need" in r.stdout
