"""A front-lit slab against the plane-parallel Monte Carlo of tests/montecarlo.py (independent of
popvol; itself checked against Chandrasekhar's H functions in test_montecarlo.py) as its voxels
thicken: the accuracy issue's dense-media item (docs/METHOD.md, "Optically thick voxels").

The unscattered light scattered once is right where voxels are thin, and so is the whole
reflection (with the gathered last bounce, method.gather) at 0.25 mean free paths per voxel.
With empty voxels above the slab, as a volume from a file has, the reflection levels off near the
albedo problem's value however thick the voxels (the eighteen-ordinate walk, the default, 6-15 %
below it; the one-lobe sweeps with their diffusion stage within 18 %): the march splits optically
thick segments, so the single scattering samples the lit skin, and light transport sees voxels
capped at Medium.transport_depth_cap() mean free paths (2 at this slab's albedo of 0.9), so the
multiply scattered light is that of a medium whose cells resolve the depth it comes from; the
gathered last bounce scatters the unscattered light as the capped walk saw it (docs/METHOD.md
Eq. 25g). Where the slab's face is the grid's own edge the fields are clamped to the top voxel's
values, which hold little of the unscattered light of thick voxels, so the march takes it there
by Beer-Lambert from the face (Eq. 25d) and the single scattering is the Monte Carlo's; the whole
reflection is within the goal (5 % of Monte Carlo) from 0.25 mean free paths per voxel to 10^4 (16
cells; 0.25 at 32).
``python scripts/dense_slab.py --solver ordinates [--pad 2]`` prints the whole table.
"""
import numpy as np
import pytest

import popvol
from popvol.scene import apply_overrides
from montecarlo import half_space_mc, slab_fluence_mc
from slab import ALBEDO, G, LIGHT, VIEW, centre_radiance, slab_depth, slab_scene, wide_slab_fluence

GOAL = 0.05            # the accuracy issue's band: within 5 % of the reference
PHOTONS = 200_000


def monte_carlo(tau_voxel):
    return half_space_mc(LIGHT, VIEW, ALBEDO, G, depth=slab_depth(tau_voxel), n_photons=PHOTONS)


def test_single_scattering_of_a_thin_slab_matches_monte_carlo():
    """At 0.25 mean free paths per voxel (slab tau 1) the unscattered light scattered once
    (Solution.single_scattering) is the Monte Carlo's single scattering within 2 % plus three of
    its standard errors (measured x0.999 at 16 cells, x1.00 at 32)."""
    mc = monte_carlo(0.25)
    for resolution in (16, 32):
        scene = slab_scene(0.25, resolution)
        single = centre_radiance(popvol.render(scene, popvol.solve(scene).single_scattering(), jitter=False))
        assert single == pytest.approx(mc["single"], rel=0.02, abs=3 * mc["stderr_single"]), resolution


@pytest.mark.parametrize("tau_voxel", [10.0, 100.0, 1e4])
def test_single_scattering_of_a_thick_slab_in_empty_space_levels_off(tau_voxel):
    """With empty voxels above the slab, as a volume from a file has (its density ramps over one
    voxel, slab.slab_scene's ``pad``), the unscattered light scattered once stays at the Monte
    Carlo's single scattering however thick the voxels (within 25 %: measured x0.80 / x0.98 /
    x1.10 at 16 cells and x1.01 / x1.04 / x1.13 at 32 for 10 / 100 / 10^4 mean free paths per
    voxel): the march splits a segment that would be optically thicker than
    kernels.render.MAX_SEGMENT_DEPTH, so it samples the lit skin instead of stepping over it."""
    mc = monte_carlo(tau_voxel)
    for resolution in (16, 32):
        scene = slab_scene(tau_voxel, resolution, pad=2)
        single = centre_radiance(popvol.render(scene, popvol.solve(scene).single_scattering(), jitter=False))
        assert single == pytest.approx(mc["single"], rel=0.25, abs=3 * mc["stderr_single"]), resolution


@pytest.mark.parametrize("solver, rel", [("ordinates", 0.2), ("sweep", 0.2)])
@pytest.mark.parametrize("tau_voxel", [10.0, 100.0, 1e4, 1e5])
def test_reflection_of_a_thick_slab_in_empty_space_levels_off_near_monte_carlo(tau_voxel, solver, rel):
    """With empty voxels above the slab, the whole reflected radiance levels off near the Monte
    Carlo's (the semi-infinite albedo problem's value) at 16 and 32 cells, from 10 to 10^5 mean
    free paths per voxel (before the transport's cap, x0.37 at 10 and x0.12 from 100 on): an
    optically thick medium's reflection depends on its albedo and g, not its density. The
    eighteen-ordinate walk (the default) within 20 %: measured x0.88 / x0.85 / x0.85 / x0.85 at 16
    cells and x0.94 / x0.90 / x0.89 / x0.89 at 32, too dark; the one-lobe sweeps with their
    diffusion stage within 20 %: x0.96 / x0.97 / x0.98 / x0.98 and x1.18 / x1.17 / x1.18 / x1.18.
    Before the gather scattered the capped walk's unscattered light (docs/METHOD.md Eq. 25g) the
    default was x0.80 / x0.78 and x0.86 / x0.82, and before it integrated each segment's source
    function exactly (Eq. 25f) x0.78 / x0.76 and x0.83 / x0.80. Neither meets the issue's 5 %."""
    mc = monte_carlo(tau_voxel)
    for resolution in (16, 32):
        scene = apply_overrides(slab_scene(tau_voxel, resolution, pad=2), solver=solver)
        total = centre_radiance(popvol.render(scene, popvol.solve(scene), jitter=False))
        assert total == pytest.approx(mc["total"], rel=rel, abs=3 * mc["stderr_total"]), resolution


@pytest.mark.parametrize("tau_voxel", [1.0, 10.0, 100.0, 1e4])
@pytest.mark.parametrize("resolution", [16, 32])
def test_single_scattering_of_a_slab_whose_face_is_the_grid_edge_matches_monte_carlo(tau_voxel, resolution):
    """With the slab's face at the grid's edge, no empty voxel above it, the unscattered light
    scattered once is the Monte Carlo's within 3 % plus three of its standard errors from 1 to
    10^4 mean free paths per voxel (measured x1.013 / x1.001 / x1.000 / x1.000 at 16 cells and
    x0.989 / x1.000 / x1.000 / x1.000 at 32; with the fields clamped there, x0.94 / x0.34 / x0.34
    / x0.34 and x0.95 / x0.11 / x0.04 / x0.04): the outer half cell is lit by Beer-Lambert from
    the face and each segment's mean taken in closed form (docs/METHOD.md Eq. 25d)."""
    mc = monte_carlo(tau_voxel)
    scene = slab_scene(tau_voxel, resolution)
    single = centre_radiance(popvol.render(scene, popvol.solve(scene).single_scattering(), jitter=False))
    assert single == pytest.approx(mc["single"], rel=0.03, abs=3 * mc["stderr_single"])


@pytest.mark.parametrize("tau_voxel, resolution", [(0.25, 32), (1.0, 16), (10.0, 16), (100.0, 16), (1e4, 16)])
def test_reflection_of_a_slab_matches_monte_carlo(tau_voxel, resolution):
    """The whole reflected radiance (every order of scattering) within GOAL of Monte Carlo, from
    0.25 to 10^4 mean free paths per voxel, with the slab's face at the grid's edge: the level the
    issue asks for. Measured with the eighteen-ordinate walk, the default: x0.946 / x0.956 at
    0.25 (16 / 32 cells), x0.987 / x1.015 at 1, x1.018 at 10, 100 and 10^4 (16 cells; x1.054 at
    32), where the single scattering is x1.00 and the rest x1.02. Before the gathered last bounce
    scattered the capped walk's unscattered light (docs/METHOD.md Eq. 25g) the thick slab was
    x0.933, and x0.88-x0.89 before the gather integrated each segment's source function exactly
    (Eq. 25f): strict expected failures until then. So the thinnest slab is held at 32 cells,
    where the default is within GOAL."""
    mc = monte_carlo(tau_voxel)
    scene = slab_scene(tau_voxel, resolution)
    total = centre_radiance(popvol.render(scene, popvol.solve(scene), jitter=False))
    assert total == pytest.approx(mc["total"], rel=GOAL, abs=3 * mc["stderr_total"])


def test_transport_sees_capped_voxels_and_the_unscattered_light_the_true_ones():
    """medium.transport_medium caps the density where a voxel is more than MAX_TRANSPORT_DEPTH mean
    free paths across (albedo, g and the thin voxels untouched, a thin medium returned as it
    is), and popvol.solve walks that medium while its unscattered light is Beer-Lambert through
    the true density: a sun straight down the slab's columns, so the cell centres' direct
    fluence is exp(-tau) of the depth crossed (Eq. 22), and the scattered rest phi - direct is
    the capped medium's."""
    from popvol.lights import DirectionalLight
    from popvol.medium import MAX_TRANSPORT_DEPTH
    thin = slab_scene(1.0, 16).medium
    assert thin.transport_medium() is thin
    scene = slab_scene(10.0, 16, pad=2)
    med = scene.medium
    capped = med.transport_medium()
    assert capped.max_voxel_optical_depth() == pytest.approx(MAX_TRANSPORT_DEPTH, rel=1e-6)
    assert capped.albedo == pytest.approx(med.albedo) and capped.g == med.g
    assert np.array_equal(capped.density > 0, med.density > 0)
    scene.lights = [DirectionalLight([0.0, 0.0, -1.0], 1.0)]
    sol = popvol.solve(scene)
    k = med.shape[2] - 3                      # the top full voxel, below two empty ones
    assert sol.direct[0, 0, 8, 8, k + 1] == pytest.approx(1.0, abs=1e-6)
    # half a voxel of 10 mean free paths from its face to its centre
    assert sol.direct[0, 0, 8, 8, k] == pytest.approx(np.exp(-0.5 * 10.0), rel=1e-5)
    scene_capped = slab_scene(10.0, 16, pad=2)
    scene_capped.medium, scene_capped.lights = capped, scene.lights
    ref = popvol.solve(scene_capped)
    assert ref.direct[0, 0, 8, 8, k] == pytest.approx(np.exp(-0.5 * MAX_TRANSPORT_DEPTH), rel=1e-5)
    np.testing.assert_allclose(sol.phi - sol.direct, ref.phi - ref.direct, atol=1e-6)
    np.testing.assert_allclose(sol.phid, ref.phid)


def test_gather_scatters_the_unscattered_light_of_the_capped_medium():
    """Where voxels are capped, the gathered last bounce scatters each sun's unscattered light
    as the walk saw it, through the capped density (pipeline.transport_direct, docs/METHOD.md
    Eq. 25g): the unscattered field of the same scene solved with the capped medium as its own,
    on every voxel the renderer reads; the true one (Solution.direct) stays with the camera's
    samples; and nothing where no voxel is capped."""
    from popvol.pipeline import seen_voxels, transport_direct
    from popvol.renderer import gathered_fields
    scene = slab_scene(10.0, 16, pad=2)
    sol = popvol.solve(scene)
    capped_scene = slab_scene(10.0, 16, pad=2)
    capped_scene.medium = scene.medium.transport_medium()
    capped = popvol.solve(capped_scene).direct
    seen = seen_voxels(scene.medium)
    got = transport_direct(sol)
    np.testing.assert_allclose(got[:, :, seen], capped[:, :, seen], rtol=1e-5, atol=1e-7)
    assert got[0, 0, 8, 8, 3] > 10 * sol.direct[0, 0, 8, 8, 3]      # the top full voxel's centre: 0.32 against 0.011
    lit = gathered_fields(sol)
    np.testing.assert_allclose(lit.phi - lit.direct, sol.phi - sol.direct, atol=1e-6)
    assert gathered_fields(sol) is not sol and lit.phi is gathered_fields(sol).phi   # made once
    thin = slab_scene(1.0, 16)
    thin_sol = popvol.solve(thin)
    assert transport_direct(thin_sol) is None and gathered_fields(thin_sol) is thin_sol


def test_the_cap_follows_the_diffusion_length_up_to_a_transport_mean_free_path():
    """medium.Medium.transport_depth_cap: MAX_TRANSPORT_DEPTH (2) mean free paths per voxel, or
    half the diffusion length L_d = 1 / sqrt(3 (1 - a) (1 - a g)) where that is more, but at most
    one transport mean free path, 1 / (1 - g); a and g the smallest of the medium's (of the
    voxels holding medium, for a grid of albedos)."""
    from popvol.medium import Medium

    def cap(albedo, g, density=None):
        rho = np.ones((4, 4, 4), np.float32) if density is None else density
        return Medium(rho, 0.25, [0.0, 0.0, 0.0], scale=40.0, albedo=albedo, g=g).transport_depth_cap()

    half_ld = 0.5 / np.sqrt(3 * 0.03 * (1 - 0.97 * 0.85))                 # 3.98 mean free paths
    for albedo, g, expect in ((1.0, 0.5, 2.0), (1.0, -0.5, 2.0), (0.999, 0.5, 2.0), (0.9, 0.85, 2.0),
                              (1.0, 0.6, 2.5), (1.0, 0.85, 1 / 0.15), (0.999, 0.85, 1 / 0.15),
                              (0.97, 0.85, half_ld)):
        assert cap(albedo, g) == pytest.approx(expect, rel=1e-6), (albedo, g)
    g = np.full((4, 4, 4), 0.85, np.float32)
    g[0, 0, 0] = 0.7
    assert cap(1.0, g) == pytest.approx(1 / 0.3, rel=1e-6)
    albedo = np.full((4, 4, 4), 1.0, np.float32)
    albedo[0, 0, 0] = 0.5                                           # in an empty voxel: not the medium's
    rho = np.ones((4, 4, 4), np.float32)
    rho[0, 0, 0] = 0.0
    assert cap(albedo, 0.85, rho) == pytest.approx(1 / 0.15, rel=1e-6)
    med = Medium(np.ones((4, 4, 4), np.float32), 0.25, [0.0, 0.0, 0.0], scale=40.0, albedo=1.0, g=0.85)
    assert med.transport_medium().max_voxel_optical_depth() == pytest.approx(1 / 0.15, rel=1e-6)   # 10 -> 6.7


def test_a_white_forward_scattering_slab_on_thick_voxels_against_monte_carlo(monkeypatch):
    """A cloud's optics, albedo 0.999 and g 0.85, on voxels of 10 mean free paths, empty voxels
    above the slab, against the plane-parallel Monte Carlo. Capped at 2 mean free paths per voxel,
    the slab is 8 mean free paths deep, 1.2 transport mean free paths, where light of this albedo
    comes back from some 50 (its diffusion length), so its scattered light leaks through: x0.39 /
    x0.43 at 16 / 32 cells (measured). Capped at one transport mean free path (6.7 mean free
    paths, less than half its diffusion length) x0.61 / x0.72: still too dark (the warning below),
    converging from below. An absorbing medium with the same g (albedo 0.9, diffusion length 3.8
    mean free paths) keeps the cap of 2, where it is within 6 % (x0.95 / x1.01); capped at one
    transport mean free path it would be x0.77 / x0.77."""
    def reflection(resolution, albedo=0.999):
        mc = half_space_mc(LIGHT, VIEW, albedo, 0.85, depth=slab_depth(10.0), n_photons=PHOTONS)
        scene = slab_scene(10.0, resolution, pad=2, albedo=albedo, g=0.85)
        return centre_radiance(popvol.render(scene, popvol.solve(scene), jitter=False)) / mc["total"]

    coarse, fine = reflection(16), reflection(32)
    assert 0.5 < coarse < fine < 1.0 + GOAL
    absorbing = reflection(32, albedo=0.9)
    assert absorbing == pytest.approx(1.0, abs=0.1)
    monkeypatch.setattr("popvol.medium.MAX_REDUCED_DEPTH", 0.0)           # capped at 2 mean free paths
    assert reflection(16) < coarse - 0.15 and reflection(32) < fine - 0.2
    assert reflection(32, albedo=0.9) == absorbing                        # already capped at 2
    monkeypatch.undo()
    monkeypatch.setattr("popvol.medium.DIFFUSION_LENGTH_SHARE", np.inf)   # at one transport mean free path
    assert reflection(32, albedo=0.9) < absorbing - 0.15


def test_a_medium_capped_short_of_its_diffusion_length_is_named_in_a_warning(tmp_path):
    """Where light transport caps voxels short of half the medium's diffusion length (held at one
    transport mean free path, or at 2 mean free paths where g <= 0.5), their scattered light
    leaks through and the image comes out too dark (the slab above, x0.61 at 16 cells; at g = 0.5
    and albedo 0.999 x0.56-0.66 from 10 mean free paths per voxel on, measured). popvol render
    says so in one line; not where the cap reaches half the diffusion length (albedo 0.9), nor
    where no voxel is capped."""
    import subprocess
    import sys
    assert "less than the depth this medium reflects light from" in \
        slab_scene(10.0, 16, albedo=0.999, g=0.85).medium.capped_scattering_warning()
    assert slab_scene(10.0, 16, albedo=0.999).medium.capped_scattering_warning() is not None   # g = 0.5
    assert slab_scene(10.0, 16).medium.capped_scattering_warning() is None                       # albedo 0.9
    assert slab_scene(10.0, 16, g=0.85).medium.capped_scattering_warning() is None
    assert slab_scene(4.0, 16, albedo=0.999, g=0.85).medium.capped_scattering_warning() is None  # not capped
    toml = tmp_path / "thick.toml"
    toml.write_text('[medium]\ntype = "procedural"\nresolution = 12\nscale = 400.0\ng = 0.85\n\n'
                    '[[lights]]\ntype = "directional"\ndirection = [0.3, -1.0, -0.2]\nirradiance = 1.0\n\n'
                    '[camera]\nwidth = 24\nheight = 16\n\n[method]\nresolution = 16\n')
    r = subprocess.run([sys.executable, "-m", "popvol.cli", "render", str(toml), "-o", str(tmp_path / "x.exr")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if "reflects light from" in line]
    assert len(lines) == 1 and lines[0].startswith(f"popvol: warning: {toml}: the densest voxels are"), r.stderr


@pytest.mark.parametrize("tau_voxel, within", [(0.5, 0.04), (2.0, 0.16)])
def test_fluence_inside_a_white_slab_against_monte_carlo(tau_voxel, within):
    """The fluence inside a white slab (albedo 1, g 0.85, four voxels deep, two empty voxels
    above it), voxel by voxel from the lit face down, against the plane-parallel Monte Carlo's
    mean over each voxel's depth: within 4 % on voxels of half a mean free path (measured x1.02 /
    x1.00 / x0.98 / x0.97), and on voxels of 2 (not capped) a regression guard within 16 % where
    the walk is known to be dark, more so with depth (x1.00 / x0.94 / x0.89 / x0.86; docs/METHOD.md,
    "Optically thick voxels": x0.76-x0.92 at 3.75, x0.66-x0.77 at 10, capped at 6.7)."""
    walk, cap = wide_slab_fluence(tau_voxel, 1.0, 0.85)
    assert cap > tau_voxel                                       # the walk's own voxels
    mc = slab_fluence_mc(-LIGHT[2], 1.0, 0.85, 4 * tau_voxel, 32, n_photons=200_000, seed=8).reshape(4, 8).mean(axis=1)
    np.testing.assert_allclose(walk, mc, rtol=within)
