"""The Monte Carlo oracle itself, against analytic results (it must be right to judge POP)."""
import numpy as np
import pytest

from montecarlo import chandrasekhar_h, cube_beam_mc, half_space_mc, slab_fluence_mc, slab_legendre_mc, slab_mc


def test_slab_pure_absorber_is_beer_lambert():
    r = slab_mc(2.0, 0.0, 0.5, n_photons=50_000, seed=1)
    assert r["R"] == 0.0
    assert r["T"] == pytest.approx(np.exp(-2.0), abs=4 * r["stderr_T"] + 1e-3)


def test_slab_conservative_reflects_what_it_does_not_transmit():
    r = slab_mc(3.0, 1.0, 0.3, n_photons=50_000, seed=2)
    assert r["T"] + r["R"] == pytest.approx(1.0, abs=1e-9)


def test_slab_change_detector_against_an_earlier_monte_carlo_run():
    """Change detector: an earlier, independent Monte Carlo run of the same slab (200k paths,
    tau 4, albedo 1, g 0.8) gave T 0.747, R 0.253; the walk here must reproduce it."""
    r = slab_mc(4.0, 1.0, 0.8, n_photons=200_000, seed=3)
    assert r["T"] == pytest.approx(0.747, abs=3 * r["stderr_T"] + 0.005)


def test_cube_pure_absorber():
    tau, hw = 3.0, 0.125
    r = cube_beam_mc(tau, 0.0, 0.8, hw, n_photons=20_000, seed=4, n_depth_bins=8)
    assert r["transmitted"] == pytest.approx(np.exp(-tau), abs=4 * r["stderr_transmitted"] + 1e-3)
    assert r["reflected"] == 0 and r["side"] == 0
    x = np.linspace(0, 1, 9)
    expected = (np.exp(-tau * x[:-1]) - np.exp(-tau * x[1:])) / (tau / 8)
    np.testing.assert_allclose(r["fluence_depth"], expected, rtol=0.03)
    assert r["r2_mean"] == pytest.approx(2 * hw**2 / 3, rel=0.02)   # the beam's own spread


def test_cube_conservative_all_energy_leaves():
    r = cube_beam_mc(5.0, 1.0, 0.6, 0.1, n_photons=20_000, seed=5)
    assert r["absorbed"] == 0
    assert r["transmitted"] + r["reflected"] + r["side"] == pytest.approx(1.0, abs=1e-9)


def test_half_space_matches_chandrasekhar_isotropic():
    """The half-space oracle against the exact albedo problem of isotropic scattering: the
    reflected radiance per unit irradiance is (albedo / 4 pi) mu0 / (mu0 + mu) H(mu0) H(mu)
    (Chandrasekhar, Radiative Transfer, 1950, Ch. IV, with pi F = 1), its first order the same
    without the Hs."""
    light, view, albedo = np.array([0.6, 0.0, -0.8]), np.array([0.0, 0.28, 0.96]), 0.9
    mu0, mu = 0.8, 0.96 / np.linalg.norm(view)
    r = half_space_mc(light, view, albedo, 0.0, n_photons=200_000)
    first = albedo / (4 * np.pi) * mu0 / (mu0 + mu)
    H0, H1 = chandrasekhar_h([mu0, mu], albedo)
    assert r["single"] == pytest.approx(first, rel=5 * r["stderr_single"] / first + 1e-3)
    assert r["total"] == pytest.approx(first * H0 * H1, rel=4 * r["stderr_total"] / r["total"] + 2e-3)


def _layer_mean_exp(depth, n, mu0=1.0):
    """Each of n equal layers' mean of exp(-z / mu0) over a depth ``depth``, in closed form."""
    z = np.linspace(0.0, depth, n + 1)
    return mu0 * (np.exp(-z[:-1] / mu0) - np.exp(-z[1:] / mu0)) / (depth / n)


def test_slab_fluence_of_a_pure_absorber_is_beer_lambert():
    """Each layer's mean of exp(-z / mu0), in closed form."""
    mu0, depth, n = 0.8, 3.0, 6
    got = slab_fluence_mc(mu0, 0.0, 0.5, depth, n, n_photons=400_000, seed=4)
    np.testing.assert_allclose(got, _layer_mean_exp(depth, n, mu0), rtol=0.02)


def test_slab_fluence_absorbs_what_the_slab_oracle_absorbs():
    """sigma_a times the fluence's integral over depth is the power absorbed (per unit of the
    power entering at normal incidence): the track-length estimate here against slab_mc's
    collision estimate of the same slab, two different estimators of one quantity."""
    depth, albedo, g, n = 2.0, 0.9, 0.7, 8
    phi = slab_fluence_mc(1.0, albedo, g, depth, n, n_photons=200_000, seed=6)
    absorbed = (1.0 - albedo) * phi.sum() * depth / n
    assert absorbed == pytest.approx(slab_mc(depth, albedo, g, n_photons=200_000, seed=7)["A"], rel=0.01)


def test_slab_legendre_fluence_is_the_fluence_less_the_unscattered_light():
    """Column 0 of slab_legendre_mc (the light that scattered) plus Beer-Lambert's unscattered
    light is slab_fluence_mc's fluence (another run of another tally)."""
    depth, n = 3.0, 6
    scattered = slab_legendre_mc(0.95, 0.8, depth, n, lmax=4, n_photons=200_000, seed=11)[:, 0]
    total = slab_fluence_mc(1.0, 0.95, 0.8, depth, n, n_photons=200_000, seed=12)
    np.testing.assert_allclose(scattered + _layer_mean_exp(depth, n), total, rtol=0.02)


def test_slab_legendre_flux_carries_what_is_transmitted():
    """In a slab that absorbs nothing the net flux is the same at every depth: the scattered
    light's flux (column 1, fluence times <mu>) plus the beam's exp(-z) is the transmittance T,
    which slab_mc counts at the far face (energy conservation; two estimators)."""
    depth, n = 4.0, 8
    flux = slab_legendre_mc(1.0, 0.7, depth, n, lmax=4, n_photons=200_000, seed=13)[:, 1]
    T = slab_mc(depth, 1.0, 0.7, n_photons=200_000, seed=14)["T"]
    np.testing.assert_allclose(flux + _layer_mean_exp(depth, n), T, atol=0.01)


def test_slab_legendre_deep_light_is_diffusion():
    """Deep in a thick slab that scatters isotropically and absorbs nothing, the radiance is
    diffusion's 1 + 3 <mu> mu (its second moment <P_2> vanishes, up to O(1 / tau^2)) and its
    flux is Fick's law: <mu> phi = -(1/3) d phi / dz (the P1 approximation's exact limit)."""
    depth, n = 20.0, 10
    acc = slab_legendre_mc(1.0, 0.0, depth, n, lmax=2, n_photons=40_000, seed=15)
    mid = slice(3, 7)
    assert np.all(np.abs(acc[mid, 2] / acc[mid, 0]) < 0.02)
    dz = depth / n
    fick = -(acc[4:8, 0] - acc[2:6, 0]) / (2 * dz) / 3.0
    np.testing.assert_allclose(acc[3:7, 1], fick, rtol=0.1)
