"""The gathered last scattering (method.gather, kernels/gather.py): the kernel against its
NumPy twin, and the front-lit slab's reflection against the plane-parallel Monte Carlo of
tests/montecarlo.py, where lighting the camera from the fields' lobes is 18-40 % too bright."""
import dataclasses

import numpy as np
import pytest

import popvol
import twins as ref
from popvol import hg, metrics, renderer
from popvol.pipeline import voxels_seen
from popvol.scene import apply_overrides

SUN = {"type": "directional", "direction": [-0.9, -0.4, -0.35], "irradiance": [5.0, 4.85, 4.5]}


def small_scene(**method):
    return popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 10, "seed": 3, "scale": 30.0, "albedo": 0.95, "g": 0.6},
        "lights": [SUN],
        "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 24, "height": 16},
        "method": {"resolution": 12, **method}})


@pytest.mark.parametrize("s_up, s_v, path", [(0.0, 0.0, 1.0), (1e-4, 3e-4, 2.0), (0.003, 0.001, 1.5), (0.3, 0.9, 1.0),
                                             (2.0, 5.0, 1.0), (40.0, 30.0, 1.0), (0.0, 4.0, 1.0), (3.0, 0.0, 1.0)])
def test_segment_integrates_a_linear_source_function_exactly(s_up, s_v, path):
    """A gathered segment's emission (docs/METHOD.md Eq. 25f): the closed-form weights of
    kernels.gather._segment against the twin's Gauss-Legendre quadrature of sigma_t
    linear along the path and the source function J = q / sigma_t linear in its optical depth,
    from a thin segment (the series) to one of 35 mean free paths and segments with an empty end;
    a J the same at both ends adds J (1 - T) (the equilibrium with a uniform sky)."""
    from popvol.kernels import gather as KG
    j_up, j_v = 0.7, 0.2
    t, a_up, a_v = KG._segment(s_up, s_v, path)
    tau = 0.5 * (s_up + s_v) * path
    assert t == pytest.approx(np.exp(-tau), rel=1e-12)
    got = a_up * j_up * s_up + a_v * j_v * s_v
    assert got == pytest.approx(ref._linear_source(j_up * s_up, s_up, j_v * s_v, s_v, path), rel=1e-7, abs=1e-15)
    same = a_up * 0.5 * s_up + a_v * 0.5 * s_v
    assert same == pytest.approx(0.5 * (1.0 - t), rel=1e-7, abs=1e-15)
    if tau > 20:            # the voxel's own first mean free paths: J(v) + (J(up) - J(v)) / tau
        assert got == pytest.approx(j_v + (j_up - j_v) / tau, rel=1e-6)


def test_gather_directions_cover_the_sphere():
    dirs, weights = renderer.gather_directions(200)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
    assert weights.sum() == pytest.approx(4 * np.pi)
    assert np.abs(dirs.mean(axis=0)).max() < 0.01                  # no preferred direction


def test_capped_directions_integrate_a_peaked_phase_function():
    """The phase function toward view directions inside the cap integrates to 1 (HG's
    normalisation) and its mean cosine to g: with half the directions in a 50-degree cap about
    the view axis, 64 directions miss by less than a third of what 64 on the whole sphere
    miss (measured: mean error 0.095 against 0.31, g = 0.877), and 256 by < 5 %."""
    from popvol import hg
    axis = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    rng = np.random.default_rng(0)
    views = axis + 0.25 * rng.normal(size=(400, 3))
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    views = views[views @ axis > np.cos(np.radians(35.0))]
    g = 0.877

    def errors(n, cap):
        dirs, weights = renderer.gather_directions(n, axis, cap)
        assert weights.sum() == pytest.approx(4 * np.pi)
        np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
        f = hg.f_hg(views @ dirs.T, g) * weights                       # (views, directions)
        return np.abs(f.sum(1) - 1.0), np.abs((f * (views @ dirs.T)).sum(1) / g - 1.0)

    capped, uniform = errors(64, np.radians(50.0)), errors(64, 0.0)
    assert capped[0].mean() < uniform[0].mean() / 3
    assert capped[1].mean() < uniform[1].mean() / 3
    assert max(e.max() for e in errors(256, np.radians(50.0))) < 0.05


def _gathered(scene, sol, n, separate=True):
    """renderer.gather's light at the voxels the renderer reads, from n directions capped about
    the view; without the sun's lobe gathered apart where ``separate`` is False."""
    inputs = renderer.render_inputs(scene, sol)
    with pytest.MonkeyPatch.context() as mp:
        if not separate:
            mp.setattr(renderer, "separated_sun", lambda medium, lights, lobes: (
                np.zeros(lobes.shape[1], np.bool_), np.array([0.0, 0.0, 1.0]), 0.0))
        return renderer.gather(inputs[0], inputs[1], renderer.field_bundles(sol),
                               np.asarray(scene.camera.origin, float), voxels_seen(scene.medium.density), n,
                               cap=renderer.gather_cap(scene.camera))


def test_sun_lobe_gathered_apart_converges_with_fewer_directions():
    """The sun's unscattered lobe (peaked: g = 0.85) and the phase toward the eye, integrated
    exactly and only the transported light averaged by the quadrature (renderer.separated_sun,
    docs/METHOD.md Eq. 25e), against the same gather from 4096 directions (the integral both
    converge to: the two agree there within 1e-4): with 64 directions the light gathered at
    the voxels is within 1 % in sum and 6 % rms of it (measured x1.002, 4.5 %), where gathering
    the lobe as the rest is x1.060 and 12.8 % rms, its peak falling between directions."""
    scene = small_scene()
    scene.medium.g = 0.85
    sol = popvol.solve(scene)
    converged = _gathered(scene, sol, 4096)
    lit = converged[..., 0] > 0
    assert lit.sum() > 200
    np.testing.assert_allclose(_gathered(scene, sol, 4096, False)[lit].sum(), converged[lit].sum(),
                               rtol=1e-4)

    def misses(light):
        return (light[lit].sum() / converged[lit].sum() - 1.0,
                np.sqrt(np.mean((light[lit] - converged[lit]) ** 2)) / converged[lit].mean())
    apart, together = misses(_gathered(scene, sol, 64)), misses(_gathered(scene, sol, 64, False))
    assert abs(apart[0]) < 0.01 and apart[1] < 0.06
    assert abs(together[0]) > 0.03 and together[1] > 2 * apart[1]


def test_the_brightest_suns_unscattered_lobe_is_taken_apart():
    """renderer.separated_sun takes apart the unscattered lobes (one per field channel) of the
    directional light that carries the most of that light, with its direction and anisotropy;
    none where g varies from voxel to voxel or only point lights shine."""
    def scene(lights, g=0.6):
        return popvol.scene_from_dict({
            "medium": {"type": "procedural", "resolution": 10, "seed": 3, "scale": 30.0, "albedo": [0.95, 0.9, 0.8],
                       "g": g},
            "lights": lights,
            "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 24, "height": 16},
            "method": {"resolution": 12}})

    def apart(sc):
        sol = popvol.solve(sc)
        medium, lights = renderer.render_inputs(sc, sol)[:2]
        state = renderer.gather_state(medium, lights, renderer.field_bundles(sol), voxels_seen(sc.medium.density), 1)
        return state[-1], sol

    dim = {"type": "directional", "direction": [-0.9, -0.4, -0.35], "irradiance": [1.0, 1.0, 1.0]}
    bright = {"type": "directional", "direction": [0.3, -0.9, 0.2], "irradiance": [4.0, 3.0, 2.0]}
    point = {"type": "point", "position": [0.0, 1.5, 0.0], "intensity": [50.0, 50.0, 50.0]}
    (separated, axis, g_sun), sol = apart(scene([dim, bright, point]))
    assert separated.sum() == sol.phi.shape[1]                  # the bright sun's lobe in each channel
    np.testing.assert_allclose(axis, sol.directions[1], atol=1e-6)
    assert g_sun == pytest.approx(0.6, rel=1e-6)
    assert not apart(scene([point]))[0][0].any()
    varying = scene([bright])
    varying.medium.g = np.linspace(0.3, 0.7, varying.medium.density.size, dtype=np.float32).reshape(
        varying.medium.shape)
    assert not apart(varying)[0][0].any()


def test_gather_cap_covers_the_view():
    scene = small_scene()
    axis, cap = renderer.gather_cap(scene.camera)
    fwd = scene.camera.basis()[0]
    np.testing.assert_allclose(axis, -fwd)
    rays = scene.camera.ray_directions()                        # every pixel's view direction
    widest = np.degrees(np.arccos((rays @ fwd).min()))          # a corner pixel's centre
    assert widest + 15.0 <= np.degrees(cap) <= widest + 17.0     # its corner: 1.3 degrees further out


@pytest.mark.parametrize("albedo", [0.95, [0.95, 0.9, 0.8]])
def test_gathered_source_equals_numpy_twin(albedo):
    """One sun in a grey medium is transported in one channel times its colour
    (renderer.one_colour), an RGB medium in three: both as the twin's RGB transport."""
    scene = small_scene()
    scene.medium.albedo = np.asarray(albedo, np.float64) * np.ones(3)
    sol = popvol.solve(scene)
    inputs = renderer.render_inputs(scene, sol)
    medium, lights = inputs[0], inputs[1]
    grid = renderer.field_bundles(sol)[0]
    colour = renderer.one_colour(medium, lights, grid)
    assert (colour is None) == isinstance(albedo, list)
    assert colour is None or np.array_equal(colour, SUN["irradiance"])
    seen = voxels_seen(scene.medium.density)
    got = renderer.gather(medium, lights, renderer.field_bundles(sol), np.asarray(scene.camera.origin, float),
                          seen, 12)
    dirs, weights = renderer.gather_directions(12)
    expect = ref.gathered_source(scene, sol, dirs, weights)
    assert expect.max() > 0
    np.testing.assert_allclose(got, expect, rtol=2e-4, atol=1e-6 * expect.max())


def test_one_colour_sweep_is_the_rgb_sweep_of_one_channel():
    """A change detector, named as one: kernels.gather._sweep_one_colour is _sweep's arithmetic
    for one channel in the same order, so the two give the same bits, direction by direction
    (axis-aligned and oblique, so that upstream points fall outside the grid), with per-voxel
    albedo and g. Its light itself is checked against the twin (test above)."""
    from popvol.kernels import gather as KG
    scene = small_scene()
    med = scene.medium
    rng = np.random.default_rng(4)
    med.albedo = (0.8 + 0.2 * rng.random(med.shape)).astype(np.float32)
    med.g = (0.3 + 0.5 * rng.random(med.shape)).astype(np.float32)
    sol = popvol.solve(scene)
    medium, lights = renderer.render_inputs(scene, sol)[:2]
    seen = voxels_seen(med.density)
    _, _, medium, grids, across_z, lobes, colour, _ = renderer.gather_state(medium, lights, renderer.field_bundles(sol),
                                                                         seen, 1)
    assert colour is not None                                   # one light in a grey medium
    to_eye = KG.eye_directions(medium, np.asarray(scene.camera.origin, np.float64), grids[4])
    grids, across_z = grids + (to_eye,), across_z + (renderer.z_first(to_eye),)
    dirs = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [0.6, -0.64, 0.48], [-0.3, 0.2, -0.93],
                     [0.57, 0.57, -0.59]])
    separated = np.zeros(lobes.shape[1], np.bool_)
    separated[0] = True                                         # the sun's unscattered lobe, apart
    for w in dirs / np.linalg.norm(dirs, axis=1)[:, None]:
        outs = [np.zeros(grids[0].shape + (1,), np.float32) for _ in range(4)]
        norms = [np.zeros(grids[0].shape, np.float32) for _ in range(4)]
        none = np.zeros(1)                                      # no light with a region's pattern
        KG._sweep(medium, lobes, grids, across_z, w, 0.7, outs[0], norms[0], np.array([0.3]), separated, 0.9,
                  outs[2], norms[2], none)
        KG._sweep_one_colour(medium, lobes, grids, across_z, w, 0.7, outs[1], norms[1], 0.3, separated, 0.9,
                             outs[3], norms[3], none)
        assert outs[0].max() > 0 and outs[2].max() > 0
        for got, expect in zip(outs[1::2] + norms[1::2], outs[::2] + norms[::2]):
            np.testing.assert_array_equal(got, expect)


def sky_scene(zenith=(0.3, 0.5, 1.0), horizon=(0.6, 0.6, 0.7), ground=(0.1, 0.1, 0.1), lights=8, **medium):
    """small_scene's cloud under an analytic sky alone (``lights`` lights), 12 gathered directions."""
    return popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 10, "seed": 3, "scale": 30.0, "albedo": 0.95, "g": 0.6,
                   **medium},
        "lights": [{"type": "sky", "zenith": list(zenith), "horizon": list(horizon), "ground": list(ground),
                    "lights": lights}],
        "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 24, "height": 16},
        "method": {"resolution": 12, "gather": 12}})


def test_environment_enters_the_gather_through_the_grids_faces():
    """The regions of an environment map are gathered: the light entering the grid along each
    direction is the map's radiance from the opposite direction (renderer.gathered_environment),
    then transported as the lobes' light is; the grey RGB sweep (kernels.gather._sweep_grey)
    against the twin's transport of the same boundary, and the same scene without the boundary
    darker (its first scattering is the boundary's)."""
    from popvol.kernels.render import background_radiance
    scene = sky_scene()
    sol = popvol.solve(scene)
    env, regions, patterns = renderer.gathered_environment(scene, sol)
    assert regions.all() and env.shape == scene.environment.radiance.shape
    medium, lights = renderer.render_inputs(scene, sol)[:2]
    assert np.array_equal(lights[5], sol.lobe_a0) and (lights[5] > 0).all()    # their unscattered lobes
    seen = voxels_seen(scene.medium.density)
    eye = np.asarray(scene.camera.origin, float)
    got = renderer.gather(medium, lights, renderer.field_bundles(sol), eye, seen, 12, environment=env,
                          patterns=patterns)
    dirs, weights = renderer.gather_directions(12)
    boundary = np.array([background_radiance(env, -w) for w in dirs])
    expect = ref.gathered_source(scene, sol, dirs, weights, boundary)
    np.testing.assert_allclose(got, expect, rtol=2e-4, atol=1e-6 * expect.max())
    closed = renderer.gather(medium, lights, renderer.field_bundles(sol), eye, seen, 12, patterns=patterns)
    assert closed.sum() < 0.6 * got.sum()


@pytest.mark.parametrize("H, g", [(64, 0.6), (64, 0.85), (128, 0.85)])
def test_region_pattern_of_the_whole_sky_is_isotropic(H, g):
    """A region that is the whole sky, of one radiance, sends its unscattered light every way
    alike: what it scatters toward any direction is the phase function's integral over the
    sphere, 1 / (4 pi) per steradian, whatever g (renderer.region_pattern, .pattern_table; a
    map of 128 rows in blocks of 2 x 2 texels)."""
    env = np.full((H, 2 * H, 3), 0.7, np.float32)
    pattern = renderer.region_pattern(env, np.ones((H, 2 * H), bool))
    assert len(pattern[1]) == 64 * 128 and pattern[1].sum() == pytest.approx(1.0)
    w = np.random.default_rng(1).normal(size=(40, 3))
    got = renderer.pattern_table([None, pattern], w / np.linalg.norm(w, axis=1)[:, None], g)
    assert np.all(got[:, 0] == 0)
    np.testing.assert_allclose(got[:, 1], 1 / (4 * np.pi), rtol=0.01)


def test_region_pattern_of_a_cap_is_its_phase_integral():
    """A region that is a cap of the sky of half-angle 30 degrees about its axis a, of one
    radiance, taken from its texels, against the phase function integrated over the cap by
    quadrature in polar angle and azimuth about a (independent of the map's texels): what it
    scatters toward w is int_cap f_hg(-s . w; g) ds / Omega_cap, within 2 % at w along, across
    and against a, and half-way between against and across."""
    H, g = 64, 0.6
    from popvol.envmap import texel_geometry
    toward, _ = texel_geometry(H, 2 * H)
    a = np.array([0.3, 0.8, -0.52])
    a /= np.linalg.norm(a)
    cap = np.radians(30.0)
    pattern = renderer.region_pattern(np.ones((H, 2 * H, 3), np.float32), toward @ a >= np.cos(cap))
    p_ = np.cross(a, [1.0, 0.0, 0.0])
    p_ /= np.linalg.norm(p_)
    q_ = np.cross(a, p_)
    theta = (np.arange(400) + 0.5) * cap / 400
    phi = (np.arange(400) + 0.5) * 2 * np.pi / 400
    T, P = np.meshgrid(theta, phi, indexing="ij")
    s_ = (np.cos(T)[..., None] * a + (np.sin(T) * np.cos(P))[..., None] * p_ + (np.sin(T) * np.sin(P))[..., None] * q_)
    dA = np.sin(T) * (cap / 400) * (2 * np.pi / 400)
    for w in (-a, a, p_, (-a + p_) / np.sqrt(2)):
        expect = np.sum(hg.f_hg(np.clip(-(s_ @ w), -1, 1), g) * dA) / np.sum(dA)
        got = renderer.pattern_table([pattern], w[None], g)[0, 0]
        assert got == pytest.approx(expect, rel=0.02), w


def test_regions_keep_their_unscattered_lobe_for_the_gather_alone():
    """An environment region walked by the ordinates keeps its unscattered lobe in ``direct``
    (Beer-Lambert along its direction; Solution.lobe_a0 its a0), a part of its phid, with phi and
    phia 0: the samples do not scatter it once (Solution.single_scattering leaves the regions
    nothing), and without the gather the image is what its whole walked light gives."""
    scene = sky_scene()
    sol = popvol.solve(scene)
    a0 = np.array([light.a0 for light in scene.lights])
    np.testing.assert_array_equal(sol.lobe_a0, a0)
    assert (0 < a0).all() and (a0 < 1).all() and not sol.unscattered.any()
    assert sol.direct.max() > 0 and not sol.phi.any() and not sol.phia.any()
    assert np.all(sol.direct <= sol.phid * (1 + 1e-5) + 1e-7)
    single = sol.single_scattering()
    assert not single.direct.any() and not single.phi.any() and sol.direct.max() > 0
    plain = popvol.render(apply_overrides(scene, gather=0), sol, jitter=False)
    cut = dataclasses.replace(sol, direct=np.zeros_like(sol.direct), lobe_a0=None)
    np.testing.assert_array_equal(popvol.render(apply_overrides(scene, gather=0), cut, jitter=False), plain)


def test_grey_rgb_sweep_is_the_rgb_sweep():
    """A change detector, named as one: kernels.gather._sweep_grey is _sweep's arithmetic with
    the channels written out, so the two agree to float rounding, direction by direction
    (axis-aligned and oblique), with light entering the grid."""
    from popvol.kernels import gather as KG
    scene = sky_scene()
    sol = popvol.solve(scene)
    medium, lights = renderer.render_inputs(scene, sol)[:2]
    seen = voxels_seen(scene.medium.density)
    _, _, medium, grids, across_z, lobes, colour, _ = renderer.gather_state(medium, lights, renderer.field_bundles(sol),
                                                                         seen, 1, True)
    patterns = renderer.gathered_environment(scene, sol)[2]
    assert colour is None and (lobes[:, :, 3] >= KG.PATTERN).any()
    to_eye = KG.eye_directions(medium, np.asarray(scene.camera.origin, np.float64), grids[4])
    grids, across_z = grids + (to_eye,), across_z + (renderer.z_first(to_eye),)
    dirs = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [0.6, -0.64, 0.48], [-0.3, 0.2, -0.93]])
    separated = np.zeros(lobes.shape[1], np.bool_)
    separated[lobes.shape[1] // 2] = True                       # one lobe apart, as a sun's would be
    for w in dirs / np.linalg.norm(dirs, axis=1)[:, None]:
        outs = [np.zeros(grids[0].shape + (3,), np.float32) for _ in range(4)]
        norms = [np.zeros(grids[0].shape, np.float32) for _ in range(4)]
        entering = np.array([0.2, 0.3, 0.4])
        # the regions' unscattered lobes, in their patterns toward w
        pattern = renderer.pattern_table(patterns, w[None], 0.6)[0]
        KG._sweep(medium, lobes, grids, across_z, w, 0.7, outs[0], norms[0], entering, separated, 0.9, outs[2],
                  norms[2], pattern)
        KG._sweep_grey(medium, lobes, grids, across_z, w, 0.7, outs[1], norms[1], entering, separated, 0.9, outs[3],
                       norms[3], pattern)
        assert outs[0].max() > 0 and outs[2].max() > 0
        for got, expect in ((outs[1], outs[0]), (outs[3], outs[2])):
            np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-7 * expect.max())
        np.testing.assert_array_equal(norms[1], norms[0])
        np.testing.assert_array_equal(norms[3], norms[2])


@pytest.mark.parametrize("g, scale, lights, within, mean_within", [
    (0.6, 2.0, 8, 0.02, 0.01), (0.6, 30.0, 32, 0.07, 0.03), (0.85, 2.0, 8, 0.02, 0.01), (0.85, 2.0, 32, 0.02, 0.01),
    (0.85, 100.0, 32, 0.16, 0.05)])
def test_uniform_environment_keeps_a_white_medium_at_its_radiance(g, scale, lights, within, mean_within):
    """In an isotropic radiance field L0 a medium that absorbs nothing changes nothing: every
    ray leaves it with L0, whatever its density and phase function (the equilibrium of the
    transport equation). A cloud of albedo 1 under a uniform sky of L0 = 1, split into 8 or 32
    lights, renders every pixel that sees it at 1 (mean (min-max) measured, `python
    scripts/white_medium.py`): with g = 0.6 within 2 % at an optical depth of 2 along the view
    (8 lights: 1.002 (0.994-1.018)) and within 7 % at 30 (32 lights: 0.977 (0.934-1.000); voxels
    of 3.75 mean free paths, capped at 2.5 for light transport; with ``tail = 0``, every packet
    walked on the domains' own cells, 0.982 (0.959-1.000): the darkest inner pixels darken with the
    light the tail walks on blocks of 2^3 cells, 0.947 with a tenth of it, 0.934 with the 15 % of
    the default, docs/METHOD.md "The walk's tail on wider cells"); with g = 0.85 within 2 % at 2
    (8 lights: 0.997 (0.987-1.000); 32: 1.000 (0.993-1.003)). Each region's unscattered lobe is
    gathered in its region's own pattern (docs/METHOD.md Eq. 26a); one HG lobe per region for
    all its light left g = 0.85 at 2 with 8 lights at 0.964 (0.875-0.999) and with 32 at 0.991
    (0.954-1.003). A regression guard where the walk is known to be dark, g = 0.85 on voxels of
    12.5 mean free paths (capped at 6.7, one transport mean free path): 0.952 (0.864-1.018), its
    inner pixels the dark ones (docs/METHOD.md, "Optically thick voxels")."""
    scene = sky_scene((1.0, 1.0, 1.0), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0), lights=lights, albedo=1.0, g=g, scale=scale,
                      resolution=16)
    scene = apply_overrides(scene, resolution=16, gather=64)
    img = popvol.render(scene, popvol.solve(scene))
    seen = metrics.camera_optical_depth(scene) > 0.05
    assert seen.sum() > 80
    assert np.abs(img[seen] - 1.0).max() < within
    assert abs(float(img[seen].mean()) - 1.0) < mean_within


def test_gather_changes_only_the_rendering():
    """gather is a render-only knob: the solution is reused, and the image changes (gather = 0:
    the fields' lobes light every sample)."""
    scene = small_scene(gather=0)
    sol = popvol.solve(scene)
    plain = popvol.render(scene, sol, jitter=False)
    scene = apply_overrides(scene, gather=16)             # the same medium, another method
    gathered = popvol.render(scene, sol, jitter=False)
    assert np.all(np.isfinite(gathered)) and gathered.max() > 0
    assert not np.allclose(gathered, plain)
    again = popvol.solve(scene, reuse=sol)
    assert all(d.reused for d in again.domains)


@pytest.mark.parametrize("tau, resolution, blocks, band", [(0.25, 16, 0, 0.07), (0.25, 32, 0, 0.07), (1.0, 16, 0, 0.07),
                                                           (1.0, 32, 0, 0.07), (0.25, 32, 8, 0.10)])
def test_front_lit_slab_with_gathered_last_bounce_matches_monte_carlo(tau, resolution, blocks, band):
    """The slab of tests/slab.py (albedo 0.9, g 0.5, sun behind the camera, seen straight
    down): with 64 gathered directions its reflected radiance is within 7 % of the half-space
    Monte Carlo at 0.25 and 1 mean free paths per voxel (measured with the default, eighteen
    ordinates and the sun's lobe gathered apart: x0.938 / x0.947 at 0.25, x0.965 / x0.992 at 1,
    16 / 32 cells; with the one-lobe sweeps x0.971 / x0.941 and x0.946 / x1.056), where lighting
    the camera from the fields' lobes is x1.17-x1.41 (gather = 0). Gathered on blocks of 2^3
    voxels (gather_resolution 8; half a mean free path each, so the slab, 4 voxels thick, is
    two blocks thick) within 10 % (measured x0.935 at 32 cells)."""
    from montecarlo import half_space_mc
    from slab import ALBEDO, G, LIGHT, VIEW, centre_radiance, slab_depth, slab_scene
    mc = half_space_mc(LIGHT, VIEW, ALBEDO, G, depth=slab_depth(tau), n_photons=100_000, seed=5)
    scene = apply_overrides(slab_scene(tau, resolution), gather=64, gather_resolution=blocks)
    assert renderer.gather_factor(scene.medium, blocks) == (2 if blocks else 1)
    total = centre_radiance(popvol.render(scene, popvol.solve(scene), jitter=False))
    assert total / mc["total"] == pytest.approx(1.0, abs=band)


def test_block_mean_is_the_mean_of_each_block():
    x = np.random.default_rng(1).random((2, 7, 5, 9)).astype(np.float32)
    got = renderer.block_mean(x, 3)
    assert got.shape == (2, 3, 2, 3)
    for i, j, k in np.ndindex(3, 2, 3):        # the edge blocks hold 1, 2 or 3 voxels per axis
        expect = x[:, 3 * i:3 * i + 3, 3 * j:3 * j + 3, 3 * k:3 * k + 3].mean(axis=(1, 2, 3))
        np.testing.assert_allclose(got[:, i, j, k], expect, rtol=1e-6)


def test_block_sums_kernel_equals_numpy_twin():
    x = np.random.default_rng(2).random((3, 2, 11, 7, 9)).astype(np.float32)
    for factor in (1, 2, 3, 4):
        np.testing.assert_allclose(renderer.block_mean(x, factor), ref.block_mean(x, factor), rtol=1e-5)



def test_block_mean_on_some_blocks_only():
    """renderer.block_mean with ``only`` (kernels.sampling.block_sums' mask): the marked blocks
    hold the twin's means, bit for bit those of the whole grid's, and the others 0; the voxels
    on rows of blocks without a marked block are not read (NaN there changes nothing)."""
    rng = np.random.default_rng(5)
    x = rng.random((2, 11, 7, 9)).astype(np.float32)
    for factor in (2, 3):
        shape = tuple(-(-n // factor) for n in x.shape[1:])
        only = rng.random(shape) < 0.3
        only[0, 0] = False                      # the row of blocks (0, 0, :): no block marked
        x_nan = x.copy()
        x_nan[:, :factor, :factor, :] = np.nan
        got = renderer.block_mean(x_nan, factor, only)
        whole = renderer.block_mean(x, factor)
        assert np.array_equal(got[:, only], whole[:, only])
        np.testing.assert_allclose(got[:, only], ref.block_mean(x, factor)[:, only], rtol=1e-5)
        assert not got[:, ~only].any()


def test_upsample_reproduces_a_linear_field():
    """Trilinear interpolation between the blocks' centres is exact for a linear function of
    the voxel index, inside the outermost centres (clamped to the edge outside them); voxels not
    needed stay 0."""
    factor, shape = 3, (12, 9, 15)
    centres = [(np.arange(-(-n // factor)) * factor + 0.5 * (factor - 1)) for n in shape]
    f = (lambda x, y, z: 0.5 + 2.0 * x - 1.0 * y + 0.25 * z)
    coarse = f(*np.meshgrid(*centres, indexing="ij"))[..., None]
    needed = np.random.default_rng(3).random(shape) < 0.7
    got = renderer.upsample(coarse.astype(np.float32), factor, needed)[..., 0]
    idx = np.meshgrid(*[np.clip(np.arange(n), c[0], c[-1]) for n, c in zip(shape, centres)], indexing="ij")
    np.testing.assert_allclose(got[needed], f(*idx)[needed], rtol=1e-5, atol=1e-5)
    assert np.all(got[~needed] == 0)


def test_upsample_kernel_equals_numpy_twin():
    coarse = np.random.default_rng(4).random((4, 3, 5, 3)).astype(np.float32)
    needed = np.ones((11, 7, 14), bool)
    for factor in (2, 3):
        np.testing.assert_allclose(renderer.upsample(coarse, factor, needed),
                                   ref.upsample(coarse, factor, needed.shape), rtol=1e-5, atol=1e-6)


def test_gather_does_not_depend_on_its_lanes(monkeypatch):
    """Directions swept in one lane or four (in parallel) give the same light."""
    scene = small_scene()
    sol = popvol.solve(scene)
    inputs = renderer.render_inputs(scene, sol)
    args = (inputs[0], inputs[1], renderer.field_bundles(sol), np.asarray(scene.camera.origin, float),
            voxels_seen(scene.medium.density), 12)
    four = renderer.gather(*args)
    monkeypatch.setattr(renderer, "GATHER_LANES", 1)
    np.testing.assert_allclose(renderer.gather(*args), four, rtol=1e-5, atol=1e-7 * four.max())


def test_a_coarser_gather_grid_keeps_the_image():
    """Gathering on blocks of 2^3 voxels of an optically thin cloud (0.2 mean free paths per
    voxel where it is dense) changes the image by little against the voxels' own grid, and
    far less than the gather itself changes it (measured with the one-lobe sweeps: relMSE 0.003
    against the gather's 0.012; the six ordinates' lobes are nearer the gathered light here,
    0.0025 against 0.0019)."""
    from popvol import metrics
    scene = popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 20, "seed": 3, "scale": 2.0, "albedo": 0.95, "g": 0.6},
        "lights": [SUN],
        "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 48, "height": 32},
        "method": {"resolution": 20, "gather": 32, "gather_resolution": 0},
        "experimental": {"solver": "sweep"}})        # whose lobes the gather changes most
    assert renderer.gather_factor(scene.medium, 10) == 2
    sol = popvol.solve(scene)
    fine = popvol.render(scene, sol, jitter=False)
    coarse = popvol.render(apply_overrides(scene, gather_resolution=10), sol, jitter=False)
    plain = popvol.render(apply_overrides(scene, gather=0), sol, jitter=False)
    mask = metrics.luminance_mask(fine)
    change, no_gather = metrics.relmse(coarse, fine, mask), metrics.relmse(plain, fine, mask)
    print(f"coarse gather {change:.4f}, no gather {no_gather:.4f}")
    assert change < 0.3 * no_gather


def test_gather_blocks_stay_optically_thin():
    """The factor gather_resolution asks for is cut where a block would be wider than half a
    mean free path: the slab of tests/slab.py (16 voxels across) at 1 mean free path per
    voxel keeps its voxels, at 0.125 takes blocks of 4^3."""
    from slab import slab_scene
    assert renderer.gather_factor(slab_scene(0.125, 16).medium, 4) == 4
    assert renderer.gather_factor(slab_scene(0.125, 16).medium, 0) == 1
    assert renderer.gather_factor(slab_scene(1.0, 16).medium, 4) == 1


def test_single_scattering_solution_is_not_gathered():
    """A solution of the unscattered light alone renders as the single scattering whatever
    method.gather says (the samples light it; nothing is gathered from it)."""
    scene = small_scene()
    single = popvol.solve(scene).single_scattering()
    np.testing.assert_array_equal(popvol.render(scene, single, jitter=False),
                                  popvol.render(apply_overrides(scene, gather=0), single, jitter=False))


def test_a_camera_move_gathers_from_what_the_last_frame_kept(monkeypatch):
    """What the gather makes before the camera is known (renderer.gather_state: the transport
    grid, the cells' lobes) is kept with the solution, so a second view of the same solution
    makes it once, and its image is bit for bit that of a solution without the kept state; a
    change of the light's power (Solution.relit, which shares the cache) makes it anew, and a
    changed medium is refused the solution (its kept state is never read for it)."""
    made = []
    real = renderer.gather_state
    monkeypatch.setattr(renderer, "gather_state", lambda *a: made.append(1) or real(*a))
    scene = small_scene(gather=16)
    sol = popvol.solve(scene)
    moved = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, origin=(0.4, 0.5, 2.3)))
    popvol.render(scene, sol)
    kept = popvol.render(moved, sol)
    assert len(made) == 1
    fresh = popvol.render(moved, dataclasses.replace(sol, cache={}))
    assert len(made) == 2 and np.array_equal(kept, fresh)
    brighter = [dataclasses.replace(scene.lights[0], irradiance=[10.0, 9.7, 9.0])]
    relit = popvol.render(moved, sol.relit(brighter))
    assert len(made) == 3
    np.testing.assert_allclose(relit, 2.0 * kept, rtol=1e-5, atol=1e-7)
    denser = dataclasses.replace(moved, medium=dataclasses.replace(moved.medium, scale=60.0))
    with pytest.raises(popvol.PopvolError, match="solved for another medium"):
        popvol.render(denser, sol)
    assert len(made) == 3


def test_gather_within_the_occupied_box_is_the_whole_grids(monkeypatch):
    """Transporting the light only within the box of the occupied voxels (plus GATHER_MARGIN)
    gives the light of the whole grid: nothing outside emits, and what leaves never returns."""
    scene = popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 24, "seed": 3, "scale": 2.0, "albedo": 0.95, "g": 0.6},
        "lights": [SUN], "method": {"resolution": 16},
        "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 24, "height": 16}})
    from popvol.medium import Medium
    med = scene.medium                                    # the cloud in a grid 6 voxels wider
    scene.medium = Medium(np.pad(med.density, 6), med.voxel_size, med.origin - 6 * med.voxel_size,
                          scale=med.scale, albedo=med.albedo, g=med.g)
    sol = popvol.solve(scene)
    inputs = renderer.render_inputs(scene, sol)
    seen = voxels_seen(scene.medium.density)
    box = renderer.occupied_box((scene.medium.density > 0) | seen, renderer.GATHER_MARGIN)
    assert np.prod([b.stop - b.start for b in box]) < 0.8 * seen.size           # the test crops
    args = (inputs[0], inputs[1], renderer.field_bundles(sol), np.asarray(scene.camera.origin, float), seen, 16)
    cropped = renderer.gather(*args)
    monkeypatch.setattr(renderer, "GATHER_MARGIN", 1000)
    whole = renderer.gather(*args)
    assert cropped.max() > 0
    np.testing.assert_allclose(cropped, whole, rtol=1e-4, atol=1e-6 * whole.max())


def test_gather_state_hands_the_kernels_c_ordered_masks():
    """A compile-time guard, not a check of the light: the masks gather_state hands the gather's
    kernels are C-ordered arrays whether the occupied box crops the grid or not. A view of a
    cropped box has Numba's 'A' layout, one of the whole grid 'C', and each layout compiled
    gathered_source, its sweep, eye_directions and upsample_blocks once more (about 12 s)."""
    scene = popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 24, "seed": 3, "scale": 2.0, "albedo": 0.95, "g": 0.6},
        "lights": [SUN], "method": {"resolution": 16},
        "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 24, "height": 16}})
    from popvol.medium import Medium
    med = scene.medium
    # a cloud with empty space around it (the box crops the grid); a medium filling its grid
    for density, cropped in ((np.pad(med.density, 6), True), (np.full((10, 8, 10), 0.5, np.float32), False)):
        scene.medium = Medium(density, med.voxel_size, med.origin, scale=med.scale, albedo=med.albedo, g=med.g)
        sol = popvol.solve(scene)
        inputs = renderer.render_inputs(scene, sol)
        seen = voxels_seen(scene.medium.density)
        for factor in (1, 2):
            _, seen_box, _, grids, _, _, _, _ = renderer.gather_state(inputs[0], inputs[1], renderer.field_bundles(sol),
                                                                   seen, factor)
            assert (seen_box.shape != seen.shape) == cropped
            assert seen_box.flags.c_contiguous and grids[4].flags.c_contiguous, (cropped, factor)


def test_environment_regions_are_gathered_and_relit_with_their_lights():
    """An environment's regions (a0 < 1) have no unscattered part to scatter once at the
    samples: the gather takes their first scattering from the map, entering through the grid's
    faces, so a sky alone is gathered (another image than its lobes give, gather = 0). The
    gathered light is linear in the lights' powers, the map's light scaled with its regions'
    (renderer.gathered_environment): the sun and the sky lit together are the sun alone plus
    the sky alone, over the background that each render holds once; the sun alone is the sun's
    own scene."""
    sky = {"type": "sky", "lights": 4}
    base = {"medium": {"type": "procedural", "resolution": 12, "seed": 3, "scale": 8.0, "albedo": 0.95, "g": 0.6},
            "camera": {"origin": [0.0, 0.3, 2.4], "target": [0.0, 0.5, 0.0], "fov": 40.0, "width": 32, "height": 20},
            "method": {"resolution": 12}}
    scene = popvol.scene_from_dict({**base, "lights": [sky]})
    sol = popvol.solve(scene)
    assert not sol.unscattered.any() and all(light.map_region for light in scene.lights)
    gathered = popvol.render(scene, sol, jitter=False)
    plain = popvol.render(apply_overrides(scene, gather=0), sol, jitter=False)
    assert not np.allclose(gathered, plain, rtol=0.01)
    scene = popvol.scene_from_dict({**base, "lights": [SUN, sky]})
    sol = popvol.solve(scene)
    assert list(sol.unscattered) == [True] + [False] * (len(sol.unscattered) - 1)
    dark = (lambda l: dataclasses.replace(l, irradiance=np.zeros(3)))
    sun_only = sol.relit([scene.lights[0]] + [dark(l) for l in scene.lights[1:]])
    sky_only = sol.relit([dark(scene.lights[0])] + scene.lights[1:])
    none = sol.relit([dark(l) for l in scene.lights])
    both = popvol.render(scene, sol, jitter=False)
    sun = popvol.render(scene, sun_only, jitter=False)
    background = popvol.render(scene, none, jitter=False)
    sky = popvol.render(scene, sky_only, jitter=False)
    assert (sun - background).max() > 0 and (sky - background).max() > 0
    np.testing.assert_allclose(both + background, sun + sky, rtol=1e-4, atol=1e-5 * both.max())
    alone = popvol.scene_from_dict({**base, "lights": [SUN]})          # the sun gathered by itself
    sun_alone = popvol.render(alone, popvol.solve(alone), jitter=False)
    np.testing.assert_allclose(sun - background, sun_alone, rtol=1e-4, atol=1e-6 * sun_alone.max())


def rays_into_ball(r, R, n, seed):
    """Points sampled about p = 0 as y = s u (u uniform on the sphere, s uniform in [0, r + R]),
    which weights the volume by 1/|y|^2, and which of them land in the ball of radius R centred
    at (r, 0, 0): (u float64 (n, 3), inside bool (n,))."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    s = rng.random(n) * (r + R)
    return u, np.linalg.norm(s[:, None] * u - np.array([r, 0.0, 0.0]), axis=1) <= R


@pytest.mark.parametrize("r_over_R", [0.0, 0.3, 0.99, 1.0, 1.01, 2.0, 3.9, 4.1, 10.0, 1e3])
def test_mean_inverse_square_is_the_balls_mean(r_over_R):
    """kernels.gather.mean_inverse_square against a Monte Carlo mean of 1/|y - p|^2 over the
    ball, sampled about p (y = p + s u, s uniform in [0, r + R], u uniform): the integral over
    the ball is then 4 pi (r + R) times the fraction of samples that land in it, with finite
    variance even where p is inside the ball (where 1/r^2 is not bounded)."""
    from popvol.kernels.gather import mean_inverse_square
    R = 0.7
    r = r_over_R * R
    n = 2_000_000
    u, inside = rays_into_ball(r, R, n, seed=1)
    mc = 4 * np.pi * (r + R) * inside.mean() / (4 / 3 * np.pi * R ** 3)
    se = 4 * np.pi * (r + R) * inside.std() / np.sqrt(n) / (4 / 3 * np.pi * R ** 3)
    if r_over_R < 100:                                # farther, few samples land in the ball
        assert mean_inverse_square(r, R) == pytest.approx(mc, rel=1e-12, abs=4 * se)
    if r_over_R >= 10:
        assert mean_inverse_square(r, R) == pytest.approx(1 / r ** 2, rel=R ** 2 / r ** 2)


@pytest.mark.parametrize("r_over_R", [0.0, 0.3, 0.99, 1.0, 1.01, 2.0, 3.9, 10.0])
def test_mean_radial_cosine_is_the_balls_weighted_mean_direction(r_over_R):
    """kernels.gather.mean_radial_cosine against a Monte Carlo mean, over the ball, of the unit
    vector from p weighted by 1/|y - p|^2: sampled about p as above (y = p + s u, s uniform in
    [0, r + R]), each sample that lands in the ball already carries that weight, so the mean is
    the mean of u over them, along the line from p to the ball's centre. Also its limits: 0 with
    p at the centre, 2/3 on the surface, 1 - x^2/5 far away (x = R/r)."""
    from popvol.kernels.gather import mean_inverse_square, mean_radial_cosine as radial
    R = 0.7
    r = r_over_R * R
    mean_radial_cosine = lambda r, R: radial(r, R, mean_inverse_square(r, R))
    u, inside = rays_into_ball(r, R, 2_000_000, seed=2)
    ux = u[inside, 0]
    assert abs(mean_radial_cosine(r, R) - ux.mean()) < 4 * ux.std() / np.sqrt(inside.sum()) + 1e-12
    if r_over_R == 0.0:
        assert mean_radial_cosine(r, R) == 0.0
    if r_over_R == 1.0:
        assert mean_radial_cosine(r, R) == pytest.approx(2.0 / 3.0, rel=1e-12)
    if r_over_R >= 10:
        assert mean_radial_cosine(r, R) == pytest.approx(1.0 - (R / r) ** 2 / 5.0, abs=(R / r) ** 4)


def test_a_point_lights_own_cell_scatters_its_light_every_way(monkeypatch):
    """The gather's emission lobes (kernels.gather.emission_lobes) of a point light: about the
    cell's mean direction from the light with g times mean_radial_cosine, so the cell that holds
    the light sends its light every way (g near 0), where the lobe at the cell's centre alone
    would have sent it all about whichever way the centre lies from the light; a cell far from
    it keeps nearly the medium's g."""
    from popvol.kernels.gather import mean_inverse_square, mean_radial_cosine
    from popvol import renderer

    def scene_at(position):
        return popvol.scene_from_dict({
            "medium": {"type": "procedural", "style": "smooth", "resolution": 16, "scale": 4.0, "albedo": 0.9,
                       "g": 0.8},
            "lights": [{"type": "point", "position": list(position), "intensity": [1.0, 1.0, 1.0]}],
            "camera": {"origin": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "width": 32, "height": 32},
            "method": {"resolution": 16, "gather_resolution": 0}})

    def lobes_of(position):
        scene = scene_at(position)
        kept = []
        real = renderer.gather_state
        with monkeypatch.context() as m:             # keep what the gather transports
            m.setattr(renderer, "gather_state", lambda *a, **k: kept.append(real(*a, **k)) or kept[-1])
            popvol.render(scene, popvol.solve(scene))
        box, seen, medium, grids, across_z, lobes, colour, sun = kept[0]
        centres = medium[5] + np.argwhere(grids[0] > 0) * medium[6]
        R = (3.0 * np.prod(medium[6]) / (4.0 * np.pi)) ** (1.0 / 3.0)
        return np.linalg.norm(centres - np.asarray(position), axis=1), R, lobes[:, 0, 3], medium[6]

    # the light 1 % of a voxel from the centre of the non-empty voxel nearest the middle (the
    # gather's cells are the voxels: gather_resolution 0)
    med = scene_at((0.0, 0.0, 0.0)).medium
    centres = med.origin + np.argwhere(med.density > 0) * med.voxel_size
    centre = centres[np.argmin(np.linalg.norm(centres, axis=1))]
    r, R, g, voxel = lobes_of(centre + 0.01 * med.voxel_size)
    nearest, farthest = np.argmin(r), np.argmax(r)
    for cell in (nearest, farthest):             # g (the unscattered light's lobe) times |m|
        assert g[cell] == pytest.approx(0.8 * mean_radial_cosine(r[cell], R, mean_inverse_square(r[cell], R)),
                                        abs=1e-6)
    assert r[nearest] < 0.02 * voxel.max() and g[nearest] < 0.02
    assert g[farthest] > 0.78


def test_a_point_light_on_a_cell_centre_is_lit_as_the_cells_mean(tmp_path):
    """A point light exactly on a voxel centre (integer coordinates on a grid of unit voxels):
    the gathered last bounce lights each cell by the mean of 1/r^2 over it, so the image is
    what a light 1 % or a quarter of a voxel away gives (within 2 % / 15 %), and what the
    image without the gather gives within 5 % (1/r^2 at the centre made it 10^24 too bright)."""
    from popvol.camera import Camera
    from popvol.lights import PointLight
    from popvol.medium import Medium
    from popvol.method import Method
    from popvol.scene import Scene

    def image(position, gather=64):
        med = Medium(np.ones((8, 8, 8), np.float32), 1.0, np.zeros(3), scale=1.0, albedo=0.9, g=0.3, source="cube")
        cam = Camera([3.5, 3.5, 20.0], [3.5, 3.5, 3.5], [0, 1, 0], 40.0, 24, 16)
        scene = Scene(med, [PointLight(np.asarray(position, float), 10.0)], cam, np.zeros(3),
                      Method(resolution=16, gather=gather))
        return popvol.render(scene, jitter=False)

    on = image([3.0, 3.0, 3.0]).mean()
    assert np.isfinite(on)
    assert on == pytest.approx(image([3.01, 3.01, 3.01]).mean(), rel=0.02)
    assert on == pytest.approx(image([3.25, 3.25, 3.25]).mean(), rel=0.15)
    assert on == pytest.approx(image([3.0, 3.0, 3.0], gather=0).mean(), rel=0.05)
