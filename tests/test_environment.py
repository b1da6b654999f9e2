"""An environment's light against a converged Mitsuba 3 reference: the regression test's small
cumulus with the WDAS cloud's optics (g 0.877, albedo 0.99), lit by an analytic sky alone
(tests/fixtures/sky_cloud.toml; its reference, 16384 spp, by scripts/make_test_references.py).

An environment's lights inject a broad lobe (a0 < 1) and have no direct field. The default walks
them with six ordinates, every order, with no diffusion stage (docs/METHOD.md, "Six ordinates"),
and gathers the last scattering with the map's light entering through the grid's faces, so
their first scattering is transported from the map itself (docs/METHOD.md, "Gathered last
bounce"). With the one-lobe sweeps (``solver = "sweep"``) they hand over to the diffusion stage
at method.environment_handover_scale (default 0.5) times the cell's factor, not at a sun's
handover_scale (2) (docs/METHOD.md, "Hand-over"). Measured in ``popvol compare``'s metric, at
128 cells: the default relMSE 0.0072, brightness x0.955 (dim / mid / bright x0.994 / x0.899 /
x1.001, ranked on the reference itself: it has no halves), each region's unscattered lobe
gathered in its region's own pattern (docs/METHOD.md Eq. 26a); with one lobe per region for all
its walked light (the default before) 0.0172, x0.895 (x0.917 / x0.839 / x0.987); lit from the
lobes at every sample instead (before the map entered the gather) 0.047, x0.817 (x0.888 / x0.715
/ x0.903); the one-lobe sweeps 0.069, x0.757, at a sun's threshold 0.146, x0.649. The middle band
is still too dark (the goal is relMSE <= 0.03, bands within 5 %): the pinned figures are a change
detector, not a bound on the accuracy; the comparisons are the tests of the choices.
"""
from pathlib import Path

import pytest

import popvol
from popvol import metrics
from popvol.reference import load_reference
from test_regression import BAND_GUARD, RELMSE_GUARD      # the change detector's margins: the regression guard's

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SCENE = FIXTURES / "sky_cloud.toml"

#: popvol's last measured figures for the default method (module docstring): a change detector
MEASURED_RELMSE, MEASURED_BRIGHTNESS = 0.0072, 0.955


@pytest.fixture(scope="module")
def reference():
    return load_reference(FIXTURES / "sky_cloud.exr")


@pytest.fixture(scope="module")
def mask(reference):
    return metrics.medium_mask(reference.image, popvol.load_scene(SCENE))


def measure(reference, mask, **overrides) -> dict:
    scene = popvol.load_scene(SCENE, **overrides)
    return metrics.compare(popvol.render(scene, popvol.solve(scene)), reference.image, mask, reference.variance)


def test_sky_light_handed_over_later_is_closer_to_mitsuba(reference, mask):
    """The one-lobe sweeps (``solver = "sweep"``) at environment_handover_scale 0.5 against the
    same with a sun's threshold for the sky's lights (2): relMSE at most 0.6 times as large
    (measured 0.069 against 0.146) and the brightness nearer 1 (x0.757 against x0.649), against
    the same independent reference. Both are far above the reference's noise (measured 1.5e-5)."""
    default = measure(reference, mask, solver="sweep")
    sun_like = measure(reference, mask, solver="sweep", environment_handover_scale=2.0)
    print(f"sweep relMSE {default['relmse']:.4f} x{default['brightness_ratio']:.3f}; at a sun's threshold "
          f"{sun_like['relmse']:.4f} x{sun_like['brightness_ratio']:.3f}; noise {default['reference_noise_relmse']:.2g}")
    assert default["relmse"] <= 0.6 * sun_like["relmse"]
    assert abs(default["brightness_ratio"] - 1.0) < abs(sun_like["brightness_ratio"] - 1.0) - 0.05
    assert default["reference_noise_relmse"] < 0.05 * default["relmse"]


def test_sky_first_scattered_from_the_map_is_closer_to_mitsuba(reference, mask, monkeypatch):
    """The map's light entering the gather through the grid's faces (the default) against the
    same solution lit from the sky's lobes at every sample (renderer.gathered_environment
    giving no map, as before it did): relMSE at most half (measured 0.014 against 0.047) and
    the brightness nearer 1 (x0.911 against x0.817), against the same independent reference."""
    from popvol import renderer
    scene = popvol.load_scene(SCENE)
    sol = popvol.solve(scene)
    gathered = metrics.compare(popvol.render(scene, sol), reference.image, mask)
    monkeypatch.setattr(renderer, "gathered_environment",
                        lambda sc, so: (None, renderer.np.zeros(len(so.unscattered), bool), None))
    lobes = metrics.compare(popvol.render(scene, sol), reference.image, mask)
    assert gathered["relmse"] <= 0.5 * lobes["relmse"]
    assert abs(gathered["brightness_ratio"] - 1.0) < abs(lobes["brightness_ratio"] - 1.0) - 0.05


def test_region_patterns_are_closer_to_mitsuba_than_one_lobe_per_region(reference, mask):
    """Each region's unscattered lobe gathered in its region's own pattern (the default: Eq.
    26a) against the same solution gathered with one lobe per region for all its walked light
    (Solution.lobe_a0 cleared, as before): relMSE at most half (measured 0.0072 against 0.0172)
    and the brightness nearer 1 (x0.955 against x0.895), against the same independent
    reference."""
    import dataclasses
    scene = popvol.load_scene(SCENE)
    sol = popvol.solve(scene)
    patterns = metrics.compare(popvol.render(scene, sol), reference.image, mask)
    one_lobe = metrics.compare(popvol.render(scene, dataclasses.replace(sol, lobe_a0=None)), reference.image, mask)
    assert patterns["relmse"] <= 0.5 * one_lobe["relmse"]
    assert abs(patterns["brightness_ratio"] - 1.0) < abs(one_lobe["brightness_ratio"] - 1.0) - 0.04


def test_sky_cloud_change_detector(reference, mask):
    """Change detector (popvol's own earlier output, MEASURED_*): the default's relMSE at most
    RELMSE_GUARD + the reference's noise above the measured, its brightness within BAND_GUARD."""
    m = measure(reference, mask)
    assert m["relmse"] <= MEASURED_RELMSE + RELMSE_GUARD + m["reference_noise_relmse"]
    assert m["brightness_ratio"] == pytest.approx(MEASURED_BRIGHTNESS, abs=BAND_GUARD)


def test_suns_keep_their_threshold():
    """environment_handover_scale touches only the lights without a direct field: a sun's
    solution with the one-lobe sweeps is bitwise the same whatever it is."""
    scene = popvol.load_scene(FIXTURES / "regression_cloud.toml", resolution=32, solver="sweep")
    a = popvol.solve(scene)
    b = popvol.solve(popvol.load_scene(FIXTURES / "regression_cloud.toml", resolution=32, solver="sweep",
                                       environment_handover_scale=7.0))
    assert (a.phi == b.phi).all() and (a.phid == b.phid).all()
