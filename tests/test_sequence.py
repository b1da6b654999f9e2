"""Animated scenes (popvol.sequence): frame numbers, Blender's sequence modes, file sequences,
keyframes, rendering runs of frames with records and skipping, one exposure, the flicker
figure, the video, and the command line."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import popvol
from popvol import sequence as sq
from popvol.errors import PopvolError
from popvol.procedural import demo_medium
from popvol.scene import load_scene, scene_from_dict

from conftest import shared_file

REPO = Path(__file__).resolve().parents[1]

TINY = """
[medium]
type = "procedural"
resolution = 16
scale = 20
[[lights]]
direction = [0.3, -1, 0]
[camera]
origin = [0, 0.5, 3]
target = [0, 0.5, 0]
width = 32
height = 18
[method]
resolution = 16
"""


def popvol_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "popvol.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd)


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def npz_frames(folder: Path, numbers, shape=(8, 8, 8)):
    """Tiny frames: frame n is a cube of density n in a box that moves 0.1 * n in x."""
    for n in numbers:
        d = np.zeros(shape, np.float32)
        d[2:6, 2:6, 2:6] = n
        np.savez(folder / f"vol_{n:03d}.npz", density=d, voxel_size=np.array([0.1]),
                 world_of_ijk_min=np.array([0.1 * n, 0.0, 0.0]))


FILE_SEQ = """
[medium]
file = "vol_###.npz"
frames = "{files}"
mode = "{mode}"
[[lights]]
direction = [0, -1, 0]
[camera]
origin = [0.4, 0.4, 3]
target = [0.4, 0.4, 0]
width = 32
height = 18
[method]
resolution = 16
"""


# ---------------------------------------------------------------------------------------------
# Frame numbers, file names, modes
# ---------------------------------------------------------------------------------------------

def test_frame_lists():
    assert sq.parse_frames("1-5", "f", "s") == [1, 2, 3, 4, 5]
    assert sq.parse_frames("1-240:2", "f", "s")[:3] == [1, 3, 5] and sq.parse_frames("1-240:2", "f", "s")[-1] == 239
    assert sq.parse_frames(" 1-3 , 7, 10-14:2", "f", "s") == [1, 2, 3, 7, 10, 12, 14]
    assert sq.parse_frames(12, "f", "s") == [12] and sq.parse_frames([0, 4], "f", "s") == [0, 4]
    assert sq.frames_text([1, 2, 3, 5, 7, 9, 20]) == "1-3, 5-9:2, 20"
    for bad, words in (("5-1", "A <= B"), ("1-10:0", "STEP"), ("a-b", "1-240:2"), ("", "frame numbers"),
                       ("1-3,2", "must increase"), (-1, "[0, 1048574]"), (True, "frame numbers"),
                       ("1-2000000", "[0, 1048574]"), ([1.5], "frame numbers")):
        with pytest.raises(PopvolError) as e:
            sq.parse_frames(bad, "sequence.frames", "s.toml")
        msg = str(e.value)
        assert msg.startswith("s.toml: sequence.frames = ") and words in msg and "\n" not in msg, msg


def test_frame_path_pads_like_blender():
    assert sq.frame_path("out/frame_####.png", 7) == "out/frame_0007.png"
    assert sq.frame_path("smoke_#.vdb", 123) == "smoke_123.vdb"          # never cut
    for bad in ("a_##_##.png", "out#/a_#.png", "plain.png"):
        with pytest.raises(PopvolError, match="one run of #"):
            sq.frame_path(bad, 1, "-o/--output", "popvol render")


def test_modes_follow_blender():
    files = [1, 2, 3]
    got = {m: [sq.file_number(f, files, m) for f in range(-2, 9)] for m in sq.MODES}
    #                     frame: -2    -1    0     1  2  3  4     5     6     7     8
    assert got["clip"] == [None, None, None, 1, 2, 3, None, None, None, None, None]
    assert got["extend"] == [1, 1, 1, 1, 2, 3, 3, 3, 3, 3, 3]
    assert got["repeat"] == [1, 2, 3, 1, 2, 3, 1, 2, 3, 1, 2]
    assert got["pingpong"] == [2, 3, 2, 1, 2, 3, 2, 1, 2, 3, 2]      # period 4: 1 2 3 2
    # files every 2nd frame are held for 2 frames; repeat cycles with the same spacing
    assert [sq.file_number(f, [1, 3, 5], "repeat") for f in range(1, 9)] == [1, 1, 3, 3, 5, 5, 1, 1]
    # offset: frame f reads file f + offset
    assert sq.file_number(1, [1001, 1002], "clip", offset=1000) == 1001


# ---------------------------------------------------------------------------------------------
# Scenes of frames
# ---------------------------------------------------------------------------------------------

def test_file_sequence_reads_each_frames_file_and_modes(tmp_path):
    npz_frames(tmp_path, [1, 2, 3])
    p = write(tmp_path, FILE_SEQ.format(files="1-3", mode="extend"))
    seq = sq.load_sequence(p)
    assert seq.frames == [1, 2, 3]
    for frame, n in ((1, 1), (2, 2), (3, 3), (7, 3), (0, 1)):
        sc = load_scene(p, frame=frame)
        assert sc.frame == frame and sc.medium.density.max() == n and not sc.hidden
        assert sc.medium.origin[0] == pytest.approx(0.1 * n)
        assert sc.files == ((tmp_path / f"vol_{n:03d}.npz").resolve(),)
    assert load_scene(p).frame == 1                       # a sequence loads its first frame
    p = write(tmp_path, FILE_SEQ.format(files="1-3", mode="clip"))
    sc = load_scene(p, frame=5)
    assert sc.hidden and sc.medium.density.max() == 0 and sc.medium.origin[0] == pytest.approx(0.3)
    p = write(tmp_path, FILE_SEQ.format(files="1-3", mode="pingpong"))
    assert load_scene(p, frame=4).medium.density.max() == 2


def test_missing_files_are_named(tmp_path):
    npz_frames(tmp_path, [1, 2, 5])
    p = write(tmp_path, FILE_SEQ.format(files="1-6", mode="clip"))
    seq = sq.load_sequence(p)
    with pytest.raises(PopvolError) as e:
        seq.check_files(seq.frames)
    msg = str(e.value)
    assert "3 file(s)" in msg and "numbers 3, 4, 6" in msg and "vol_003.npz" in msg and "\n" not in msg
    seq.check_files([1, 2, 5])                            # the frames that exist are fine
    r = popvol_cli("render", p, "-o", tmp_path / "f_###.png")
    assert r.returncode == 2 and "numbers 3, 4, 6" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("text,words", [
    (TINY.replace('resolution = 16\nscale', 'resolution = 16\nframes = "1-3"\nscale'),
     ["medium.frames applies to a medium file sequence"]),
    ('[medium]\nfile = "vol_###.npz"\n[[lights]]\ndirection = [0, -1, 0]\n', ["medium.frames", "'1-240'"]),
    ('[medium]\nfile = "vol.npz"\nmode = "extend"\n[[lights]]\ndirection = [0, -1, 0]\n',
     ["medium.mode", "no run of #"]),
    ('[medium]\nfile = "vol_###.npz"\nframes = "1-3"\nmode = "loop"\n[[lights]]\ndirection = [0, -1, 0]\n',
     ["medium.mode = 'loop'", "'pingpong'"]),
    (TINY + '[sequence]\nfps = 0\n', ["sequence.fps = 0", "(0, 1000)"]),
    (TINY + '[sequence]\nframe = "1-3"\n', ["unknown key sequence.frame", "fps, frames"]),
    (TINY + '[[keyframes]]\ncamera.fov = 30\n', ["keyframes[0].frame is required"]),
    (TINY + '[[keyframes]]\nframe = 1\nlights.3.direction = [0, -1, 0]\n', ["keyframes[0].lights.3", "1 [[lights]]"]),
    (TINY + '[[keyframes]]\nframe = 1\nlights.0.intensity = 2\n', ["unknown key keyframes[0].lights.0.intensity"]),
    (TINY + '[[keyframes]]\nframe = 1\ncamera.fov = 200\n', ["keyframes[0].camera.fov = 200", "(0, 180)"]),
    (TINY + '[[keyframes]]\nframe = 1\ncamera.roll = 2\n', ["unknown key keyframes[0].camera.roll"]),
    (TINY + '[[keyframes]]\nframe = 1\n[[keyframes]]\nframe = 1\n', ["keyframes[1].frame = 1", "keyframes[0]"]),
    (TINY + '[[lights]]\ntype = "sky"\nlights = 2\n[[keyframes]]\nframe = 1\nlights.1.zenith = 1\n',
     ["lights[1] is a 'sky' light"]),
    (TINY + '[[keyframes]]\nframe = 1\nlights.0.direction = [1, 0, 0]\n'
            '[[keyframes]]\nframe = 3\nlights.0.direction = [-1, 0, 0]\n', ["turns through zero", "1 and 3"]),
    (FILE_SEQ.format(files="1-3", mode="clip").replace('mode = "clip"\n', 'mode = "clip"\noffset = 10\n'),
     ["medium.offset = 10", "before frame 0"]),
])
def test_bad_sequences_give_one_clear_line(tmp_path, text, words):
    np.savez(tmp_path / "vol.npz", density=np.ones((4, 4, 4), np.float32))
    npz_frames(tmp_path, [1, 2, 3])
    p = write(tmp_path, text)
    r = popvol_cli("render", p, "-o", tmp_path / "f_###.png", "--frames", "1-3")
    err = r.stderr.strip()
    assert r.returncode == 2 and err.startswith("popvol: error: ") and "\n" not in err, err
    for w in words:
        assert w in err, err
    assert "s.toml" in err


def test_keyframes_interpolate_linearly_and_hold(tmp_path):
    p = write(tmp_path, TINY + """
[[keyframes]]
frame = 10
camera.origin = [0, 0.5, 3]
camera.fov = 30
lights.0.direction = [1, -1, 0]
lights.0.irradiance = 2
[[keyframes]]
frame = 20
camera.origin = [1, 0.5, 3]
camera.fov = 50
lights.0.direction = [-1, -1, 0]
lights.0.irradiance = [4, 2, 0]
[[keyframes]]
frame = 30
camera.fov = 40
""")
    seq = sq.load_sequence(p)
    assert seq.frames == list(range(10, 31))
    s = seq.scene(15)
    np.testing.assert_allclose(s.camera.origin, [0.5, 0.5, 3])
    assert s.camera.fov == pytest.approx(40)
    np.testing.assert_allclose(s.lights[0].direction, [0, -1, 0], atol=1e-12)    # normalised again
    np.testing.assert_allclose(s.lights[0].irradiance, [3, 2, 1])
    s = seq.scene(25)      # the camera's origin and the light are held after their last keyframe
    np.testing.assert_allclose(s.camera.origin, [1, 0.5, 3])
    assert s.camera.fov == pytest.approx(45)
    np.testing.assert_allclose(s.lights[0].direction, np.array([-1, -1, 0]) / np.sqrt(2))
    s = seq.scene(3)       # held before the first
    assert s.camera.fov == pytest.approx(30)
    np.testing.assert_allclose(s.lights[0].direction, np.array([1, -1, 0]) / np.sqrt(2))


def test_procedural_time_is_frame_over_fps(tmp_path):
    p = write(tmp_path, TINY.replace("scale = 20", "scale = 20\ntime = 1.0") + "[sequence]\nframes = '1-48'\nfps = 12\n")
    s = load_scene(p, frame=6)
    want = demo_medium(16, 7, 2.0, time=1.0 + 6 / 12).density
    np.testing.assert_array_equal(s.medium.density, want)
    assert not np.array_equal(s.medium.density, load_scene(p, frame=7).medium.density)
    # a still scene rendered as frames moves at 24 fps; the 'smooth' cloud does not move
    q = write(tmp_path, TINY, "still.toml")
    np.testing.assert_array_equal(load_scene(q, frame=12).medium.density, demo_medium(16, time=0.5).density)
    np.testing.assert_array_equal(load_scene(q).medium.density, demo_medium(16).density)
    r = write(tmp_path, TINY.replace("scale = 20", 'scale = 20\nstyle = "smooth"'), "smooth.toml")
    np.testing.assert_array_equal(load_scene(r, frame=5).medium.density, load_scene(r).medium.density)


# ---------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------

def test_render_run_writes_records_and_skips_what_is_done(tmp_path):
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-3'\n")
    out = tmp_path / "out"
    out.mkdir()
    opts = {"exr": str(out / "f_##.exr"), "method": {"exposure": 0.0}}
    first = sq.render_run(str(p), [1, 2, 3], str(out / "f_##.png"), opts)
    assert [r["frame"] for r in first] == [1, 2, 3] and not any(r["skipped"] for r in first)
    for r in first:
        assert set(r) >= {"frame", "path", "skipped", "seconds", "iterations", "diffusion_iterations", "exposure"}
        assert Path(r["path"]).is_file() and Path(r["exr"]).is_file() and r["exposure"] == 0.0
        assert r["iterations"] and all(i > 0 for i in r["iterations"]) and r["seconds"]["total"] > 0
        rec = json.loads(sq.record_path(r["path"]).read_text())
        assert rec["digest"] == r["digest"] and rec["frame"] == r["frame"]
    assert (out / "f_01.png").is_file() and not list(out.glob(".f_*"))     # no temporary left
    again = sq.render_run(str(p), [1, 2, 3], str(out / "f_##.png"), opts)
    assert all(r["skipped"] for r in again)
    assert [r["iterations"] for r in again] == [r["iterations"] for r in first]
    (out / "f_02.exr").unlink()                      # a missing image is rendered again
    again = sq.render_run(str(p), [1, 2, 3], str(out / "f_##.png"), opts)
    assert [r["skipped"] for r in again] == [True, False, True]
    opts["method"]["resolution"] = 12                # another method: every frame again
    again = sq.render_run(str(p), [1, 2, 3], str(out / "f_##.png"), opts)
    assert not any(r["skipped"] for r in again)
    with pytest.raises(PopvolError, match="unknown key options.colour"):
        sq.render_run(str(p), [1], str(out / "f_##.png"), {"colour": 1})


def test_static_frames_are_identical_and_the_flicker_figure(tmp_path):
    still = write(tmp_path, TINY.replace("scale = 20", 'scale = 20\nstyle = "smooth"') + "[sequence]\nframes = '1-3'\n",
                  "still.toml")
    res = popvol.render_sequence(still, "1-3", str(tmp_path / "s_#.exr"), warm_start=False)
    a, b = (popvol.io.images.read_exr(r["path"]) for r in res[:2])
    np.testing.assert_array_equal(a, b)           # the jitter is seeded: a static pair is identical
    f = sq.flicker(still, res)
    assert f["static_pairs"] == 2 and f["static_max_image_change"] == 0.0
    assert f["density"] == 0.0 and f["flicker"] is None
    moving = write(tmp_path, TINY + "[sequence]\nframes = '1-3'\nfps = 0.05\n", "moving.toml")
    res = popvol.render_sequence(moving, None, str(tmp_path / "m_#.exr"), warm_start=False)
    f = sq.flicker(moving, res)
    assert f["static_pairs"] == 0 and len(f["pairs"]) == 2
    assert f["density"] > 0.01 and f["image"] > 0 and f["flicker"] == pytest.approx(f["image"] / f["density"])


def test_one_exposure_for_the_sequence(tmp_path):
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-3'\n[[keyframes]]\nframe = 1\nlights.0.irradiance = 1\n"
                               "[[keyframes]]\nframe = 3\nlights.0.irradiance = 8\n")
    res = popvol.render_sequence(p, None, str(tmp_path / "f_#.png"), exr=str(tmp_path / "f_#.exr"))
    stops = {r["exposure"] for r in res}
    assert len(stops) == 1 and all(r["metered_frame"] == 2 for r in res) and not any(r["skipped"] for r in res)
    mid = popvol.io.images.read_exr(tmp_path / "f_2.exr")
    assert stops.pop() == pytest.approx(popvol.io.images.auto_exposure(mid))
    # the frames differ 8x in light and so in the PNGs: no exposure pumping hides it
    from PIL import Image
    first, last = (np.asarray(Image.open(tmp_path / f"f_{i}.png"), float).mean() for i in (1, 3))
    assert last > 2 * first
    res = popvol.render_sequence(p, None, str(tmp_path / "f_#.png"), exr=str(tmp_path / "f_#.exr"))
    assert all(r["skipped"] for r in res)


def test_cli_frames_video_and_stats(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-4'\nfps = 12\n")
    out = tmp_path / "out"
    out.mkdir()
    r = popvol_cli("render", p, "-o", out / "f_###.png", "--video", tmp_path / "v.mp4",
                   "--stats", tmp_path / "s.json", "--frames", "1-4:1")
    assert r.returncode == 0, r.stderr
    assert "4 frames (1-4)" in r.stdout and "4 rendered, 0 skipped" in r.stdout
    doc = json.loads((tmp_path / "s.json").read_text())
    assert [f["frame"] for f in doc["frames"]] == [1, 2, 3, 4]
    assert doc["flicker"]["image"] > 0 and doc["flicker"]["density"] > 0 and len(doc["flicker"]["pairs"]) == 3
    assert doc["exposure"]["setting"] == "auto" and isinstance(doc["exposure"]["stops"], float)
    import imageio_ffmpeg
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "v.mp4"))
    meta = next(reader)
    assert meta["size"] == (32, 18) and meta["fps"] == 12 and sum(1 for _ in reader) == 4
    r = popvol_cli("render", p, "-o", out / "f_###.png", "--frames", "2-3")
    assert r.returncode == 0 and "frame 3 skipped" in r.stdout and "0 rendered, 2 skipped" in r.stdout, r.stdout
    # several frames need a # run; one frame may take a plain name
    r = popvol_cli("render", p, "-o", tmp_path / "x.png")
    assert r.returncode == 2 and "-o/--output" in r.stderr and "run of #" in r.stderr and "4 frames" in r.stderr
    r = popvol_cli("render", p, "-o", tmp_path / "x.png", "--frames", "3")
    assert r.returncode == 0 and (tmp_path / "x.png").is_file()
    still = write(tmp_path, TINY, "still.toml")
    r = popvol_cli("render", still, "-o", tmp_path / "y.png", "--video", tmp_path / "v.mp4")
    assert r.returncode == 2 and "--video applies to frames" in r.stderr
    r = popvol_cli("render", p, "-o", out / "f_###.png", "--video", tmp_path / "v.avi")
    assert r.returncode == 2 and "--video" in r.stderr and ".mp4" in r.stderr


def test_cli_workers_render_on_a_local_cluster(tmp_path):
    pytest.importorskip("distributed")
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-2'\n")
    r = popvol_cli("render", p, "-o", tmp_path / "f_#.png", "--workers", "1", "--stats", tmp_path / "s.json")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "s.json").read_text())
    assert [f["frame"] for f in doc["frames"]] == [1, 2] and (tmp_path / "f_2.png").is_file()
    r = popvol_cli("render", write(tmp_path, TINY, "still.toml"), "-o", tmp_path / "x.png", "--workers", "2")
    assert r.returncode == 2 and "--workers applies to frames" in r.stderr
    r = popvol_cli("render", p, "-o", tmp_path / "f_#.png", "--workers", "1", "--scheduler", "tcp://127.0.0.1:1")
    assert r.returncode == 2 and "exclude each other" in r.stderr


def test_missing_video_package_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(PopvolError, match=r"pip install 'popvol\[video\]'"):
        sq.import_video_writer()


# ---------------------------------------------------------------------------------------------
# The examples and the smoke script
# ---------------------------------------------------------------------------------------------

def test_demo_sequence_example():
    seq = sq.load_sequence(REPO / "examples" / "demo_sequence.toml")
    assert seq.frames == list(range(1, 49)) and seq.fps == 24
    a, b = seq.scene(1, width=32, height=18), seq.scene(48, width=32, height=18)
    assert a.medium.shape == b.medium.shape and not np.array_equal(a.medium.density, b.medium.density)
    assert a.lights[0].direction @ b.lights[0].direction < 0.5          # the sun swings


def test_make_smoke_sequence(tmp_path):
    shared_file("npz/smoke1_dense.npz")
    r = subprocess.run([sys.executable, str(REPO / "scripts" / "make_smoke_sequence.py"), str(tmp_path),
                        "--frames", "3", "--downsample", "8"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    frames = [np.load(tmp_path / f"smoke_{i:04d}.npz") for i in (1, 2, 3)]
    d = [f["density"] for f in frames]
    assert d[0].shape == d[1].shape == d[2].shape
    mass = [x.sum(dtype=np.float64) for x in d]
    assert mass[2] == pytest.approx(mass[0], rel=0.02)                  # advected, not created
    height = [(x.sum(axis=(0, 2)) * np.arange(x.shape[1])).sum() / x.sum() for x in d]
    assert height[0] < height[1] < height[2]                            # it rises
    # the example scene reads such frames
    text = (REPO / "examples" / "smoke_sequence.toml").read_text().replace("../build/smoke_seq/", "")
    text = text.replace('"1-24"', '"1-3"').replace("resolution = 128", "resolution = 16")
    p = write(tmp_path, text)
    s = load_scene(p, frame=2, width=32, height=18)
    np.testing.assert_array_equal(s.medium.density, d[1])
    assert load_scene(p, frame=9).medium.density.max() == d[2].max()    # extend holds the last


def test_scene_from_dict_builds_frames():
    d = {**scene_from_dict.__globals__["DEMO_SCENE"], "sequence": {"frames": "0-4"}, "method": {"resolution": 16}}
    d["medium"] = {**d["medium"], "resolution": 16}
    s = scene_from_dict(d, frame=3)
    assert s.frame == 3
    np.testing.assert_array_equal(s.medium.density, demo_medium(16, time=3 / 24).density)


# ---------------------------------------------------------------------------------------------
# Inputs found mishandled by a run of hostile cases
# ---------------------------------------------------------------------------------------------

def test_frame_outputs_never_overwrite_the_scenes_files(tmp_path):
    """Every frame's image and EXR are checked against every file the frames read (the scene
    file, each frame's medium file, maps), and against each other, before anything is rendered
    (the middle frame used to be metered and written first)."""
    from popvol.io.images import write_exr
    write_exr(tmp_path / "env_0002.exr", np.full((8, 16, 3), 0.5, np.float32))
    env = TINY.replace("[[lights]]\ndirection = [0.3, -1, 0]\n",
                       '[[lights]]\ntype = "envmap"\nfile = "env_0002.exr"\nlights = 2\n')
    p = write(tmp_path, env + "[sequence]\nframes = '1-3'\n")
    before = (tmp_path / "env_0002.exr").read_bytes()
    r = popvol_cli("render", p, "-o", tmp_path / "x_####.png", "--exr", tmp_path / "env_####.exr")
    assert r.returncode == 2 and "env_0002.exr (frame 2) is an input file of frame" in r.stderr, r.stderr
    assert (tmp_path / "env_0002.exr").read_bytes() == before and not list(tmp_path.glob("x_*"))
    shot = write(tmp_path, TINY + "[sequence]\nframes = '1-3'\n", name="shot_0002.png")
    r = popvol_cli("render", shot, "-o", tmp_path / "shot_####.png")
    assert r.returncode == 2 and "is the scene file" in r.stderr, r.stderr
    vols = tmp_path / "v"
    vols.mkdir()
    npz_frames(vols, [1, 2])
    seq = write(vols, FILE_SEQ.format(files="1-2", mode="clip"))
    with pytest.raises(PopvolError, match="vol_001.npz .frame 1. is an input file of frame 1"):
        sq.check_frame_outputs(sq.load_sequence(seq), str(seq), str(vols / "vol_###.png"), str(vols / "vol_###.npz"),
                               [1, 2])
    r = popvol_cli("render", p, "--frames", "0,10", "-o", tmp_path / "c_1#.exr", "--exr", tmp_path / "c_#.exr")
    assert r.returncode == 2 and "c_10.exr (frame 10) is also -o/--output of frame 0" in r.stderr, r.stderr


def test_damaged_or_edited_frames_are_rendered_again(tmp_path):
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-2'\n")
    out = str(tmp_path / "f_#.png")
    opts = {"method": {"exposure": 0.0}}
    sq.render_run(str(p), [1, 2], out, opts)
    (tmp_path / "f_1.png").write_bytes(b"")                     # emptied
    rec = json.loads(sq.record_path(tmp_path / "f_2.png").read_text())
    rec["exposure"] = "abc"                                     # an edited record
    sq.record_path(tmp_path / "f_2.png").write_text(json.dumps(rec))
    again = sq.render_run(str(p), [1, 2], out, opts)
    assert [r["skipped"] for r in again] == [False, False]
    assert [r["skipped"] for r in sq.render_run(str(p), [1, 2], out, opts)] == [True, True]


def test_scheduler_addresses_that_are_not_one_or_do_not_answer(tmp_path):
    """A malformed address is refused at once; a port where something listens but never
    answers (no Dask scheduler) is given up after the timeout, in one line, not hung."""
    import socket
    import time
    pytest.importorskip("distributed")
    from popvol.distributed import connect
    for address in ("garbage", "http://example", "inproc://nothing", "tcp://host:99999"):
        with pytest.raises(PopvolError, match="give tcp://HOST:PORT"):
            connect(address, timeout=1)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(5)
        t0 = time.perf_counter()
        with pytest.raises(PopvolError, match="no answer|Timed out"):
            connect(f"tcp://127.0.0.1:{silent.getsockname()[1]}", timeout=1)
        assert time.perf_counter() - t0 < 30


def test_more_local_workers_than_cores_is_refused(tmp_path):
    import os
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-2'\n")
    r = popvol_cli("render", p, "-o", tmp_path / "f_#.png", "--workers", str((os.cpu_count() or 1) + 1))
    assert r.returncode == 2 and "cores" in r.stderr and r.stderr.count("\n") == 1, r.stderr


def test_the_exposure_is_metered_on_a_frame_that_shows_the_medium(tmp_path):
    """Frames 0-9 of files 0-2 with mode clip: the middle frame (5) is hidden, so the exposure
    is the auto exposure of the middle one of the frames that show the medium (1)."""
    npz_frames(tmp_path, [1, 2, 3])
    p = write(tmp_path, FILE_SEQ.format(files="1-3", mode="clip"))
    stops, mid, res = sq._meter(sq.load_sequence(p), list(range(0, 10)), str(tmp_path / "f_#.png"), None, {})
    assert mid == 2 and res["hidden"] is False and stops != 0.0


def test_a_frame_that_cannot_be_made_is_named(tmp_path):
    """Keyframes that bring the camera onto its target at frame 5: the error names the frame."""
    p = write(tmp_path, TINY + "[[keyframes]]\nframe = 1\ncamera.origin = [0, 0.5, 3]\n"
              "[[keyframes]]\nframe = 9\ncamera.origin = [0, 0.5, -3]\n")
    seq = sq.load_sequence(p)
    seq.scene(4)
    with pytest.raises(PopvolError, match=r"s.toml: frame 5: camera.target equals camera.origin"):
        seq.scene(5)


def test_an_edited_exposure_record_is_metered_again(tmp_path):
    p = write(tmp_path, TINY + "[sequence]\nframes = '1-3'\n")
    out = tmp_path / "f_#.png"
    stops, mid, _ = sq._meter(sq.load_sequence(p), [1, 2, 3], str(out), None, {})
    meter = tmp_path / sq.RECORD_DIR / "f_#.png.exposure.json"
    rec = json.loads(meter.read_text())
    for bad in (1e308, 100.0, float("nan")):
        meter.write_text(json.dumps({**rec, "exposure": bad}))
        again, _, res = sq._meter(sq.load_sequence(p), [1, 2, 3], str(out), None, {})
        assert again == pytest.approx(stops) and res is not None


def test_a_hash_in_a_folder_name_is_literal_for_a_plain_name_and_refused_beside_a_run(tmp_path):
    folder = tmp_path / "take#1"
    folder.mkdir()
    sq.check_patterns(str(folder / "f.png"), None, [1])                # one frame, a plain name
    with pytest.raises(PopvolError, match="# in its folder"):
        sq.check_patterns(str(folder / "f_##.png"), None, [1, 2])      # which # is the frame?


def test_missing_grid_files_of_the_sequence_are_named_before_rendering(tmp_path):
    """A per-voxel albedo grid of the same sequence (alb_###.npz) missing for some frames: named
    with the medium files, before any frame is rendered."""
    npz_frames(tmp_path, [1, 2, 3])
    for n in (1, 3):
        np.savez(tmp_path / f"alb_{n:03d}.npz", albedo=np.full((8, 8, 8), 0.5, np.float32))
    text = FILE_SEQ.format(files="1-3", mode="clip").replace('mode = "clip"\n',
                                                               'mode = "clip"\nalbedo = {file = "alb_###.npz"}\n')
    seq = sq.load_sequence(write(tmp_path, text))
    with pytest.raises(PopvolError, match=r"medium.file and its grid files: 1 file\(s\).*numbers 2 \(alb_002.npz"):
        seq.check_files([1, 2, 3])
    seq.check_files([1, 3])


@pytest.mark.parametrize("damage, words", [
    (lambda p: p.write_bytes(p.read_bytes()[:200]), "cannot read as .npz"),          # truncated
    (lambda p: p.write_bytes(b"not a zip at all" * 8), "is not an .npz archive"),
    (lambda p: np.savez(p, smoke=np.ones((4, 4, 4), np.float32)), "no array named 'density'"),
])
def test_an_unreadable_frame_file_is_named_with_its_frame_before_rendering(tmp_path, damage, words):
    """A frame file that exists but whose headers cannot be read (truncated, not an archive, no
    density array) is refused by check_files with its frame, before any frame renders, and
    render_run writes no frame."""
    npz_frames(tmp_path, [1, 2, 3])
    damage(tmp_path / "vol_003.npz")
    scene = write(tmp_path, FILE_SEQ.format(files="1-3", mode="clip"))
    seq = sq.load_sequence(scene)
    with pytest.raises(PopvolError, match=rf"frame 3: .*vol_003.npz: {words}"):
        seq.check_files([1, 2, 3])
    seq.check_files([1, 2])
    with pytest.raises(PopvolError, match="frame 3"):
        sq.render_run(scene, [1, 2, 3], str(tmp_path / "out_#.png"))
    assert not list(tmp_path.glob("out_*"))


def test_volume_headers_are_checked_like_the_readers(tmp_path):
    """io.volumes.check_volume_header passes the files read_volume reads and refuses, in one
    line naming the file, a .vol whose size or header is wrong and a .vdb without the magic."""
    from popvol.io.volumes import check_volume_header, read_volume, write_vol
    good = tmp_path / "a.vol"
    write_vol(good, np.ones((3, 4, 5), np.float32), [0, 0, 0], [1, 1, 1])
    check_volume_header(good)
    read_volume(good)
    short = tmp_path / "b.vol"
    short.write_bytes(good.read_bytes()[:-4])
    for f in (check_volume_header, read_volume):
        with pytest.raises(PopvolError, match=r"b.vol: file has .* bytes but its 3x4x5 header needs"):
            f(short)
    fake = tmp_path / "c.vdb"
    fake.write_bytes(b"VOL" + bytes(60))
    with pytest.raises(PopvolError, match=r"c.vdb: not an OpenVDB file"):
        check_volume_header(fake)
    from conftest import SHARED
    for real in (SHARED / "vdb" / "smoke1.vdb", SHARED / "vol" / "smoke1.vol"):
        if real.exists():
            check_volume_header(real)


def test_empty_frame_files_and_unwritable_output_folders_are_named_before_rendering(tmp_path, monkeypatch):
    """An empty medium file is named with the missing ones; an output folder that cannot be
    written (here a read-only file system, which refuses even root) is refused before the first
    frame, not after the frames before it."""
    import errno
    npz_frames(tmp_path, [1, 2, 3])
    (tmp_path / "vol_002.npz").write_bytes(b"")
    seq = sq.load_sequence(write(tmp_path, FILE_SEQ.format(files="1-3", mode="clip")))
    with pytest.raises(PopvolError, match=r"missing or empty, numbers 2 \(vol_002.npz"):
        seq.check_files([1, 2, 3])

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")
    import popvol.io.files
    monkeypatch.setattr(popvol.io.files.tempfile, "TemporaryFile", read_only)
    with pytest.raises(PopvolError, match="cannot write in folder .* .Read-only file system"):
        sq.check_patterns(str(tmp_path / "f_#.png"), None, [1, 2])
