"""`popvol view` without a browser: message checking, what each change re-computes, the saved
scene file reproducing the view, latest-wins scheduling and the server's guards (real server on
127.0.0.1, real websocket client)."""
import base64
import io
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("starlette", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("uvicorn", reason="the viewer extra is not installed (pip install '.[viewer]')")
pytest.importorskip("tomli_w", reason="the viewer extra is not installed (pip install '.[viewer]')")
ws_client = pytest.importorskip("websockets.sync.client", reason="websockets is not installed")

import popvol
from popvol.errors import PopvolError
from popvol.viewer import settings as S
from popvol.viewer.engine import DRAFT, FULL, PREVIEW, Engine
from popvol.viewer.server import running

SMALL_SCENE = """
[medium]
type = "file"
file = "../data/blob.npz"
scale = 3.0
albedo = 0.9
g = 0.6

[[lights]]
type = "directional"
direction = [-0.6, -0.7, 0.3]
irradiance = [2.0, 1.9, 1.7]

[background]
radiance = [0.2, 0.3, 0.5]

[camera]
origin = [0.4, 0.5, 2.6]
target = [0.0, 0.0, 0.0]
width = 48
height = 28

[method]
resolution = 24
exposure = 0.5
"""


def write_small_scene(folder: Path) -> Path:
    """A 20^3 blob in data/blob.npz and scenes/small.toml that reads it by a relative path."""
    (folder / "data").mkdir(exist_ok=True)
    (folder / "scenes").mkdir(exist_ok=True)
    x = np.linspace(-1, 1, 20)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    density = np.clip(1.2 - np.sqrt(X**2 + 1.5 * Y**2 + Z**2) * 1.4, 0, None).astype(np.float32)
    np.savez(folder / "data" / "blob.npz", density=density, voxel_size=np.array([0.1]),
             world_of_ijk_min=np.array([-0.95, -0.95, -0.95]))
    path = folder / "scenes" / "small.toml"
    path.write_text(SMALL_SCENE)
    return path


SEQUENCE_SCENE = """
[sequence]
frames = "1-5:2"        # frames 1, 3, 5
fps = 24
""" + SMALL_SCENE.replace('file = "../data/blob.npz"',
                         'file = "../data/vol_###.npz"\nframes = "1-5"\nmode = "extend"') + """
[[keyframes]]
frame = 1
lights.0.direction = [-0.6, -0.7, 0.3]

[[keyframes]]
frame = 5
lights.0.direction = [0.5, -0.7, 0.2]
lights.0.irradiance = [3.0, 2.5, 2.0]
"""


def write_sequence_scene(folder: Path) -> Path:
    """scenes/seq.toml: a sequence of frames 1, 3, 5 reading data/vol_001.npz ... vol_005.npz
    (the blob of write_small_scene, denser and further along +x each frame), with the sun's
    direction and irradiance keyframed and the camera free."""
    write_small_scene(folder)
    blob = np.load(folder / "data" / "blob.npz")
    for n in range(1, 6):
        np.savez(folder / "data" / f"vol_{n:03d}.npz", density=blob["density"] * (0.6 + 0.2 * n),
                 voxel_size=np.array([0.1]), world_of_ijk_min=np.array([-0.95 + 0.05 * n, -0.95, -0.95]))
    path = folder / "scenes" / "seq.toml"
    path.write_text(SEQUENCE_SCENE)
    return path


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    return write_small_scene(tmp_path_factory.mktemp("viewer"))


@pytest.fixture(scope="module")
def engine(scene_path):
    return Engine(scene_path, resolution=24, draft_resolution=12)


# -- messages ---------------------------------------------------------------------------------

BAD_MESSAGES = [
    ("{bad", "not valid JSON"),
    ("[1, 2]", "must be a JSON object"),
    ('{"type": "fly"}', "message type 'fly' is unknown"),
    ('{"settings": {"g": 0.5}}', "message type None is unknown"),
    ('{"type": "set"}', "non-empty object 'settings'"),
    ('{"type": "set", "settings": {}}', "non-empty object 'settings'"),
    ('{"type": "set", "settings": {"g": 0.5}, "extra": 1}', "unknown key(s) 'extra'"),
    ('{"type": "set", "settings": {"colour": 1}}', "unknown setting 'colour'"),
    ('{"type": "set", "settings": {"g": 1}}', "g = 1 must be a finite number in (-1, 1)"),
    ('{"type": "set", "settings": {"g": -1.0}}', "g = -1.0 must be a finite number in (-1, 1)"),
    ('{"type": "set", "settings": {"g": NaN}}', "NaN is not a number"),
    ('{"type": "set", "settings": {"density": Infinity}}', "Infinity is not a number"),
    ('{"type": "set", "settings": {"density": 1e999}}', "must be a finite number"),
    ('{"type": "set", "settings": {"albedo": 1.5}}', "albedo = 1.5 must be a finite number in [0, 1]"),
    ('{"type": "set", "settings": {"albedo": "0.5"}}', "must be a finite number"),
    ('{"type": "set", "settings": {"intensity": true}}', "must be a finite number"),
    ('{"type": "set", "settings": {"camera_elevation": 95}}', "must be a finite number in [-89, 89]"),
    ('{"type": "set", "settings": {"camera_distance": 0}}', "camera_distance = 0 must be a finite number in"),
    ('{"type": "save", "now": true}', "unknown key(s) 'now'"),
]


@pytest.mark.parametrize("text,expected", BAD_MESSAGES)
def test_bad_messages_give_one_clear_line(text, expected):
    with pytest.raises(PopvolError) as e:
        S.parse_message(text, (0.1, 10.0), has_sun=True)
    assert expected in str(e.value) and "\n" not in str(e.value)


def test_good_messages_and_scenes_without_a_sun():
    m = S.parse_message('{"type": "set", "settings": {"g": 0.5, "sun_azimuth": 30}}', (0.1, 10.0), True)
    assert m.kind == "set" and m.changes == {"g": 0.5, "sun_azimuth": 30.0}
    assert S.parse_message('{"type": "save"}', (0.1, 10.0), True).kind == "save"
    with pytest.raises(PopvolError, match="no directional light"):
        S.parse_message('{"type": "set", "settings": {"sun_azimuth": 30}}', (0.1, 10.0), has_sun=False)
    with pytest.raises(PopvolError, match="binary"):
        S.parse_message(b"\x00\x01", (0.1, 10.0), True)


def test_angles_round_trip():
    frame = S.orbit_frame((0.0, 1.0, 0.0))
    for az, el in ((0, 0), (30, 45), (-120, -60), (179, 10)):
        back = S.angles_of(S.direction_of(az, el, frame), frame)
        assert np.allclose(back, (az, el), atol=1e-9)
    # azimuth 0 is +z, 90 is +x, elevation 90 is +y
    assert np.allclose(S.direction_of(0, 0, frame), [0, 0, 1])
    assert np.allclose(S.direction_of(90, 0, frame), [1, 0, 0])
    assert np.allclose(S.direction_of(0, 90, frame), [0, 1, 0])


# -- the engine: what each change re-computes ---------------------------------------------------

def test_initial_settings_reproduce_the_scene(engine, scene_path):
    s = engine.initial
    scene = engine.scene_for(s)
    base = popvol.load_scene(scene_path)
    assert np.allclose(scene.camera.origin, base.camera.origin, atol=1e-12)
    assert np.allclose(scene.lights[0].direction, base.lights[0].direction, atol=1e-12)
    assert (s.density, s.albedo, s.g, s.intensity, s.exposure) == (1.0, 0.9, 0.6, 1.0, 0.5)


def test_camera_intensity_and_exposure_do_not_propagate(engine):
    s0 = engine.initial
    f0 = engine.frame(s0, FULL)
    solves = engine.solves
    moved = engine.frame(replace(s0, camera_azimuth=s0.camera_azimuth + 40, camera_distance=3.0), FULL)
    assert engine.solves == solves and not moved.propagated and moved.seconds["propagate"] == 0.0
    assert np.abs(moved.image - f0.image).mean() > 1e-3            # the view did change
    # intensity: the same fields with twice the irradiance, as a fresh solve would give
    s2 = replace(s0, intensity=2.0)
    brighter = engine.frame(s2, FULL)
    assert engine.solves == solves and not brighter.propagated
    scene = engine.scene_for(s2)
    fresh = popvol.render(scene, popvol.solve(scene))
    np.testing.assert_allclose(brighter.image, fresh, rtol=1e-5, atol=1e-6)
    engine.frame(replace(s0, exposure=2.0), FULL)
    assert engine.solves == solves


def test_light_and_medium_changes_propagate(engine):
    s0 = engine.initial
    f0 = engine.frame(s0, FULL)
    for change in ({"sun_azimuth": s0.sun_azimuth + 50}, {"density": 3.0}, {"albedo": 0.5}, {"g": -0.3}):
        solves = engine.solves
        f = engine.frame(replace(s0, **change), FULL)
        assert engine.solves == solves + 1 and f.propagated, change
        assert np.abs(f.image - f0.image).mean() > 1e-3, change
    solves = engine.solves                               # going back to recent settings is free
    back = engine.frame(replace(s0, density=3.0), FULL)
    assert engine.solves == solves and not back.propagated
    assert len(engine._solutions) <= 4


def test_drafts_are_smaller_and_use_the_full_solution_when_it_exists(engine):
    s = replace(engine.initial, sun_azimuth=engine.initial.sun_azimuth - 70)
    solves = engine.solves
    d = engine.frame(s, DRAFT)                                   # no solution yet: a coarse one
    assert d.propagated and d.resolution == 12 and engine.solves == solves + 1
    assert (d.width, d.height) == (24, 14)
    f = engine.frame(s, FULL)
    assert f.propagated and f.resolution == 24 and (f.width, f.height) == (48, 28)
    d2 = engine.frame(replace(s, camera_azimuth=s.camera_azimuth + 5), DRAFT)
    assert not d2.propagated and d2.resolution == 24 and engine.solves == solves + 2


def test_the_preview_is_the_full_view_without_the_gathered_last_bounce(engine, scene_path):
    """draft -> preview -> full: the preview propagates at the view's cells and renders at its
    size with gather = 0 (the image popvol.render makes of that scene); the full frame then
    renders from the preview's solution, with the gather."""
    assert engine.method.gather > 0
    assert [engine.next_level(x) for x in (DRAFT, PREVIEW, FULL)] == [PREVIEW, FULL, None]
    s = replace(engine.initial, sun_azimuth=engine.initial.sun_azimuth + 33)
    solves = engine.solves
    p = engine.frame(s, PREVIEW)
    assert p.propagated and p.resolution == 24 and (p.width, p.height) == (48, 28)
    scene = engine.scene_for(s, PREVIEW)
    assert scene.method.gather == 0 and engine.scene_for(s, FULL).method.gather == engine.method.gather
    np.testing.assert_allclose(popvol.render(scene, popvol.solve(scene)), p.image, rtol=1e-5, atol=1e-6)
    f = engine.frame(s, FULL)
    assert not f.propagated and engine.solves == solves + 1
    assert not np.allclose(f.image, p.image, rtol=1e-3)          # the gather changes the image
    no_gather = Engine(scene_path, resolution=24, draft_resolution=12)
    no_gather.method = replace(no_gather.method, gather=0)
    assert no_gather.next_level(DRAFT) == FULL


def test_saved_toml_renders_the_view_exactly(engine, tmp_path, monkeypatch):
    s = replace(engine.initial, camera_azimuth=35.0, camera_elevation=20.0, camera_distance=3.5,
                sun_azimuth=-40.0, sun_elevation=25.0, density=1.7, albedo=0.8, g=0.3, intensity=1.5,
                exposure=1.0)
    view = engine.frame(s, FULL)
    out = tmp_path / "out"
    out.mkdir()
    png, toml = engine.save(s, out)
    assert (png.name, toml.name) == ("popvol-view-001.png", "popvol-view-001.toml")
    assert engine.save(s, out)[1].name == "popvol-view-002.toml"         # never overwrites
    monkeypatch.chdir(tmp_path)                                          # somewhere else entirely
    scene = popvol.load_scene(toml)
    assert Path(scene.source) == toml
    image = popvol.render(scene, popvol.solve(scene))
    np.testing.assert_allclose(image, view.image, rtol=1e-5, atol=1e-6)
    from PIL import Image

    from popvol.io.images import tonemap
    saved = np.asarray(Image.open(png))
    assert np.array_equal(saved, tonemap(image, scene.method.exposure, scene.method.tone))
    assert np.array_equal(saved, np.asarray(Image.open(io.BytesIO(view.png))))
    # and through the command line
    r = subprocess.run([sys.executable, "-m", "popvol.cli", "render", str(toml), "-o", "again.png"],
                       capture_output=True, text=True, check=False)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(np.asarray(Image.open(tmp_path / "again.png")), saved)


SKY_AND_SUN = """
[[lights]]
type = "directional"
direction = [-0.6, -0.7, 0.3]
irradiance = 2.0

[[lights]]
type = "sky"
lights = 3
"""

POINT_ONLY = """
[[lights]]
type = "point"
position = [0.2, 0.1, 0.0]
intensity = [3.0, 2.0, 1.0]
"""


@pytest.mark.parametrize("lights", [SKY_AND_SUN, POINT_ONLY], ids=["sun+sky", "point"])
def test_saved_toml_renders_exactly_with_other_lights(lights, tmp_path):
    """An environment's K lights are kept (the sun alone moves); a point light is scaled by
    the intensity control and has no sun to move."""
    path = write_small_scene(tmp_path)
    text = SMALL_SCENE.split("[[lights]]")[0] + lights + "\n[camera]" + SMALL_SCENE.split("[camera]")[1]
    if "sky" in lights:
        text = text.replace("[background]\nradiance = [0.2, 0.3, 0.5]\n", "")
    path.write_text(text)
    e = Engine(path, resolution=16, draft_resolution=8)
    n_lights = len(e.base.lights)
    assert e.has_key and e.has_sun == ("sky" in lights)
    s = replace(e.initial, intensity=2.5, camera_azimuth=-30.0)
    if e.has_sun:
        s = replace(s, sun_azimuth=10.0, sun_elevation=60.0)
    else:
        with pytest.raises(PopvolError, match="no directional light"):
            S.parse_message('{"type": "set", "settings": {"sun_azimuth": 3}}', e.distance_range, e.has_sun)
    view = e.frame(s, FULL)
    toml = e.save(s, tmp_path)[1]
    scene = popvol.load_scene(toml)
    assert len(scene.lights) == n_lights
    key = scene.lights[0]
    power = key.irradiance if e.has_sun else key.intensity
    assert np.allclose(power, e.base.lights[0].power * 2.5)
    np.testing.assert_allclose(popvol.render(scene, popvol.solve(scene)), view.image, rtol=1e-5, atol=1e-6)


def test_saved_toml_keeps_the_scene_and_makes_paths_absolute(engine, tmp_path):
    import tomllib
    engine.save(engine.initial, tmp_path)
    data = tomllib.loads((tmp_path / "popvol-view-001.toml").read_text())
    assert Path(data["medium"]["file"]).is_absolute() and Path(data["medium"]["file"]).is_file()
    assert data["background"]["radiance"] == [0.2, 0.3, 0.5]
    assert data["method"]["resolution"] == 24 and data["method"]["exposure"] == 0.5
    with pytest.raises(PopvolError, match="does not exist"):
        engine.save(engine.initial, tmp_path / "missing")


def test_a_save_whose_png_fails_leaves_neither_file(engine, tmp_path, monkeypatch):
    """The saved view's TOML and PNG are written together: a PNG that cannot be written (here
    a full disk) leaves no scene file without its image, and the error is one line naming it."""
    from PIL import Image

    def full_disk(self, fp, *a, **k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(Image.Image, "save", full_disk)
    with pytest.raises(PopvolError, match=r"popvol-view-001.png: cannot write PNG .*No space left"):
        engine.save(engine.initial, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_view_resolution_scales_the_method():
    from popvol.scene import Method
    m = Method(resolution=128, diffusion_resolution=64, environment_resolution=64, gather_resolution=64)
    from popvol.viewer.engine import view_method
    v = view_method(m, 64)
    assert (v.resolution, v.diffusion_resolution, v.environment_resolution, v.gather_resolution) == (64, 32, 32, 32)
    assert view_method(m, 256).resolution == 128                  # never finer than the scene
    assert view_method(Method(resolution=32, diffusion_resolution=0), 16).diffusion_resolution == 0


# -- sequences: the frame setting ----------------------------------------------------------------

@pytest.fixture(scope="module")
def seq_path(tmp_path_factory):
    return write_sequence_scene(tmp_path_factory.mktemp("viewer-seq"))


@pytest.fixture(scope="module")
def seq_engine(seq_path):
    return Engine(seq_path, resolution=24, draft_resolution=12)


def test_frame_setting_is_checked_against_the_frames():
    frames = [1, 3, 5]
    m = S.parse_message('{"type": "set", "settings": {"frame": 3, "g": 0.2}}', (0.1, 10.0), True, True, frames)
    assert m.changes == {"frame": 3, "g": 0.2} and isinstance(m.changes["frame"], int)
    assert S.parse_message('{"type": "set", "settings": {"frame": 5.0}}', (0.1, 10.0), True, True,
                           frames).changes == {"frame": 5}
    for text in ('{"type": "set", "settings": {"frame": 2}}', '{"type": "set", "settings": {"frame": 7}}'):
        with pytest.raises(PopvolError, match=r"frame = \d must be one of the scene's frames \(1-5:2\)"):
            S.parse_message(text, (0.1, 10.0), True, True, frames)
    with pytest.raises(PopvolError, match="this scene has no frames"):     # a still scene
        S.parse_message('{"type": "set", "settings": {"frame": 1}}', (0.1, 10.0), True, True, None)


def test_sequence_engine_loads_each_frame_with_the_controls_on_top(seq_engine, seq_path):
    e = seq_engine
    assert e.frames == [1, 3, 5] and e.initial.frame == 1
    assert e.follows == S.SUN_KEYS                        # the sun is keyframed, the camera is not
    assert e.frames_info() == {"first": 1, "last": 5, "step": 2, "count": 3, "runs": [[1, 5, 2]],
                               "text": "1-5:2", "fps": 24.0}
    s = replace(e.initial, frame=5, sun_azimuth=None, sun_elevation=None, density=2.0, camera_azimuth=20.0)
    scene = e.scene_for(s)
    own = popvol.load_scene(seq_path, frame=5)
    assert scene.medium.density is e.frame_scene(5)[0].medium.density
    assert np.array_equal(scene.medium.density, own.medium.density)          # frame 5's file
    assert np.allclose(scene.medium.scale, 2.0 * own.medium.scale)           # density x 2 on top
    assert np.allclose(scene.lights[0].direction, own.lights[0].direction, atol=1e-12)   # keyframed sun
    assert np.allclose(scene.lights[0].irradiance, [3.0, 2.5, 2.0])
    assert S.scene_angles(scene)["camera_azimuth"] == pytest.approx(20.0)      # the orbit holds
    resolved = e.resolve(s)
    assert resolved.frame == 5 and resolved.sun_azimuth == pytest.approx(S.scene_angles(own)["sun_azimuth"])
    moved = e.scene_for(replace(s, sun_azimuth=10.0, sun_elevation=40.0))       # the user's sun, this frame
    assert S.scene_angles(moved)["sun_azimuth"] == pytest.approx(10.0)
    with pytest.raises(PopvolError, match="must be one of the scene's frames"):
        e.frame(replace(s, frame=4), DRAFT)


def test_frames_media_are_kept_in_a_small_bounded_cache(seq_path, monkeypatch):
    from popvol.viewer import engine as E
    e = Engine(seq_path, resolution=12, draft_resolution=8)
    first = e.frame_scene(1)[0]
    assert e.frame_scene(1)[0] is first is e.base                   # loaded once
    third = e.frame_scene(3)[0]
    assert e.frame_scene(3)[0] is third
    monkeypatch.setattr(E, "MAX_FRAMES", 2)
    e.frame_scene(5)
    assert len(e._frames) == 2 and e.frame_scene(5)[0] is not None
    assert e.frame_scene(1)[0] is not first                         # evicted, loaded again
    monkeypatch.setattr(E, "MAX_FRAME_BYTES", first.medium.density.nbytes + 1)
    e.frame_scene(3)
    assert len(e._frames) == 1                                      # the memory bound: the newest only


def test_a_frame_change_warm_starts_the_draft_from_the_previous_frame(seq_path, monkeypatch):
    import functools
    import inspect

    from popvol.viewer import engine as E
    if "warm" not in inspect.signature(popvol.solve).parameters:
        pytest.skip("popvol.solve takes no warm start here")
    calls = []
    real = E.solve

    @functools.wraps(real)
    def recording(scene, **kw):
        calls.append(kw)
        return real(scene, **kw)

    monkeypatch.setattr(E, "solve", recording)
    e = Engine(seq_path, resolution=16, draft_resolution=8)
    assert e.warm_start
    s = replace(e.initial, sun_azimuth=None, sun_elevation=None)
    e.frame(s, DRAFT)
    assert calls[-1].get("warm") is None                           # nothing to start from
    previous = e._last[8][0]
    d = e.frame(replace(s, frame=3), DRAFT)                        # only the frame changed
    assert calls[-1]["warm"] is previous
    assert e.warm_solves == 1 and d.propagated
    e.frame(replace(s, frame=3, density=2.0), DRAFT)               # the user changed the medium: cold
    assert calls[-1].get("warm") is None
    e.frame(replace(s, frame=5), FULL)                             # full frames are always cold
    assert calls[-1].get("warm") is None and e.warm_solves == 1


KEYED_CAMERA = """
[sequence]
frames = "0-2"
fps = 10
[medium]
type = "procedural"
resolution = 12
scale = 20
[[lights]]
type = "point"
position = [0.0, 1.5, 0.0]
intensity = 2.0
[camera]
origin = [0, 0.5, 3]
target = [0, 0.5, 0]
width = 24
height = 14
[method]
resolution = 12
[[keyframes]]
frame = 0
camera.origin = [0, 0.5, 3]
[[keyframes]]
frame = 2
camera.origin = [2, 1.0, 2]
"""


def test_a_keyframed_camera_follows_its_keyframes(tmp_path):
    path = tmp_path / "cam.toml"
    path.write_text(KEYED_CAMERA)
    e = Engine(path, resolution=12, draft_resolution=8)
    assert e.follows == S.CAMERA_KEYS and not e.has_sun
    following = replace(e.initial, frame=2, camera_azimuth=None, camera_elevation=None, camera_distance=None)
    cam = e.scene_for(following).camera
    assert np.allclose(cam.origin, [2, 1.0, 2], atol=1e-9)
    held = e.scene_for(replace(following, camera_azimuth=0.0, camera_elevation=0.0, camera_distance=3.0)).camera
    assert np.allclose(held.origin, [0, 0.5, 3], atol=1e-9)         # the user's orbit, on this frame
    # exposure = "auto" (the default): one exposure for every frame, the first full frame's
    from popvol.io.images import auto_exposure
    assert e.exposure_auto
    first = e.frame(e.initial, FULL)
    last = e.frame(following, FULL)
    assert first.exposure == last.exposure == auto_exposure(first.image, tone=e.tone)
    assert auto_exposure(last.image, tone=e.tone) != first.exposure


# -- the server -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def server(engine, tmp_path_factory):
    with running(engine, tmp_path_factory.mktemp("saves"), refine_delay=0.2) as url:
        yield url


def connect(url, **kw):
    kw.setdefault("origin", url.rstrip("/"))
    return ws_client.connect(url.replace("http", "ws", 1) + "ws", **kw)


def receive(ws, kind, timeout=60, level=None):
    """The next message of type ``kind`` (and ``level``), skipping others."""
    end = time.monotonic() + timeout
    while True:
        m = json.loads(ws.recv(timeout=max(0.01, end - time.monotonic())))
        if m["type"] == kind and (level is None or m.get("level") == level):
            return m


def test_burst_of_camera_messages_renders_the_latest_only(server, engine, monkeypatch):
    with connect(server) as ws:
        init = receive(ws, "init")
        first = receive(ws, "frame")
        assert first["level"] == FULL and first["version"] == 0
        renders, solves = engine.renders, engine.solves
        # every render waits until the whole burst is sent, whatever the machine's speed (a render
        # holds the GIL, so on a slow machine the burst would otherwise trickle in between renders)
        sent = threading.Event()
        frame = engine.frame

        def frame_after_the_burst(*args, **kwargs):
            sent.wait(60)
            return frame(*args, **kwargs)
        monkeypatch.setattr(engine, "frame", frame_after_the_burst)
        az0 = init["settings"]["camera_azimuth"]
        for i in range(20):
            ws.send(json.dumps({"type": "set", "settings": {"camera_azimuth": az0 + i + 1}}))
        sent.set()
        frames = []
        while True:
            m = receive(ws, "frame")
            frames.append(m)
            if m["level"] == FULL:
                break
        # at most the draft under way when the burst began, one of the latest, the preview, the full
        assert engine.renders - renders == len(frames) <= 4
        assert engine.solves == solves                               # camera only: no propagation
        last = frames[-1]
        assert last["version"] == 20 and last["settings"]["camera_azimuth"] == az0 + 20
        # drafts while input arrives, then the preview (no gathered last bounce) and the full frame
        assert [f["level"] for f in frames[-2:]] == [PREVIEW, FULL] and frames[-2]["version"] == 20
        assert all(f["level"] == DRAFT for f in frames[:-2])
        assert [f["version"] for f in frames] == sorted(f["version"] for f in frames)
        png = base64.b64decode(last["png"])
        assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_malformed_messages_get_an_error_and_the_server_goes_on(server):
    with connect(server) as ws:
        receive(ws, "frame")
        for text, expected in BAD_MESSAGES[:3] + BAD_MESSAGES[8:11]:
            ws.send(text)
            assert expected in receive(ws, "error")["message"]
        ws.send(b"\x00binary")
        assert "binary" in receive(ws, "error")["message"]
        ws.send(json.dumps({"type": "set", "settings": {"g": 0.2}}))
        f = receive(ws, "frame", level=PREVIEW)                 # propagated at the view's cells ...
        assert f["settings"]["g"] == 0.2 and f["propagated"]
        f = receive(ws, "frame", level=FULL)                    # ... and the full frame reuses it
        assert f["settings"]["g"] == 0.2 and not f["propagated"]


def test_save_over_the_websocket(server, engine):
    with connect(server) as ws:
        receive(ws, "frame")
        ws.send(json.dumps({"type": "set", "settings": {"density": 2.0}}))
        ws.send(json.dumps({"type": "save"}))
        saved = receive(ws, "saved")
        scene = popvol.load_scene(saved["toml"])
        assert scene.medium.scale[0] == pytest.approx(6.0)
        assert Path(saved["png"]).is_file()


def test_a_still_scene_refuses_a_frame(server):
    with connect(server) as ws:
        init = receive(ws, "init")
        assert init["frames"] is None and init["follows"] == [] and init["settings"]["frame"] is None
        assert receive(ws, "frame")["frame"] is None
        ws.send(json.dumps({"type": "set", "settings": {"frame": 1}}))
        assert "this scene has no frames" in receive(ws, "error")["message"]


@pytest.fixture(scope="module")
def seq_server(seq_engine, tmp_path_factory):
    with running(seq_engine, tmp_path_factory.mktemp("seq-saves"), refine_delay=0.2) as url:
        yield url


def test_set_frame_brings_that_frame_with_the_controls_kept(seq_server, seq_engine):
    with connect(seq_server) as ws:
        init = receive(ws, "init")
        assert init["frames"]["runs"] == [[1, 5, 2]] and init["follows"] == ["sun_azimuth", "sun_elevation"]
        first = receive(ws, "frame")
        assert first["frame"] == 1 and first["settings"]["frame"] == 1
        ws.send(json.dumps({"type": "set", "settings": {"density": 1.5, "camera_azimuth": 40.0,
                                                        "sun_azimuth": 5.0}}))
        f = receive(ws, "frame", level=FULL)
        assert f["frame"] == 1 and f["settings"]["sun_azimuth"] == 5.0 and f["follows"] == []
        ws.send(json.dumps({"type": "set", "settings": {"frame": 5}}))
        f = receive(ws, "frame", level=FULL)
        own = S.scene_angles(popvol.load_scene(seq_engine.sequence.source, frame=5))
        assert f["frame"] == 5 and f["settings"]["frame"] == 5 and f["version"] == 2
        assert f["follows"] == ["sun_azimuth", "sun_elevation"]          # the keyframed sun is back
        assert f["settings"]["sun_azimuth"] == pytest.approx(own["sun_azimuth"])
        assert f["settings"]["density"] == 1.5 and f["settings"]["camera_azimuth"] == 40.0   # kept
        ws.send(json.dumps({"type": "set", "settings": {"frame": 3, "sun_azimuth": -20.0}}))
        f = receive(ws, "frame", level=FULL)                   # a sun set with the frame holds
        assert f["frame"] == 3 and f["settings"]["sun_azimuth"] == -20.0 and f["follows"] == ["sun_elevation"]


def test_scrubbing_frames_gives_drafts_then_the_full_frame(seq_server, seq_engine):
    with connect(seq_server) as ws:
        receive(ws, "frame")
        renders = seq_engine.renders
        scrub = [3, 5, 3, 1, 3, 5, 5, 3, 1, 3, 5, 3]
        for n in scrub:
            ws.send(json.dumps({"type": "set", "settings": {"frame": n}}))
        frames = []
        while True:
            m = receive(ws, "frame")
            frames.append(m)
            if m["level"] == FULL:
                break
        assert frames[-2]["level"] == PREVIEW and (frames[-2]["width"], frames[-2]["height"]) == (48, 28)
        drafts = frames[:-2]
        assert all(f["level"] == DRAFT for f in drafts) and len(drafts) >= 1
        assert all((f["width"], f["height"]) == (24, 14) for f in drafts)               # half the pixels
        assert all(f["resolution"] in (12, 24) for f in drafts)
        last = frames[-1]
        assert last["version"] == len(scrub) and last["frame"] == 3 and (last["width"], last["height"]) == (48, 28)
        assert seq_engine.renders - renders == len(frames) < len(scrub)


def test_saved_frame_renders_as_popvol_render_of_the_saved_toml(seq_engine, seq_path, tmp_path, monkeypatch):
    import tomllib
    s = replace(seq_engine.initial, frame=3, sun_azimuth=None, sun_elevation=None, camera_azimuth=25.0,
                density=1.3, g=0.4, intensity=1.2, exposure=0.8)
    view = seq_engine.frame(s, FULL)
    assert view.settings.frame == 3
    png, toml = seq_engine.save(s, tmp_path)
    data = tomllib.loads(toml.read_text())
    assert "sequence" not in data and "keyframes" not in data and "frames" not in data["medium"]
    assert Path(data["medium"]["file"]) == (seq_path.parent.parent / "data" / "vol_003.npz").resolve()
    assert "frame 3" in toml.read_text().splitlines()[1]
    monkeypatch.chdir(tmp_path)
    r = subprocess.run([sys.executable, "-m", "popvol.cli", "render", str(toml), "-o", "again.png"],
                       capture_output=True, text=True, check=False)
    assert r.returncode == 0, r.stderr
    from PIL import Image
    saved = np.asarray(Image.open(png))
    assert np.array_equal(np.asarray(Image.open(tmp_path / "again.png")), saved)
    assert np.array_equal(saved, np.asarray(Image.open(io.BytesIO(view.png))))
    scene = popvol.load_scene(toml)
    np.testing.assert_allclose(popvol.render(scene, popvol.solve(scene)), view.image, rtol=1e-5, atol=1e-6)


def test_websocket_from_another_site_is_refused(server):
    from websockets.exceptions import InvalidStatus
    with pytest.raises(InvalidStatus):
        with connect(server, origin="http://evil.example"):
            pass


def raw_get(url: str, target: str, host: str | None = None) -> tuple[int, bytes]:
    """Send one HTTP/1.1 GET with ``target`` exactly as written (no client normalises it; it
    may carry its own headers after " HTTP/1.1"); returns (status, body)."""
    hostport = url.split("//")[1].rstrip("/")
    h, p = hostport.rsplit(":", 1)
    with socket.create_connection((h, int(p)), timeout=10) as s:
        if " HTTP/1.1\r\n" not in target:
            target += " HTTP/1.1\r\nConnection: close"
        s.sendall(f"GET {target}\r\nHost: {host or hostport}\r\n\r\n".encode())
        data = b""
        while (chunk := s.recv(65536)) and not data.startswith(b"HTTP/1.1 101"):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


TRAVERSALS = ["/static/../server.py", "/static/%2e%2e/server.py", "/static/..%2fserver.py",
              "/static/%2e%2e%2fserver.py", "/static/..%5cserver.py", "/static/%2E%2E/%2E%2E/cli.py",
              "/static/..%252fserver.py", "/static/....//server.py", "/static/.%2e/server.py",
              "/static//etc/passwd", "/static/%2fetc%2fpasswd", "/static/../../popvol/viewer/server.py",
              "/static/static/../../server.py", "/../server.py", "/%2e%2e/server.py"]


@pytest.mark.parametrize("target", TRAVERSALS)
def test_static_files_cannot_escape_their_folder(server, target):
    status, body = raw_get(server, target)
    assert status in (400, 404), (target, status)
    assert b"create_app" not in body and b"root:" not in body and b"import click" not in body


def test_page_and_static_files_are_served(server):
    status, body = raw_get(server, "/")
    assert status == 200 and b"popvol view" in body and b"/static/viewer.js" in body
    status, body = raw_get(server, "/static/viewer.js")
    assert status == 200 and b"WebSocket" in body
    status, _ = raw_get(server, "/", host="evil.example")              # DNS rebinding guard
    assert status == 400
    status, _ = raw_get(server, "/", host="localhost:1234")
    assert status == 200
    upgrade = "/ws HTTP/1.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n" \
              "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nX-Pad: 1"
    assert raw_get(server, upgrade, host="localhost:1234")[0] == 101      # the websocket too
    assert raw_get(server, upgrade, host="evil.example")[0] == 403


def test_ipv6_loopback(engine, tmp_path):
    try:
        socket.create_server(("::1", 0), family=socket.AF_INET6).close()
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    with running(engine, tmp_path, host="::1") as url:
        assert url.startswith("http://[::1]:")
        port = url.rstrip("/").rsplit(":", 1)[1]
        with socket.create_connection(("::1", int(port)), timeout=10) as s:
            s.sendall(f"GET / HTTP/1.1\r\nHost: [::1]:{port}\r\nConnection: close\r\n\r\n".encode())
            reply = b""
            while chunk := s.recv(65536):
                reply += chunk
        assert reply.startswith(b"HTTP/1.1 200") and b"popvol view" in reply


# -- the command line -----------------------------------------------------------------------------

def popvol_cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "popvol.cli", *args], capture_output=True, text=True,
                          check=False, **kw)


@pytest.mark.parametrize("args,expected", [
    (["missing.toml"], "missing.toml: scene file not found"),
    (["--port", "70000"], "--port 70000 must be an integer in [0, 65535]"),
    (["--save-dir", "no/such/folder"], "--save-dir no/such/folder: folder does not exist"),
    (["--resolution", "1"], "--resolution = 1 must be an integer in [2, 4096]"),
])
def test_view_command_bad_input_is_one_line(args, expected, tmp_path):
    r = popvol_cli("view", "--no-browser", *args, cwd=tmp_path, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip() == f"popvol: error: {expected}"


def test_view_command_serves_the_page(scene_path, tmp_path):
    """`popvol view --no-browser --port 0` warms up, prints the address, serves the page, and
    stops cleanly on Ctrl+C."""
    p = subprocess.Popen([sys.executable, "-m", "popvol.cli", "view", str(scene_path), "--no-browser",
                          "--port", "0", "--resolution", "16", "--save-dir", str(tmp_path)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        for line in p.stdout:
            if "open http://127.0.0.1:" in line:
                url = line.split("open ")[1].split()[0]
                break
        assert url, p.stderr.read()
        status, body = raw_get(url, "/")
        assert status == 200 and b"popvol view" in body
        with connect(url) as ws:
            init = receive(ws, "init")
            assert init["resolution"] == 16 and init["has_sun"]
            assert receive(ws, "frame")["level"] == FULL
            p.send_signal(signal.SIGINT)                         # Ctrl+C, with a page open
            out, err = p.communicate(timeout=30)
        assert p.returncode == 0 and "popvol view: stopped" in out and err == ""
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
