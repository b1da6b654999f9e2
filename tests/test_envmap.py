"""Environment lights (popvol/envmap.py): the decomposition conserves the map's integral (an
analytic constant and a numerically integrated sky), a sun ends up alone, the background seen
is the map (against the twin and against Mitsuba's envmap), and bad maps are clear errors."""
import numpy as np
import pytest
from scipy import integrate

import popvol
from popvol import envmap
from popvol.errors import PopvolError
from popvol.io.images import write_exr
import twins as ref
from popvol.renderer import render
from popvol.scene import scene_from_dict


def test_texel_solid_angles_cover_the_sphere():
    d, omega = envmap.texel_geometry(32, 64)
    assert omega.sum() == pytest.approx(4 * np.pi, rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)


@pytest.mark.parametrize("k", [1, 5, 12, 32])
def test_constant_map_decomposes_into_lights_that_sum_to_4_pi_L(k):
    env = envmap.EnvMap(np.full((16, 32, 3), [1.0, 2.0, 0.5], np.float32))
    lights = envmap.decompose(env, k)
    assert len(lights) == k
    total = sum(l.irradiance for l in lights)
    np.testing.assert_allclose(total, 4 * np.pi * np.array([1.0, 2.0, 0.5]), rtol=1e-6)
    if k == 1:                            # the whole uniform sphere: no mean direction
        assert lights[0].a0 < 1e-6
    for l in lights:
        assert 0 <= l.a0 <= 1 and l.from_environment


def test_sky_decomposition_conserves_the_integral_of_the_analytic_sky():
    zenith, horizon, ground = np.array([0.2, 0.4, 0.9]), np.array([0.8, 0.8, 0.9]), np.array([0.1, 0.1, 0.05])

    def radiance(theta, c):          # the sky of envmap.sky, written out: sqrt(sin elevation) blend
        y = np.cos(theta)
        if y < 0:
            return ground[c]
        t = np.sqrt(y)
        return (1 - t) * horizon[c] + t * zenith[c]

    exact = [2 * np.pi * integrate.quad(lambda th: radiance(th, c) * np.sin(th), 0, np.pi,
                                        points=[np.pi / 2], limit=200)[0] for c in range(3)]
    env = envmap.sky(zenith, horizon, ground, height=256)
    lights = envmap.decompose(env, 12)
    total = sum(l.irradiance for l in lights)
    np.testing.assert_allclose(total, envmap.integral(env), rtol=1e-9)     # exactly the map's
    np.testing.assert_allclose(total, exact, rtol=2e-3)                     # and the sky's


def test_the_sun_is_its_own_light():
    H = 64
    rad = np.full((H, 2 * H, 3), 0.05, np.float32)
    rad[10:12, 40:42] = 5000.0                          # a small bright sun
    env = envmap.EnvMap(rad)
    d, omega = envmap.texel_geometry(H, 2 * H)
    sun_dir = (d[10:12, 40:42] * omega[10:12, 40:42, None]).sum((0, 1))
    sun_dir /= np.linalg.norm(sun_dir)
    sun_power = 5000.0 * omega[10:12, 40:42].sum()
    lights = envmap.decompose(env, 8)
    assert len(lights) == 8
    brightest = max(lights, key=lambda l: l.irradiance[0])
    assert sorted(l.irradiance[0] for l in lights)[-2] < 0.1 * brightest.irradiance[0]   # not split
    assert np.dot(-brightest.direction, sun_dir) > np.cos(np.radians(2.0))
    assert brightest.irradiance[0] == pytest.approx(sun_power, rel=0.05)
    # collimated, so its unscattered light is kept apart; the others are regions of the map
    # without the sun, whose texels the gather lets in (renderer.gathered_environment)
    assert brightest.a0 == 1.0 and brightest.unscattered and not brightest.map_region
    others = [l for l in lights if l is not brightest]
    assert all(l.map_region and l.a0 < 1 for l in others)
    covered = sum(l.texels.astype(int) for l in lights)
    assert covered.max() == 1 and covered.sum() == H * 2 * H                 # each texel in one light
    assert not any(l.texels[10:12, 40:42].any() for l in others)
    # one light holding the sun is no region of a map without it
    (single,) = envmap.decompose(env, 1)
    assert not single.map_region and single.a0 < 1


def _scene(env_table, width=32, height=16):
    return scene_from_dict({
        "medium": {"type": "procedural", "resolution": 16, "scale": 0.0},       # empty: only the background
        "lights": [env_table],
        "camera": {"origin": [0, 0, 0.01], "target": [0.3, 0.2, -1], "fov": 100, "width": width, "height": height},
        "method": {"resolution": 8}})


def test_background_is_the_map_in_the_kernel_and_its_twin(tmp_path):
    rng = np.random.default_rng(5)
    write_exr(tmp_path / "env.exr", rng.random((8, 16, 3)).astype(np.float32) * 3)
    sc = _scene({"type": "envmap", "file": str(tmp_path / "env.exr"), "lights": 4})
    sol = popvol.solve(sc)
    img = render(sc, sol, jitter=False)
    for py in range(0, sc.camera.height, 3):
        for px in range(0, sc.camera.width, 3):
            np.testing.assert_allclose(img[py, px], ref.render_pixel(sc, sol, px, py), rtol=1e-4, atol=1e-6)


def test_background_matches_mitsubas_envmap(tmp_path):
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed")
    from popvol.reference import import_mitsuba, mitsuba_dict
    mi = import_mitsuba("scalar_rgb")
    # a smooth map (bilinear filtering differs little) with a clear left/right/up/down structure
    d, _ = envmap.texel_geometry(32, 64)
    rad = np.stack([1 + d[..., 0], 1 + d[..., 1], 1 + d[..., 2]], -1).astype(np.float32)
    write_exr(tmp_path / "env.exr", rad)
    sc = _scene({"type": "envmap", "file": str(tmp_path / "env.exr"), "lights": 4}, 24, 16)
    ms = mi.load_dict(mitsuba_dict(sc, mi, spp=256))
    ref_img = np.asarray(mi.render(ms, spp=256), np.float64)[..., :3]
    sc.method.spp = 64
    img = render(sc)
    # both average the map over each pixel; their texel filters differ slightly (measured: mean
    # 0.007, max 0.026 on values 0..2); a flipped or rotated convention errs by ~1
    assert np.abs(img - ref_img).mean() < 0.015
    assert np.abs(img - ref_img).max() < 0.06


@pytest.mark.parametrize("table,words", [
    ({"type": "envmap", "file": "square.exr"}, ["lat-long", "twice as wide"]),
    ({"type": "envmap", "file": "missing.exr"}, ["not found"]),
    ({"type": "envmap", "file": "map.hdr"}, ["not a readable Radiance"]),
    ({"type": "envmap", "file": "map.png"}, ["OpenEXR (.exr) or Radiance (.hdr)"]),
    ({"type": "envmap"}, ["file is required"]),
    ({"type": "sky", "lights": 0}, ["lights", "[1, 256]"]),
    ({"type": "sky", "zenith": [1, 2]}, ["zenith"]),
    ({"type": "sky", "sun": 1}, ["unknown key lights[0].sun"]),
    ({"type": "spot"}, ["lights[0].type", "'envmap'", "'sky'"]),
])
def test_bad_environment_lights(tmp_path, table, words):
    write_exr(tmp_path / "square.exr", np.ones((8, 8, 3), np.float32))
    (tmp_path / "map.hdr").write_bytes(b"#?RADIANCE\n")
    (tmp_path / "map.png").write_bytes(b"\x89PNG")
    t = dict(table)
    if "file" in t:
        t["file"] = str(tmp_path / t["file"])
    with pytest.raises(PopvolError) as e:
        _scene(t)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_radiance_hdr_maps_read_like_exr(tmp_path):
    """A .hdr written by OpenCV (an independent writer) reads back as the same radiance in RGB
    order, to the precision of RGBE: one shared exponent per pixel and 8-bit mantissas, so each
    channel is exact to 1/128 of the pixel's largest channel."""
    cv2 = pytest.importorskip("cv2", reason="OpenCV is not installed (pip install 'popvol[hdr]')")
    rng = np.random.default_rng(2)
    rad = (rng.random((8, 16, 3)) * [1.0, 3.0, 9.0]).astype(np.float32) + 0.05
    cv2.imwrite(str(tmp_path / "sky.hdr"), rad[..., ::-1])          # OpenCV writes BGR
    env = envmap.load(tmp_path / "sky.hdr", scale=2.0)
    step = 2.0 * rad.max(axis=-1, keepdims=True) / 128
    assert np.all(np.abs(env.radiance - 2.0 * rad) <= step)
    assert np.all(env.radiance.argmax(-1) == rad.argmax(-1))          # RGB, not BGR
    sc = _scene({"type": "envmap", "file": str(tmp_path / "sky.hdr"), "lights": 3})
    assert len(sc.lights) == 3 and sc.environment.radiance.shape == (8, 16, 3)


def test_one_environment_per_scene_and_no_second_background():
    with pytest.raises(PopvolError, match="only one environment"):
        scene_from_dict({"medium": {"type": "procedural", "resolution": 16},
                         "lights": [{"type": "sky"}, {"type": "sky"}]})
    with pytest.raises(PopvolError, match="background of a scene with an environment"):
        scene_from_dict({"medium": {"type": "procedural", "resolution": 16},
                         "lights": [{"type": "sky"}], "background": {"radiance": 0.5}})
