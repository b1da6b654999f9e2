"""The procedural cloud (popvol.procedural) and its scene keys (medium.style, medium.time).

The generation time is measured by ``python -m popvol.procedural`` (quoted in the module's
docstring), not asserted here.
"""
import hashlib
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from popvol.errors import PopvolError
from popvol.procedural import MOVING_STYLES, STYLES, VOXEL_ASPECT, cloud_density, cloud_shape, demo_medium
from popvol.scene import DEMO_SCENE, scene_from_dict

REPO = Path(__file__).resolve().parents[1]
LIGHT = [{"direction": [0, -1, 0]}]

#: Change detector: sha256 of the "smooth" cloud as popvol 0.1 made it (before "style" existed).
#: The Mitsuba references of tests/fixtures and scenes/accuracy were rendered from these grids;
#: if a digest changes, the style changed and those references no longer match.
SMOOTH_SHA256 = {(96, 7): "a1d3f8a940edcc9400f5467c9a422b3ed03390a1c32ca54c2ad2bd338b4caa00",
                 (48, 3): "7f176da0053f2b0db781041b3cb90c1e8779cd4dc8d7825058c3a8a72f0f2dd0",
                 (8, 7): "d884f0f534df82eb90a3368c9d253db40bc0745307a49f9c1818d7c5627978f8"}


def high_frequency_fraction(d: np.ndarray, k0: float = 0.125) -> float:
    """The fraction of the density's variance (power spectrum without the mean) at spatial
    frequencies above ``k0`` cycles per voxel."""
    p = np.abs(np.fft.rfftn(d - d.mean())) ** 2
    f = [np.fft.fftfreq(n) for n in d.shape[:2]] + [np.fft.rfftfreq(d.shape[2])]
    k = np.sqrt(f[0][:, None, None] ** 2 + f[1][None, :, None] ** 2 + f[2][None, None, :] ** 2)
    return float(p[k > k0].sum() / p.sum())


@pytest.mark.parametrize("key", sorted(SMOOTH_SHA256))
def test_smooth_style_is_popvol_0_1s_cloud_bitwise(key):
    d = cloud_density(*key, style="smooth")
    assert hashlib.sha256(d.tobytes()).hexdigest() == SMOOTH_SHA256[key]


@pytest.mark.parametrize("style", STYLES)
@pytest.mark.parametrize("resolution", [8, 13, 40])
def test_grid_shape_type_and_range(style, resolution):
    d = cloud_density(resolution, 5, style)
    assert d.shape == cloud_shape(resolution, style) and d.dtype == np.float32
    assert d.min() == 0.0 and 0.0 < d.max() <= 1.0
    assert np.all(d[:, 0, :] == 0)                     # below the flat base: empty


def test_cumulus_is_the_default_and_deterministic():
    a = cloud_density(40, 11)
    assert np.array_equal(a, cloud_density(40, 11, "cumulus"))
    assert np.array_equal(a, cloud_density(40, 11, "cumulus", 0.0))
    assert np.array_equal(cloud_density(40, 11, time=2.5), cloud_density(40, 11, time=2.5))


@pytest.mark.parametrize("style", STYLES)
def test_different_seeds_give_different_clouds(style):
    a, b = cloud_density(40, 1, style), cloud_density(40, 2, style)
    assert np.abs(a - b).mean() > 0.01 * a.mean()


def test_cumulus_has_more_small_scale_detail_than_smooth():
    """At the default size, several times the variance above 1/8 cycle per voxel (wavelengths
    under 8 voxels): the erosion's billows and wisps (measured: 0.063 against 0.013)."""
    smooth = high_frequency_fraction(cloud_density(96, 7, "smooth"))
    cumulus = high_frequency_fraction(cloud_density(96, 7, "cumulus"))
    assert cumulus > 3 * smooth


def test_cumulus_keeps_a_dense_core():
    """Erosion carves the edges, not the cloud away: a good share of the occupied voxels is
    saturated, and the cloud's volume is within a factor 2 of the smooth one's."""
    c, s = cloud_density(64, 7, "cumulus"), cloud_density(64, 7, "smooth")
    assert (c == 1).sum() > 0.3 * (c > 0).sum()
    assert 0.5 < (c > 0.05).sum() / (s > 0.05).sum() < 2


def test_time_zero_is_the_still_cloud_bitwise():
    d = cloud_density(32, 7)
    for t in (0.0, -0.0, 0):
        assert np.array_equal(cloud_density(32, 7, time=t), d)


def test_density_is_continuous_in_time():
    """density(t + dt) - density(t) -> 0 as dt -> 0, at t = 0 and t = 3.7 (Lipschitz: the
    change shrinks with dt), and the cloud does change over a few seconds."""
    for t in (0.0, 3.7):
        d = cloud_density(32, 7, time=t)
        steps = [np.abs(cloud_density(32, 7, time=t + dt) - d).max() for dt in (1e-1, 1e-2, 1e-3, 1e-4)]
        assert steps[-1] < 1e-2
        for big, small in zip(steps, steps[1:]):
            assert small <= 0.2 * big + 1e-6
    assert np.abs(cloud_density(32, 7, time=5.0) - cloud_density(32, 7)).mean() > 1e-3


@pytest.mark.parametrize("style", MOVING_STYLES)
def test_time_moves_the_detail_not_the_cloud(style):
    """The puffs stay: the occupied volume changes little while the detail moves."""
    a, b = cloud_density(48, 7, style), cloud_density(48, 7, style, time=20.0)
    assert np.abs(a - b).max() > 0.5
    assert abs((a > 0.05).sum() / (b > 0.05).sum() - 1) < 0.15


def test_the_field_is_many_small_clouds_on_voxels_twice_as_tall():
    """The "field" style: separate small cumulus over a square, a fifth or so of the ground
    covered, each flat-based, on voxels twice as tall as wide (as in atmospheric models)."""
    import scipy.ndimage as ndimage
    d = cloud_density(96, 7, "field")
    assert d.shape == (96, 12, 96)
    labels, n = ndimage.label(d > 0.05)
    sizes = np.bincount(labels.ravel())[1:]
    assert (sizes >= 30).sum() >= 8                     # many clouds, not one
    cover = (d.max(axis=1) > 0).mean()
    assert 0.1 < cover < 0.5
    m = demo_medium(96, 7, extent=2.0, style="field")
    assert m.voxel_size[1] == VOXEL_ASPECT["field"] * m.voxel_size[0] == 2 * 2.0 / 96
    lo, hi = m.bounds
    np.testing.assert_allclose([lo[0], lo[1], hi[0], hi[1]], [-1.0, 0.0, 1.0, 0.5])


def test_the_field_example_is_the_field_on_tall_voxels():
    from popvol import load_scene
    sc = load_scene(REPO / "examples" / "field_sun.toml")
    assert sc.medium.voxel_size[1] == 2 * sc.medium.voxel_size[0]
    assert np.array_equal(sc.medium.density, cloud_density(128, 7, "field"))
    assert sc.lights[0].direction[2] < 0                  # the sun shines away from the camera


def test_a_field_renders_with_a_closed_energy_budget():
    """Tall voxels through the whole pipeline: every domain's budget closes and the image is
    finite, not black, and brighter where the clouds are."""
    import popvol
    sc = scene_from_dict({"medium": {"type": "procedural", "style": "field", "resolution": 48, "scale": 40.0},
                          "lights": [{"direction": [-0.45, -0.6, -0.66]}],
                          "camera": {"origin": [0.0, 0.9, 2.4], "target": [0.0, 0.1, 0.0], "width": 48, "height": 27},
                          "method": {"resolution": 48}})
    sol = popvol.solve(sc)
    for d in sol.stats()["domains"]:
        b = d["budget_per_unit_irradiance"]
        assert abs(b["balance_error"]) < 1e-4 * b["injected"]
    img = popvol.render(sc, sol)
    assert np.all(np.isfinite(img)) and img.max() > 0.02      # measured 0.048 (0.05-0.06 with the sweeps)


def test_function_refuses_unknown_style_and_bad_time():
    with pytest.raises(ValueError, match="style"):
        cloud_density(16, 7, "cirrus")
    for t in (math.nan, math.inf):
        with pytest.raises(ValueError, match="time"):
            cloud_density(16, 7, time=t)
    with pytest.raises(ValueError, match="cumulus"):
        cloud_density(16, 7, "smooth", 1.0)


# ---------------------------------------------------------------------------------------------
# The scene keys
# ---------------------------------------------------------------------------------------------

def medium(**keys):
    return scene_from_dict({"medium": {"type": "procedural", "resolution": 16, **keys}, "lights": LIGHT},
                           source="s.toml").medium


def test_scene_style_and_time_reach_the_generator():
    assert np.array_equal(medium().density, cloud_density(16, 7, "cumulus"))
    assert np.array_equal(medium(style="smooth", seed=3).density, cloud_density(16, 3, "smooth"))
    assert np.array_equal(medium(time=1.5).density, cloud_density(16, 7, time=1.5))
    assert np.array_equal(medium(style="field", time=1.5).density, cloud_density(16, 7, "field", 1.5))


@pytest.mark.parametrize("keys, words", [
    ({"style": "cirrus"}, ["medium.style", "'cumulus'", "'smooth'"]),
    ({"style": 3}, ["medium.style", "'cumulus'", "'smooth'"]),
    ({"time": math.nan}, ["medium.time", "finite"]),
    ({"time": math.inf}, ["medium.time", "finite"]),
    ({"time": "soon"}, ["medium.time"]),
    ({"time": 1e7}, ["medium.time"]),
    ({"style": "smooth", "time": 1.0}, ["medium.time", "'cumulus'"]),
])
def test_scene_refuses_bad_style_or_time_in_one_line(keys, words):
    with pytest.raises(PopvolError) as e:
        medium(**keys)
    msg = str(e.value)
    assert msg.startswith("s.toml: ") and "\n" not in msg
    for w in words:
        assert w in msg


@pytest.mark.parametrize("key", ["style", "time"])
def test_style_and_time_do_not_apply_to_a_file_medium(key, tmp_path):
    np.savez(tmp_path / "v.npz", density=np.ones((4, 4, 4), np.float32))
    with pytest.raises(PopvolError, match=f"medium.{key} applies to medium.type = 'procedural'"):
        scene_from_dict({"medium": {"file": str(tmp_path / "v.npz"), key: "smooth" if key == "style" else 1.0},
                         "lights": LIGHT})


def _procedural_scenes():
    for folder in ("scenes/accuracy", "tests/fixtures"):
        for p in sorted((REPO / folder).glob("*.toml")):
            m = tomllib.loads(p.read_text()).get("medium", {})
            if m.get("type", "file" if "file" in m else "procedural") == "procedural":
                yield p


@pytest.mark.parametrize("path", list(_procedural_scenes()), ids=lambda p: p.name)
def test_scenes_with_references_name_their_cloud(path):
    """Their Mitsuba references were rendered from one style of cloud (most from "smooth", made
    before the default became "cumulus"): each must name it, so that a change of the default
    cannot silently pair a reference with another cloud."""
    assert tomllib.loads(path.read_text())["medium"].get("style") in ("smooth", "field")


def test_the_demo_shows_the_cumulus_under_sun_and_sky():
    assert DEMO_SCENE["medium"].get("style", STYLES[0]) == "cumulus"
    kinds = [l.get("type", "directional") for l in DEMO_SCENE["lights"]]
    assert kinds == ["directional", "sky"]
    assert DEMO_SCENE["lights"][0]["direction"][2] < 0      # the sun shines away from the camera


def test_cached_noise_tiles_give_the_same_cloud():
    """The tiles are made once per seed (procedural._tiles): a frame made with them cached is
    bitwise the frame made from scratch, and the cache cannot be written through."""
    from popvol import procedural
    procedural._tiles.cache_clear()
    fresh = procedural.cloud_density(32, 11, "cumulus", 0.4)
    again = procedural.cloud_density(32, 11, "cumulus", 0.4)
    assert np.array_equal(fresh, again)
    perlin, worley, _ = procedural._tiles(11)
    assert not perlin.flags.writeable and not worley.flags.writeable
