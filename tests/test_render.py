"""Rendering: the Numba kernel against its NumPy twin, an empty medium, the optically thin
limit against single scattering computed independently by brute force, the combined
in-scattering source against lighting light by light, and empty-space skipping."""
import dataclasses

import numpy as np
import pytest
from brute import density_sampler, view_march
from slab import cube_single_scattering, dense_cube_scene

from popvol import hg, metrics
from popvol.camera import Camera
import twins as ref
from popvol.lights import DirectionalLight, PointLight
from popvol.medium import Medium
from popvol.pipeline import solve
from popvol.kernels.render import MAX_SEGMENT_DEPTH, block_at
from popvol.kernels.source import in_scattering_source
from popvol.renderer import (BLOCK, dense_blocks_box, densest_in_blocks, field_bundles, occupied_cells, render,
                             render_inputs, skip_blocks)
from popvol.scene import Method, Scene, apply_overrides


def blob_medium(n=24, peak_tau=0.03, albedo=1.0, g=0.6):
    """A Gaussian blob in the unit cube; peak_tau ~ optical depth through its centre."""
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rho = np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / (2 * 0.15**2)).astype(np.float32)
    scale = peak_tau / (0.15 * np.sqrt(2 * np.pi))     # integral of the Gaussian through the centre
    return Medium(rho, 1.0 / n, np.full(3, 0.5 / n), scale=scale, albedo=albedo, g=g, source="blob")


def blob_scene(direction, w=32, h=20, background=(0.1, 0.2, 0.3), **kw):
    cam = Camera([0.5, 0.62, 2.4], [0.5, 0.5, 0.5], [0, 1, 0], 32.0, w, h)
    return Scene(blob_medium(**kw), [DirectionalLight(direction, [1.0, 0.8, 0.6])], cam,
                 np.array(background, float), Method(resolution=24, step=0.25, tolerance=1e-6))


def single_scattering(scene, n_steps=400, n_light_steps=200):
    """Brute-force L = int T_v sigma_s E T_light f_hg(mu; g) dt + T_v L_bg at pixel centres,
    sigma_t by scipy's linear interpolation clamped to the edge inside the medium's cells; each
    colour channel with its own sigma_t and albedo (constant optics)."""
    med, light = scene.medium, scene.lights[0]
    lo, hi = med.bounds
    density = density_sampler(med)
    d, pts, dt = view_march(scene, n_steps)
    rho = density(pts)
    # transmittance toward the light: march from each point against the light direction
    ld = -light.direction
    tl_exit = np.full(pts.shape[:-1], np.inf)
    for a in range(3):
        if abs(ld[a]) > 1e-12:
            tl_exit = np.minimum(tl_exit, np.maximum((lo[a] - pts[..., a]) / ld[a], (hi[a] - pts[..., a]) / ld[a]))
    rho_l = np.zeros(pts.shape[:-1])                            # optical depth / scale
    for s in (np.arange(n_light_steps) + 0.5) / n_light_steps:
        rho_l += density(pts + (s * tl_exit)[..., None] * ld) * tl_exit / n_light_steps
    mu = -(d @ light.direction)
    phase = hg.f_hg(mu, med.g)
    L = np.empty(d.shape)
    for c in range(3):
        st = med.scale[c] * rho
        tau_v = np.cumsum(st * dt, axis=-1) - 0.5 * st * dt
        L[..., c] = (np.sum(np.exp(-tau_v) * med.albedo[c] * st * np.exp(-med.scale[c] * rho_l) * dt, axis=-1)
                     * phase * light.irradiance[c] + np.exp(-np.sum(st * dt, axis=-1)) * scene.background[c])
    return L


def _rel_error(direction, peak_tau):
    scene = blob_scene(direction, background=(0, 0, 0), peak_tau=peak_tau)
    scene.method.max_step = 1     # one sample per step: the midpoint rule's error stays below O(tau)
    img = render(scene, jitter=False).astype(np.float64)
    ss = single_scattering(scene)
    medium_px = ss[..., 0] > 0.05 * ss[..., 0].max()
    assert medium_px.sum() > 50
    return ((img - ss) / np.maximum(ss, 1e-30))[medium_px]


@pytest.mark.parametrize("direction", [[0.3, -0.6, 0.74], [0.3, -0.8, -0.52]], ids=["forward", "backward"])
def test_thin_medium_matches_single_scattering(direction):
    """In the optically thin limit POP's in-scattered radiance (black background) is single
    scattering. The difference is O(tau): POP attenuates toward the light by sigma_a only
    (here 0) and adds multiple scattering. Measured: median 1.4-2.2 % at peak optical depth
    0.03, 0.3-0.4 % at 0.006, 0.05-0.09 % at 0.0012. So: within 1.5 % of single scattering at
    tau = 0.006 in every pixel, and the error shrinks in proportion to tau."""
    coarse = _rel_error(direction, 0.03)
    fine = _rel_error(direction, 0.006)
    assert np.abs(fine).max() < 0.015, np.abs(fine).max()
    assert np.median(np.abs(fine)) < 0.006
    assert np.median(np.abs(fine)) < 0.3 * np.median(np.abs(coarse))     # linear in tau
    assert fine.min() > -1e-3          # POP is never darker than single scattering here


def test_chromatic_thin_medium_matches_single_scattering_per_channel():
    """RGB extinction and albedo: the medium is propagated once per channel and each channel of
    the image is that channel's single scattering (same tolerance as the grey case)."""
    scene = blob_scene([0.3, -0.6, 0.74], background=(0, 0, 0), peak_tau=0.006)
    med = scene.medium
    scene.medium = Medium(med.density, med.voxel_size, med.origin, scale=med.scale * [1.0, 0.6, 0.3],
                          albedo=[0.9, 0.7, 0.5], g=med.g, source="rgb blob")
    assert scene.medium.n_channels == 3
    img = render(scene, jitter=False).astype(np.float64)
    ss = single_scattering(scene)
    px = ss[..., 2] > 0.05 * ss[..., 2].max()
    err = (img - ss)[px] / ss[px]
    assert np.abs(err).max() < 0.015, np.abs(err).max()
    # the channels differ as sigma_s = albedo * scale does (thin: radiance ~ sigma_s)
    ratio = img[px].sum(0) / img[px].sum(0)[0]
    np.testing.assert_allclose(ratio, np.array([0.9, 0.7 * 0.6, 0.5 * 0.3]) / 0.9 * [1.0, 0.8, 0.6], rtol=0.02)


def test_per_voxel_albedo_and_g_equal_their_constants_when_uniform_and_act_locally():
    scene = blob_scene([0.3, -0.6, 0.74], peak_tau=0.5, albedo=0.8, g=0.5)
    med = scene.medium
    const = render(scene, jitter=False)
    scene.medium = Medium(med.density, med.voxel_size, med.origin, scale=med.scale,
                          albedo=np.full(med.shape, 0.8, np.float32), g=np.full(med.shape, 0.5, np.float32))
    np.testing.assert_allclose(render(scene, jitter=False), const, rtol=1e-5, atol=1e-7)
    # albedo 0 in the left half (x < 0.5): no light scattered there, the right half unchanged
    alb = np.full(med.shape, 0.8, np.float32)
    alb[: med.shape[0] // 2] = 0.0
    scene.medium = Medium(med.density, med.voxel_size, med.origin, scale=med.scale, albedo=alb, g=0.5)
    scene.background = np.zeros(3)
    img = render(scene, jitter=False)
    w = img.shape[1]
    assert img[:, : w // 3].max() < 0.05 * img[:, 2 * w // 3:].max()


@pytest.mark.parametrize("max_step, rtol", [(1, 2e-3), (8, 5e-3)])
def test_background_is_attenuated_by_the_view_transmittance(max_step, rtol):
    """A non-scattering medium (albedo 0): the image is exp(-int sigma_t) * background. With one
    sample per step of a quarter voxel to 0.2 %; where one sample spans up to 8 steps in thin
    blocks (method.max_step, at most kernels.render.COARSE_DEPTH mean free paths together) to
    0.5 % (measured 0.35 % at the pixel centres)."""
    scene = blob_scene([0, -1, 0], peak_tau=1.5, albedo=0.0)
    scene.method.max_step = max_step
    img = render(scene, jitter=False).astype(np.float64)
    np.testing.assert_allclose(img, single_scattering(scene), rtol=rtol, atol=1e-6)


@pytest.mark.parametrize("position", [[0.5, 0.55, 0.5], [0.5, 0.5, 0.9]], ids=["centre", "edge"])
def test_long_samples_in_thin_blocks_keep_the_image_near_a_point_light(position):
    """A point light inside a thin blob (peak optical depth 0.5): where one sample spans several
    steps (method.max_step 8), never longer than kernels.render.NEAR_POINT_LIGHT of the distance
    to the light, the image is within 2 % of one sample per step in every pixel (measured 0.3 %
    with the light at the centre, 0.9 % near the edge), though most pixels changed."""
    scene = blob_scene([0, -1, 0], peak_tau=0.5, albedo=1.0, background=(0, 0, 0))
    scene.lights = [PointLight(position, [1.0, 1.0, 1.0])]
    scene.method.gather = 0
    sol = solve(scene)
    one = render(apply_overrides(scene, max_step=1), sol, jitter=False).astype(np.float64)
    long = render(apply_overrides(scene, max_step=8), sol, jitter=False).astype(np.float64)
    lit = one > 1e-3 * one.max()
    assert (long != one).mean() > 0.5
    np.testing.assert_allclose(long[lit], one[lit], rtol=0.02)


def test_empty_medium_shows_the_background():
    scene = blob_scene([0, -1, 0])
    scene.medium.density[:] = 0
    img = render(scene)
    np.testing.assert_allclose(img, np.broadcast_to(scene.background, img.shape), rtol=1e-6)


@pytest.mark.parametrize("isotropic, optics, combined", [("walk", "grey", True), ("diffusion", "grey", True),
                                                         ("diffusion", "rgb, per-voxel g", True),
                                                         ("diffusion", "rgb, per-voxel g", False),
                                                         ("diffusion", "dense", True),
                                                         ("diffusion", "point light", True)])
def test_render_kernel_equals_numpy_twin(isotropic, optics, combined):
    """"dense": up to 18 mean free paths per voxel, so the march splits its segments
    (kernels/render.py, MAX_SEGMENT_DEPTH) in the kernel and the twin alike. Elsewhere the blob
    is thin enough that one sample spans several steps in some blocks (method.max_step), and
    with the point light inside it fewer near the light (kernels/render.py, NEAR_POINT_LIGHT)."""
    scene = blob_scene([0.3, -0.6, 0.74], w=12, h=8, peak_tau=160.0 if optics == "dense" else 2.0,
                       albedo=0.8, g=0.5)
    if optics == "point light":
        scene.lights = [PointLight([0.5, 0.55, 0.5], [1.0, 0.8, 0.6])]
    if optics == "dense":
        med = scene.medium
        scene.method.step = 1.0
        assert float(med.density.max() * med.scale.max() * med.voxel_size.min()) > 8 * MAX_SEGMENT_DEPTH
    elif optics != "grey":
        med = scene.medium
        g = np.linspace(0.2, 0.7, med.shape[0], dtype=np.float32)[:, None, None] * np.ones(med.shape, np.float32)
        scene.medium = Medium(med.density, med.voxel_size, med.origin, scale=med.scale * [1.0, 0.5, 0.25],
                              albedo=[0.9, 0.8, 0.6], g=g)
    scene.method.isotropic = isotropic
    scene.method.handover_scale = 20.0
    scene.method.gather = 0                 # the fields' lobes light every sample, as in the twin
    sol = solve(scene)
    if isotropic == "diffusion":
        assert sol.phid.max() > 0 and np.abs(sol.flux).max() > 0
    assert_kernel_equals_twin(scene, sol, combined, rtol=5e-4)


def assert_kernel_equals_twin(scene, sol, combined, rtol):
    """Every pixel of the float32 kernel's image (pixel centres, no jitter) against the float64
    twin's (twins.render_pixel)."""
    img = render(scene, sol, jitter=False, combined=combined)
    source = ref.in_scattering_source(scene, sol) if combined else None
    for py in range(scene.camera.height):
        for px in range(scene.camera.width):
            np.testing.assert_allclose(img[py, px], ref.render_pixel(scene, sol, px, py, combined, source),
                                       rtol=rtol, atol=1e-6)


def test_jitter_is_deterministic_and_unbiased():
    scene = blob_scene([0.3, -0.6, 0.74], peak_tau=1.0)
    a, b = render(scene, jitter=True), render(scene, jitter=True)
    np.testing.assert_array_equal(a, b)
    c = render(scene, jitter=False)
    assert not np.array_equal(a, c)
    assert a.mean() == pytest.approx(c.mean(), rel=0.01)


def test_one_sample_is_the_pixel_centre_and_closer_to_the_pixel_mean():
    """At spp = 1 the default is one sample at the pixel centre and the segments' midpoints; at
    spp > 1, hashed jittered samples. Against the mean over the pixel's area (256 jittered
    samples), the centre sample is closer than one jittered sample: a midpoint rule has no
    variance and on a smooth image a bias of second order in the pixel's size (measured: relMSE
    7.7e-7 against 1.1e-4)."""
    scene = blob_scene([0.3, -0.6, 0.74], w=48, h=32, peak_tau=2.0)
    sol = solve(scene)
    with_spp = lambda n: dataclasses.replace(scene, method=dataclasses.replace(scene.method, spp=n))
    centre = render(scene, sol)
    np.testing.assert_array_equal(centre, render(scene, sol, jitter=False))
    one = render(scene, sol, jitter=True)
    many = render(with_spp(256), sol)
    np.testing.assert_array_equal(render(with_spp(4), sol), render(with_spp(4), sol, jitter=True))
    mask = many.sum(axis=2) > 1e-3 * many.sum(axis=2).max()
    err = {name: metrics.relmse(img, many, mask) for name, img in (("centre", centre), ("one", one))}
    assert err["centre"] < 0.5 * err["one"], err


def test_fields_are_only_needed_next_to_the_medium(monkeypatch):
    """solve() resamples the fields only at voxels within one voxel of non-zero density
    (pipeline.voxels_seen); rendering with fields everywhere gives the same image exactly."""
    from popvol import pipeline as P
    med = blob_medium(peak_tau=1.0)
    rho = med.density.copy()
    rho[:, :, :8] = 0.0                                    # an empty third, with a sharp edge
    scene = blob_scene([0.3, -0.6, 0.74], peak_tau=1.0)
    scene.medium = Medium(rho, med.voxel_size, med.origin, scale=med.scale, albedo=0.9, g=0.6)
    seen = P.voxels_seen(rho)
    assert not seen.all() and seen[:, :, 7:].all() and not seen[:, :, :6].any()
    img = render(scene, jitter=False)
    monkeypatch.setattr(P, "voxels_seen", lambda d: np.ones(d.shape, bool))
    np.testing.assert_array_equal(render(scene, jitter=False), img)


def test_solve_reuses_only_the_lights_whose_domains_are_unchanged():
    """solve(scene, reuse=old) copies the fields of lights whose direction, medium and method
    are unchanged (per unit irradiance, so irradiance may change) and re-propagates the others;
    the result equals a solve from scratch."""
    import dataclasses
    scene = blob_scene([0.3, -0.6, 0.74], peak_tau=1.0)
    scene.lights.append(DirectionalLight([-0.5, -0.5, 0.2], [0.2, 0.3, 0.4]))
    first = solve(scene)
    # brighter first light, a new direction for the second, a different camera and step
    scene.lights[0] = DirectionalLight(scene.lights[0].direction, [3.0, 2.0, 1.0])
    scene.lights[1] = DirectionalLight([0.1, -0.9, -0.3], [0.2, 0.3, 0.4])
    scene.method = dataclasses.replace(scene.method, step=0.5, spp=2)
    again = solve(scene, reuse=first)
    assert [d.reused for d in again.domains] == [True, False]
    fresh = solve(scene)
    for name in ("phi", "phia", "phid", "flux"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name))
    np.testing.assert_array_equal(render(scene, again, jitter=False), render(scene, fresh, jitter=False))
    # a different medium (albedo) or propagation method invalidates everything
    scene.medium = dataclasses.replace(scene.medium, albedo=0.8)
    assert not any(d.reused for d in solve(scene, reuse=fresh).domains)
    other = dataclasses.replace(scene, method=dataclasses.replace(scene.method, resolution=16))
    assert not any(d.reused for d in solve(other, reuse=fresh).domains)


def cut_blob(n=24, cut=0.05, **kw):
    """blob_medium with the density below ``cut`` of its peak set to 0: empty space around it."""
    med = blob_medium(n=n, **kw)
    rho = np.where(med.density > cut, med.density, 0.0).astype(np.float32)
    return Medium(rho, med.voxel_size, med.origin, scale=med.scale, albedo=med.albedo, g=med.g, source="cut blob")


def three_suns(scene):
    scene.lights += [DirectionalLight([-0.7, -0.2, -0.3], [0.5, 0.6, 0.9]),
                     DirectionalLight([0.1, -0.4, -0.9], [0.3, 0.3, 0.2])]
    return scene


@pytest.mark.parametrize("solver", ["ordinates", "sweep"])
def test_combined_source_kernel_equals_numpy_twin(solver):
    """kernels/source.py against tests/twins.py on a small RGB medium with per-voxel g and empty
    space, lit by two suns, a point light and a broad sun without an unscattered part (a0 < 1,
    as an environment's lights), with the diffusion stage: the suns' walk and diffuse lobes and
    the point light's diffuse lobe, at the voxels the renderer reads, 0 elsewhere. With six
    ordinates (the default) the suns' scattered light is their diffuse lobe (capped at 1) and a
    broad sun's walk fields are 0; with the one-lobe sweeps the broad sun's light is in its walk
    fields."""
    scene = blob_scene([0.3, -0.6, 0.74], w=8, h=6, n=16, peak_tau=3.0, albedo=0.9, g=0.5)
    med = cut_blob(n=16, peak_tau=3.0)
    g = np.linspace(0.2, 0.7, 16, dtype=np.float32)[:, None, None] * np.ones(med.shape, np.float32)
    scene.medium = Medium(med.density, med.voxel_size, med.origin, scale=med.scale * [1.0, 0.7, 0.4],
                          albedo=[0.9, 0.8, 0.6], g=g)
    scene.lights += [DirectionalLight([-0.5, -0.5, 0.2], [0.2, 0.3, 0.4]), PointLight([0.3, 0.62, 0.45], [1.0, 0.8, 0.6]),
                     DirectionalLight([0.1, -0.9, -0.3], [0.3, 0.2, 0.1], a0=0.4)]
    scene.method.isotropic = "diffusion"
    scene.method.handover_scale = 20.0
    scene.method.gather = 0                 # the fields' lobes light every voxel, as in the twin
    scene.method.solver = solver
    sol = solve(scene)
    assert list(sol.is_point) == [False, False, True, False] and sol.phid.max() > 0
    assert list(sol.unscattered) == [True, True, True, False]
    assert (sol.phi[3].max() > 0) == (solver == "sweep") and sol.phid[3].max() > 0
    assert list(sol.lobe_cap) == ([1.0, 1.0, 0.5, 1.0] if solver == "ordinates" else [0.5] * 4)
    source = render_inputs(scene, sol)[4][0]
    twin = ref.in_scattering_source(scene, sol)
    assert source.shape == scene.medium.shape + (3,) and source.dtype == np.float32
    assert (twin == 0).all(axis=-1).sum() > 0 and twin.max() > 0       # some voxels are not read
    np.testing.assert_allclose(source, twin, rtol=2e-5, atol=1e-6 * twin.max())


def test_a_lights_one_lobe_is_its_two_lobes_without_unscattered_light():
    """kernels.render.rest_lobe (a light without an unscattered part, lit from one lobe) gives
    walk_lobes' value with phi_dir = 0, on random fields, directions and g (a zero's sign aside)."""
    from popvol.kernels.render import rest_lobe, walk_lobes
    rng = np.random.default_rng(5)
    for _ in range(2000):
        p = float(rng.choice([0.0, -0.0, rng.random() * 10.0**rng.integers(-30, 3)]))
        pa = float(p * rng.uniform(-1.2, 1.2))
        mu, g = float(rng.uniform(-1, 1)), float(rng.uniform(-0.95, 0.95))
        assert rest_lobe(p, pa, mu, g) == walk_lobes(p, pa, 0.0, mu, g)


def test_combined_source_changes_the_image_little_with_three_suns():
    """The combined source interpolates the sum of the lobes instead of the fields, and takes
    the phase at voxel centres: on a cloud under three suns with the diffusion stage the image
    differs from lighting light by light by relMSE < 1e-4 and brightness < 0.2 % (measured
    here: relMSE 2.4e-7, brightness x0.99998; on the example scenes at 320x180, relMSE 2e-6 to
    8e-5, docs/METHOD.md, "Rendering")."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=48, h=32, peak_tau=4.0, albedo=0.95, g=0.8))
    scene.medium = cut_blob(peak_tau=4.0, albedo=0.95, g=0.8)
    scene.method.gather = 0                 # with the gather every sample reads the combined source
    sol = solve(scene)
    combined, per_light = render(scene, sol, combined=True), render(scene, sol, combined=False)
    m = metrics.compare(combined, per_light)
    print(f"relMSE {m['relmse']:.2g}, brightness x{m['brightness_ratio']:.5f}")
    assert m["relmse"] < 1e-4 and abs(m["brightness_ratio"] - 1) < 2e-3
    assert not np.array_equal(combined, per_light)


def test_combined_source_with_a_point_light_and_a_sun():
    """A point light's walk lobes are looked up per sample (its 1/r^2 spike), its diffuse lobe
    and the sun's terms come from the combined source: the image matches lighting light by
    light as closely as with suns alone (measured relMSE 7e-6, brightness x1.0002)."""
    scene = blob_scene([0.3, -0.6, 0.74], w=48, h=32, peak_tau=4.0, albedo=0.95, g=0.8)
    scene.medium = cut_blob(peak_tau=4.0, albedo=0.95, g=0.8)
    scene.lights.append(PointLight([0.3, 0.62, 0.45], [1.0, 0.8, 0.6]))
    sol = solve(scene)
    combined, per_light = render(scene, sol, combined=True), render(scene, sol, combined=False)
    m = metrics.compare(combined, per_light)
    print(f"relMSE {m['relmse']:.2g}, brightness x{m['brightness_ratio']:.5f}")
    assert m["relmse"] < 1e-4 and abs(m["brightness_ratio"] - 1) < 2e-3
    # the point light alone: its walk lobes dominate, and are read as before
    alone = dataclasses.replace(sol, irradiance=sol.irradiance * [[0.0], [1.0]])
    m = metrics.compare(render(scene, alone, combined=True), render(scene, alone, combined=False))
    assert m["relmse"] < 1e-4 and abs(m["brightness_ratio"] - 1) < 2e-3


def test_combined_source_is_not_used_next_to_the_camera():
    """Within renderer.NEAR_VOXELS of the camera the view direction turns fast across a voxel:
    there samples are lit light by light, so a camera inside the cloud sees what it saw before
    (lit from the source everywhere, this view measured relMSE 2.5e-3, brightness x0.976; the
    demo cloud seen from inside it, x1.8)."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=48, h=32, peak_tau=20.0, albedo=0.95, g=0.8))
    scene.camera = Camera([0.5, 0.5, 0.55], [0.6, 0.55, 0.0], [0, 1, 0], 60.0, 48, 32)
    sol = solve(scene)
    m = metrics.compare(render(scene, sol, combined=True), render(scene, sol, combined=False))
    assert m["relmse"] < 1e-4 and abs(m["brightness_ratio"] - 1) < 2e-3


def test_empty_space_skipping_changes_no_pixel():
    """A medium with empty blocks: skipping them gives the image bitwise (with jitter: the
    samples sit at t0 + (i + jt) step whether or not others were skipped), light by light and
    with the combined source."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=40, h=24, n=32, peak_tau=4.0))
    scene.medium = cut_blob(n=32, cut=0.1, peak_tau=4.0)
    blocks = densest_in_blocks(scene.medium.density, BLOCK) > 0
    assert blocks.shape == (4, 4, 4) and 0 < blocks.sum() < blocks.size
    sol = solve(scene)
    for combined in (True, False):
        skipped = render(scene, sol, jitter=True, combined=combined)
        np.testing.assert_array_equal(skipped, render(scene, sol, jitter=True, combined=combined, skip=False))
        assert skipped.max() > 0


def two_blobs(n=64, peak_tau=4.0):
    """Two small Gaussian blobs at opposite corners of the unit cube, 0 below 5 % of the peak:
    rays between them cross many empty blocks."""
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rho = sum(np.exp(-((X - c) ** 2 + (Y - c) ** 2 + (Z - c) ** 2) / (2 * 0.06**2)) for c in (0.2, 0.75))
    rho = np.where(rho > 0.05, rho, 0.0).astype(np.float32)
    scale = peak_tau / (0.06 * np.sqrt(2 * np.pi))
    return Medium(rho, 1.0 / n, np.full(3, 0.5 / n), scale=scale, albedo=0.9, g=0.5, source="two blobs")


@pytest.mark.parametrize("peak_tau", [4.0, 400.0])
def test_skipping_many_empty_blocks_at_once_changes_no_pixel(peak_tau):
    """Two blobs far apart in a 64^3 grid: an empty block vouches for the empty blocks up to
    n - 1 around it (renderer.skip_blocks), and a ray jumps over all of them; the image is
    bitwise that of marching every sample, light by light and with the combined source, and
    also where the blobs are so dense that the march splits its segments (peak_tau 400)."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=40, h=24))
    scene.camera = Camera([1.6, 1.3, 2.2], [0.45, 0.45, 0.45], [0, 1, 0], 40.0, 40, 24)
    scene.medium = two_blobs(peak_tau=peak_tau)
    sol = solve(scene)
    blocks = render_inputs(scene, sol)[0][9]
    assert blocks.min() <= -3                          # some blocks vouch for a cube 5 blocks wide
    for combined in (True, False):
        skipped = render(scene, sol, jitter=True, combined=combined)
        np.testing.assert_array_equal(skipped, render(scene, sol, jitter=True, combined=combined, skip=False))
        assert skipped.max() > 0


def small_cloud_in_a_large_grid(n=64):
    """A blob of radius about 0.1 at (0.55, 0.45, 0.5) in the unit cube's 64^3 grid, 0 elsewhere:
    most blocks are empty, and the box of the non-empty ones is well inside the grid."""
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rho = np.exp(-((X - 0.55) ** 2 + (Y - 0.45) ** 2 + (Z - 0.5) ** 2) / (2 * 0.05**2))
    rho = np.where(rho > 0.1, rho, 0.0).astype(np.float32)
    return Medium(rho, 1.0 / n, np.full(3, 0.5 / n), scale=60.0, albedo=0.9, g=0.5, source="small cloud")


def test_marching_only_the_box_of_non_empty_blocks_changes_no_pixel():
    """A small cloud in a large grid, seen whole, with the image's corners beside it: the march
    starts and stops at the box of the non-empty blocks (renderer.dense_blocks_box) and
    skips the cells of empty voxels (renderer.occupied_cells); the image is bitwise that of
    marching every sample, with and without jitter, light by light and with the combined
    source."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=40, h=24))
    scene.camera = Camera([0.5, 0.6, 1.6], [0.5, 0.5, 0.5], [0, 1, 0], 50.0, 40, 24)
    scene.medium = small_cloud_in_a_large_grid()
    sol = solve(scene)
    lo, hi = dense_blocks_box(scene.medium, render_inputs(scene, sol)[0][9])
    assert np.all(np.array(lo) > 0.1) and np.all(np.array(hi) < 0.9)      # well inside the unit cube
    for jitter in (True, False):
        for combined in (True, False):
            skipped = render(scene, sol, jitter=jitter, combined=combined)
            np.testing.assert_array_equal(skipped, render(scene, sol, jitter=jitter, combined=combined, skip=False))
            assert skipped.max() > 0
            # a corner's ray crosses the grid but misses the box: nothing but the background
            np.testing.assert_array_equal(skipped[0, 0], np.float32(scene.background))


def test_points_outside_the_box_of_non_empty_blocks_lie_in_empty_blocks(rng):
    """renderer.dense_blocks_box against the coarse grid itself: 20,000 random points of the
    medium's box outside it are each in a block that block_at calls empty, and every
    non-empty block's centre is inside it; a grid without density gives an empty box."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=8, h=6))
    scene.medium = small_cloud_in_a_large_grid()
    medium = render_inputs(scene, solve(scene))[0]
    blocks, size = medium[9], BLOCK * scene.medium.voxel_size
    lo, hi = dense_blocks_box(scene.medium, blocks)
    outside = 0
    for x in rng.uniform(0.0, 1.0, (20000, 3)):
        if np.any(x < lo) or np.any(x > hi):
            outside += 1
            assert block_at(medium, x, np.array([1.0, 0.0, 0.0]))[0] < 0.0
    assert outside > 15000
    for b in np.argwhere(blocks > 0):
        centre = scene.medium.origin - 0.5 * scene.medium.voxel_size + (b + 0.5) * size
        assert np.all(centre > lo) and np.all(centre < hi)
    lo, hi = dense_blocks_box(scene.medium, skip_blocks(densest_in_blocks(np.zeros_like(medium[0]), BLOCK)))
    assert np.all(np.array(lo) > np.array(hi))


def test_occupied_cells_hold_the_cells_with_a_non_empty_voxel(rng):
    """renderer.occupied_cells against the definition, cell by cell: (i, j, k) is occupied where
    one of the voxels [i, i + 1] x [j, j + 1] x [k, k + 1] within the grid has density > 0."""
    density = np.where(rng.random((9, 7, 5)) < 0.08, rng.random((9, 7, 5)), 0.0).astype(np.float32)
    cells = occupied_cells(density)
    assert cells.dtype == np.uint8 and cells.shape == density.shape and 0 < cells.sum() < cells.size
    for i, j, k in np.ndindex(density.shape):
        assert cells[i, j, k] == (density[i:i + 2, j:j + 2, k:k + 2] > 0).any()


def test_combined_source_is_the_same_in_any_number_of_lanes():
    """kernels.source.in_scattering_source deals the slices of the grid to lanes: 1, 2 and 5
    lanes give the same bits (kernels/__init__.py, "Lanes")."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=8, h=6, n=16, peak_tau=3.0))
    scene.method.isotropic = "diffusion"
    scene.method.gather = 0
    sol = solve(scene)
    medium, lights = render_inputs(scene, sol)[:2]
    grid, spherical = field_bundles(sol)
    seen = scene.medium.density > 0
    sources = []
    for lanes in (1, 2, 5):
        out = np.zeros(scene.medium.shape + (3,), np.float32)
        in_scattering_source(medium, lights, grid, spherical, np.asarray(scene.camera.origin, np.float64), seen,
                             out, lanes)
        sources.append(out)
    assert sources[0].max() > 0
    for other in sources[1:]:
        np.testing.assert_array_equal(sources[0], other)


def test_values_of_the_density_are_made_once_per_density_array():
    """Medium.derived: the renderer's coarse grid and seen voxels are made once per density
    array (a second frame gets the same arrays, equal to making them anew), anew for a medium
    whose density is another array, and a medium made by dataclasses.replace does not share
    the first one's values."""
    scene = three_suns(blob_scene([0.3, -0.6, 0.74], w=16, h=10))
    scene.medium = two_blobs(n=32)
    sol = solve(scene)
    first, second = render_inputs(scene, sol)[0][9], render_inputs(scene, sol)[0][9]
    assert first is second
    np.testing.assert_array_equal(first, skip_blocks(densest_in_blocks(scene.medium.density, BLOCK)))
    assert scene.medium.derived("seen", lambda d: None) is not None
    thicker = dataclasses.replace(scene.medium, scale=scene.medium.scale * 2)
    assert thicker.derived("seen", lambda d: "made anew") == "made anew"
    other = dataclasses.replace(scene.medium, density=scene.medium.density[::-1].copy())
    mirrored_scene = dataclasses.replace(scene, medium=other)
    mirrored = render_inputs(mirrored_scene, solve(mirrored_scene))[0][9]
    np.testing.assert_array_equal(mirrored, skip_blocks(densest_in_blocks(other.density, BLOCK)))
    assert not np.array_equal(mirrored, first)


def test_skip_blocks_holds_the_distance_to_the_nearest_occupied_block(rng):
    """renderer.skip_blocks against its brute-force twin (the Chebyshev distance over all pairs
    of blocks, capped at ``reach``) on random sparse grids of blocks, one with no occupied block."""
    for shape, fill, reach in (((7, 5, 9), 0.05, 16), ((12, 12, 12), 0.01, 4), ((3, 4, 5), 0.0, 16)):
        densest = np.where(rng.random(shape) < fill, rng.random(shape) + 0.1, 0.0).astype(np.float32)
        np.testing.assert_array_equal(skip_blocks(densest, reach), ref.skip_blocks(densest, reach))


def test_densest_in_blocks_kernel_equals_numpy_twin(rng):
    """kernels.sampling.densest_near_blocks (through renderer.densest_in_blocks) against the
    twin's slices, for blocks of 2, 3 and 8 voxels on grids whose sides are not multiples."""
    rho = np.where(rng.random((21, 10, 17)) < 0.02, rng.random((21, 10, 17)), 0.0).astype(np.float32)
    for block in (2, 3, 8):
        np.testing.assert_array_equal(densest_in_blocks(rho, block), ref.densest_in_blocks(rho, block))


def test_blocks_hold_the_largest_density_near_them(rng):
    """A block's value bounds the density's trilinear value (the twin's, clamped as the kernel's
    stencil) at every point whose clamped cell index lies in it, so it is 0 (empty) only where
    that is 0 throughout; checked at random points of a sparse random medium, and on a voxel at
    the grid's far corner."""
    rho = np.zeros((20, 17, 9), np.float32)
    rho[tuple(rng.integers(0, rho.shape, (3, 3)).T)] = rng.random(3) + 0.1
    densest = densest_in_blocks(rho, 8)
    blocks = densest > 0
    assert blocks.shape == (3, 3, 2) and 0 < blocks.sum() < blocks.size
    q = rng.uniform(-0.5, np.array(rho.shape) - 0.5, (200000, 3))
    b = np.clip(q, 0, np.array(rho.shape) - 1).astype(int) // 8
    value = ref.trilinear(rho, q)
    assert blocks[tuple(b[value > 0].T)].all()
    assert np.all(value <= densest[tuple(b.T)] * (1 + 1e-6))
    rho[:] = 0.0
    rho[19, 16, 8] = 1.0                   # read by the stencils of points in y-block 1 too
    assert set(zip(*np.nonzero(densest_in_blocks(rho, 8) > 0))) == {(2, 1, 0), (2, 1, 1), (2, 2, 0), (2, 2, 1)}


@pytest.mark.parametrize("tau_voxel, mean_tol", [(1.0, 0.06), (10.0, 0.01), (1e4, 0.01)])
def test_single_scattering_of_a_dense_cube_on_the_grid_edge_is_beer_lambert(tau_voxel, mean_tol):
    """A cube whose faces are the grid's edges: the fields there are clamped to the outermost
    voxels' values, which hold little of the unscattered light where voxels are thick, so the
    march takes a sun's unscattered light in the outer half cell by Beer-Lambert from the face
    and averages it over each segment in closed form (docs/METHOD.md Eq. 25d). Against the
    independent single scattering of a uniform cube (cube_single_scattering), over the pixels
    that see it: x1.043 / x1.0005 / x1.000 at 1 / 10 / 10^4 mean free paths per voxel (before:
    x0.79 / x0.25 / x0.25); from 10 on, where the outer half cell holds the lit skin, 95 % of
    the pixels within 1 %. At 1 mean free path per voxel the rest is the interior's trilinear
    phi_dir, which overstates a convex exp(-tau) between centres (90th percentile x1.11)."""
    scene = dense_cube_scene(tau_voxel)
    exact = cube_single_scattering(scene)
    img = render(scene, solve(scene).single_scattering(), jitter=False).astype(np.float64)
    seen = exact[..., 0] > 0.02 * exact[..., 0].max()
    assert seen.sum() > 150
    assert img[seen].sum() / exact[seen].sum() == pytest.approx(1.0, abs=mean_tol)
    if tau_voxel >= 10:
        ratio = img[seen, 0] / exact[seen, 0]
        assert np.mean(np.abs(ratio - 1) < 0.01) >= 0.95


@pytest.mark.parametrize("tau_voxel, towards, combined", [(10.0, False, True), (10.0, False, False),
                                                          (0.5, True, True)])
def test_edge_single_scattering_kernel_equals_numpy_twin(tau_voxel, towards, combined):
    """The dense cube, the whole image (walk and diffusion lobes too): the kernel's closed-form
    mean over each segment against the twin's midpoint rule of 4000 points
    (twins.edge_single_scattering); lit through the faces the camera sees, or (``towards``)
    through the others, so that its light leaves by the faces in view."""
    light = DirectionalLight([0.3, 0.8, 0.5], [1.0, 0.8, 0.6]) if towards else None
    scene = dense_cube_scene(tau_voxel, light)
    assert_kernel_equals_twin(scene, solve(scene), combined, rtol=1e-3)


def test_thick_faces_decide_the_edge_correction():
    """renderer.thick_faces: some voxel on the grid's faces at least EDGE_DEPTH mean free paths
    thick along the face's normal; a cube of 0.2 mean free paths per voxel is not (its clamped
    fields are used as they are), one of 0.25 is, and so is a grid whose one thick face voxel
    lies on one face only; a thick voxel inside the grid does not count."""
    from popvol.kernels.render import EDGE_DEPTH
    from popvol.renderer import thick_faces
    assert EDGE_DEPTH == 0.25                        # a change detector: docs/METHOD.md quotes it
    assert not thick_faces(dense_cube_scene(0.2).medium)
    assert thick_faces(dense_cube_scene(0.25).medium)
    med = dense_cube_scene(0.1).medium
    rho = np.zeros_like(med.density)
    rho[3, 4, -1] = 5.0                              # 0.5 mean free paths, on the +z face
    assert thick_faces(dataclasses.replace(med, density=rho))
    inside = np.zeros_like(med.density)
    inside[3, 4, 4] = 50.0
    assert not thick_faces(dataclasses.replace(med, density=inside))


def test_a_light_without_unscattered_light_gets_no_edge_single_scattering():
    """A broad lobe (a0 < 1, as an environment's regions are) has no unscattered part, so the
    dense cube's single scattering under it is nothing, on its faces too: the image is the
    background seen through the cube, what the same cube renders with albedo 0."""
    scene = dense_cube_scene(10.0, DirectionalLight([-0.3, -0.8, -0.5], [1.0, 0.8, 0.6], a0=0.5))
    scene.background = np.array([0.01, 0.02, 0.03])
    sol = solve(scene)
    assert not sol.unscattered[0]
    assert render(scene, sol, jitter=False).max() > 0.05         # lit, by its scattered light
    black = dataclasses.replace(scene, medium=dataclasses.replace(scene.medium, albedo=0.0))
    np.testing.assert_array_equal(render(scene, sol.single_scattering(), jitter=False),
                                  render(black, solve(black).single_scattering(), jitter=False))
