"""The real WDAS cloud (examples/wdas_sun.toml, shared data) solved and rendered small and coarse.

Oracles: the TOML itself (read here with tomllib), reference_stats.json, ray/box geometry done
here, the unit-irradiance cross-section of the light's domain, and the identity
absorbed power = int sigma_a phi dV computed on the medium's own grid. Runs in ~1-2 s.
"""
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

import popvol
from conftest import shared_file
from popvol.scene import apply_overrides

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "wdas_sun.toml"
W, H = 96, 54
RESOLUTION = 48          # cells along the longest side of the light's domain (example: 128)
ZOOM_FOV = 22.0          # the example's fov is 40; the cloud then covers ~10 % of the frame


@pytest.fixture(scope="module")
def wdas():
    shared_file("npz/wdas_cloud_sixteenth_dense.npz")       # skips when the data is absent
    toml = tomllib.loads(EXAMPLE.read_text())
    scene = popvol.load_scene(EXAMPLE, width=W, height=H, resolution=RESOLUTION)
    solution = popvol.solve(scene)
    image = popvol.render(scene, solution)
    # the solution does not depend on the camera: zoom in and render again without re-solving
    apply_overrides(scene, fov=ZOOM_FOV)
    zoomed = popvol.render(scene, solution)
    return {"toml": toml, "scene": scene, "solution": solution, "image": image, "zoomed": zoomed}


def test_example_scene_is_the_wdas_cloud(wdas):
    toml, scene = wdas["toml"], wdas["scene"]
    ref = json.loads(shared_file("reference_stats.json").read_text())["files"]["vdb/wdas_cloud_sixteenth.vdb"]
    med = scene.medium
    assert list(med.density.shape) == ref["dense_shape_xyz"]
    assert float(med.density.sum(dtype=np.float64)) == pytest.approx(ref["sum"], rel=1e-5)
    np.testing.assert_array_equal(med.scale, toml["medium"]["scale"])     # grey: one value, RGB
    np.testing.assert_array_equal(med.albedo, toml["medium"]["albedo"])
    assert med.g == toml["medium"]["g"] and med.n_channels == 1
    # the medium is the union of the voxel cells
    lo, hi = med.bounds
    vs, c0 = np.asarray(ref["voxel_size"]), np.asarray(ref["world_of_ijk_min"])
    n = np.asarray(ref["dense_shape_xyz"])
    np.testing.assert_allclose(lo, c0 - vs / 2, rtol=1e-9)
    np.testing.assert_allclose(hi, c0 + (n - 0.5) * vs, rtol=1e-9)
    # overrides went to the camera and the method; the rest comes from the TOML
    assert (scene.camera.width, scene.camera.height) == (W, H)
    assert scene.method.resolution == RESOLUTION
    np.testing.assert_allclose(scene.background, toml["background"]["radiance"])
    np.testing.assert_allclose(scene.camera.origin, toml["camera"]["origin"])
    assert len(scene.lights) == len(toml["lights"]) == 1
    d = np.asarray(toml["lights"][0]["direction"], float)
    np.testing.assert_allclose(scene.lights[0].direction, d / np.linalg.norm(d), rtol=1e-12)


@pytest.mark.parametrize("which", ["image", "zoomed"])
def test_image_is_finite_and_non_negative(wdas, which):
    img = wdas[which]
    assert img.shape == (H, W, 3) and img.dtype == np.float32
    assert np.all(np.isfinite(img))
    assert img.min() >= 0.0


def test_cloud_is_visible(wdas):
    bg = wdas["scene"].background
    for which, min_share in (("image", 0.05), ("zoomed", 0.25)):
        img = wdas[which].astype(np.float64)
        diff = np.abs(img - bg).max(axis=2)
        cloud = diff > 0.02
        assert cloud.mean() > min_share, (which, cloud.mean())
        # scattered sunlight (irradiance 2.6, 2.5, 2.3) is far less blue than the sky
        # (0.03, 0.07, 0.23): inside the cloud red rises above the sky's red
        assert np.median(img[cloud][:, 0]) > bg[0] + 0.01
        assert img[cloud][:, 0].max() > 2 * bg[0]
    # the zoomed view shows the same cloud, larger: more cloud pixels
    z = (np.abs(wdas["zoomed"] - bg).max(axis=2) > 0.02).mean()
    i = (np.abs(wdas["image"] - bg).max(axis=2) > 0.02).mean()
    assert z > 2 * i


def _rays_miss_box(origin, dirs, lo, hi):
    """Slab test, done here: True where the ray origin + t dirs (t > 0) misses [lo, hi]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - origin) / dirs
        t1 = (hi - origin) / dirs
    tmin = np.nanmax(np.minimum(t0, t1), axis=-1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=-1)
    return (tmax < tmin) | (tmax < 0)


def test_pixels_that_miss_the_medium_show_the_background(wdas):
    """Rays built here from the TOML camera (vertical fov, right = forward x up); a pixel whose
    centre ray misses the box grown by two pixel footprints cannot touch the medium, jitter or not.
    (Example framing only: zoomed in, the medium's box fills the whole frame.)"""
    which, fov = "image", None
    toml, scene = wdas["toml"], wdas["scene"]
    cam = toml["camera"]
    o, target = np.asarray(cam["origin"], float), np.asarray(cam["target"], float)
    fov = np.radians(fov if fov is not None else cam["fov"])
    fwd = (target - o) / np.linalg.norm(target - o)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = np.tan(fov / 2)
    px, py = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    sx, sy = (2 * px / W - 1) * t * W / H, (1 - 2 * py / H) * t
    dirs = fwd + sx[..., None] * right + sy[..., None] * up
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    lo, hi = scene.medium.bounds
    far = np.linalg.norm(np.maximum(np.abs(lo - o), np.abs(hi - o)))
    margin = 2 * far * (2 * t / H) * np.sqrt(2)             # two pixel diagonals at the far side
    miss = _rays_miss_box(o, dirs, lo - margin, hi + margin)
    assert 0.2 < miss.mean() < 0.98                          # both kinds of pixels are present
    img = wdas[which]
    np.testing.assert_allclose(img[miss], np.broadcast_to(scene.background, img[miss].shape), rtol=1e-6)
    hit = _rays_miss_box(o, dirs, lo, hi) == 0
    # the cloud is somewhere inside the box's footprint
    assert (np.abs(img[hit] - scene.background).max(axis=1) > 0.02).any()


def test_energy_budget_closes(wdas):
    scene, sol = wdas["scene"], wdas["solution"]
    assert len(sol.domains) == len(scene.lights) == 1
    for ds in sol.domains:
        r, b, dom = ds.result, ds.result.budget, ds.domain
        assert r.converged and r.residual <= scene.method.tolerance
        assert abs(b.balance_error) < 1e-5
        parts = b.reflected + b.transmitted + b.side + b.diffusion_leak + b.absorbed + b.in_flight
        assert parts == pytest.approx(b.injected, rel=1e-5)
        for x in (b.reflected, b.transmitted, b.side, b.diffusion_leak, b.absorbed, b.in_flight):
            assert x >= 0
        assert b.in_flight <= scene.method.tolerance * b.injected
        # unit irradiance over the domain's cross-section (n_u x n_v cells of h^2) ...
        n_d, n_u, n_v = dom.shape
        assert b.injected == pytest.approx(n_u * n_v * dom.h**2, rel=1e-5)
        # ... which covers the shadow of every non-empty voxel (the domain is cropped to them) ...
        med = scene.medium
        idx = np.argwhere(med.density > 0)
        for corner in np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]):
            q = dom.world_to_index(med.origin + (idx + corner) * med.voxel_size)
            assert np.all(q[:, 1:] >= -0.5 - 1e-9) and np.all(q[:, 1:] <= np.array([n_u, n_v]) - 0.5 + 1e-9)
        # ... and is at most the medium box's shadow |d_x| A_yz + |d_y| A_xz + |d_z| A_xy, twice
        lo, hi = med.bounds
        e = hi - lo
        d = ds.light.direction / np.linalg.norm(ds.light.direction)
        shadow = abs(d[0]) * e[1] * e[2] + abs(d[1]) * e[0] * e[2] + abs(d[2]) * e[0] * e[1]
        assert b.injected <= 2.0 * shadow
        # a nearly conservative cloud (albedo 0.99): a little is absorbed, most escapes
        assert 0 < b.absorbed < 0.05 * b.injected
        assert b.escaped > 0.9 * b.injected


def test_absorbed_power_is_sigma_a_times_fluence(wdas):
    """Absorbed power = int sigma_a phi dV. sigma_a from the npz density and the TOML optics,
    phi from the solution's world-grid fluence (per unit irradiance): the walk's plus, with the
    diffusion stage, the diffuse light's."""
    toml, sol = wdas["toml"], wdas["solution"]
    vol = np.load(shared_file("npz/wdas_cloud_sixteenth_dense.npz"))
    density = vol["density"].astype(np.float64)
    sigma_a = density * toml["medium"]["scale"] * (1 - toml["medium"]["albedo"])
    phi = sol.phi[0, 0].astype(np.float64)
    if sol.phid.shape[0]:
        phi = phi + sol.phid[0, 0]
    assert phi.shape == density.shape
    assert np.all(np.isfinite(phi)) and phi.min() >= 0
    absorbed = float((sigma_a * phi).sum() * np.prod(vol["voxel_size"]))
    assert absorbed == pytest.approx(sol.domains[0].result.budget.absorbed, rel=0.02)
    # where there is cloud, the fluence is of the order of the unit irradiance (a bright cloud)
    inside = density > 0.1
    assert 0.3 < np.median(phi[inside]) < 5.0
