"""A front-lit slab against the plane-parallel Monte Carlo of tests/montecarlo.py (independent of
popvol; itself checked against Chandrasekhar's H functions in test_montecarlo.py) as its voxels
thicken: the accuracy issue's dense-media item (docs/METHOD.md, "Optically thick voxels go dark").

The unscattered light scattered once is right where voxels are thin, and so is the whole
reflection (with the gathered last bounce, method.gather) at 0.25 mean free paths per voxel. It
misses the goal (within 5 % of Monte Carlo) from 1 mean free path per voxel up, and goes black
where voxels are many mean free paths thick, where an optically thick medium's reflection should
saturate at the albedo problem's value: those cases are strict expected failures, so that a fix
shows as an XPASS and must turn them into plain tests. With empty voxels above the slab, as a
volume from a file has, its single scattering stays right however thick the voxels (the march
splits optically thick segments). ``python scripts/dense_slab.py [--pad 2]`` prints the whole
table.
"""
import pytest

import popvol
from montecarlo import half_space_mc
from slab import ALBEDO, G, LIGHT, VIEW, centre_radiance, slab_depth, slab_scene

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


THICK = pytest.mark.xfail(strict=True, reason="#11 item 4: the reflection of a front-lit slab is x0.94 at "
                          "1 mean free path per voxel and goes black on thicker voxels (dense_slab.py)")


@pytest.mark.parametrize("tau_voxel", [0.25] + [pytest.param(t, marks=THICK) for t in (1.0, 10.0, 100.0, 1e4)])
def test_reflection_of_a_slab_matches_monte_carlo(tau_voxel):
    """The whole reflected radiance (every order of scattering) within GOAL of Monte Carlo, at 16
    cells, from 0.25 to 10^4 mean free paths per voxel: the level the issue asks for (measured
    x0.98 at 0.25, x0.94 at 1, x0.30 at 10, x0.09 at 100 and 10^4)."""
    mc = monte_carlo(tau_voxel)
    scene = slab_scene(tau_voxel, 16)
    total = centre_radiance(popvol.render(scene, popvol.solve(scene), jitter=False))
    assert total == pytest.approx(mc["total"], rel=GOAL, abs=3 * mc["stderr_total"])
