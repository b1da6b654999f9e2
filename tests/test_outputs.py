"""Outputs never overwrite inputs, are refused before any work when they cannot be written, and
are written atomically: an interrupted or failed write leaves the old file as it was."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from popvol import PopvolError, scene_from_dict
from popvol.cli import _json_safe, main
from popvol.io.images import write_image

ROOT = Path(__file__).resolve().parents[1]
TINY = """[medium]
type = "procedural"
resolution = 8
[[lights]]
type = "directional"
direction = [0.0, -1.0, 0.0]
[camera]
width = 16
height = 9
[method]
resolution = 8
"""


def run(args):
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    return e.value.code


@pytest.fixture
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


@pytest.fixture
def no_solve(monkeypatch):
    """Fail the test if the command gets as far as solving."""
    import popvol
    monkeypatch.setattr(popvol, "solve", lambda *a, **k: pytest.fail("solved before refusing"))


@pytest.mark.parametrize("option", ["-o", "--exr", "--stats"])
def test_an_output_that_is_the_scene_file_is_refused(tiny, tmp_path, capsys, option, no_solve):
    before = tiny.read_bytes()
    args = ["render", tiny, "-o", tmp_path / "a.png"]
    if option == "-o":
        args[-1] = tiny
    else:
        args += [option, tiny]
    assert run(args) == 2
    err = capsys.readouterr().err
    assert "input file" in err or "must end in" in err
    assert tiny.read_bytes() == before


def test_an_output_that_is_the_scenes_environment_map_is_refused(tmp_path, capsys, no_solve):
    shutil.copy(ROOT / "examples" / "demo_envmap.toml", tmp_path / "scene.toml")
    (tmp_path / "envmaps").mkdir()
    envmap = tmp_path / "envmaps" / "dusk.exr"
    shutil.copy(ROOT / "examples" / "envmaps" / "dusk.exr", envmap)
    before = envmap.read_bytes()
    assert run(["render", tmp_path / "scene.toml", "-o", tmp_path / "a.png", "--exr", envmap]) == 2
    assert "dusk.exr is the scene's input file" in capsys.readouterr().err
    assert envmap.read_bytes() == before


@pytest.mark.parametrize("args, words", [
    (["-o", "out.jpg"], "must end in .png or .exr"),
    (["-o", "a.png", "--exr", "lin.png"], "--exr lin.png: must end in .exr"),
    (["-o", "a.png", "--stats", "s.txt"], "must end in .json"),
    (["-o", "same.exr", "--exr", "same.exr"], "also the output of -o/--output"),
])
def test_bad_outputs_are_refused_before_any_work(tiny, tmp_path, monkeypatch, capsys, no_solve, args, words):
    monkeypatch.chdir(tmp_path)
    assert run(["render", tiny] + args) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err


def test_interrupted_write_leaves_the_old_image(tmp_path, monkeypatch):
    from PIL import Image
    out = tmp_path / "cloud.png"
    write_image(out, np.full((4, 6, 3), 0.5, np.float32))
    before = out.read_bytes()

    def half_then_interrupt(self, fp, *a, **k):
        Path(fp).write_bytes(b"\x89PNG partial")
        raise KeyboardInterrupt
    monkeypatch.setattr(Image.Image, "save", half_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_image(out, np.zeros((4, 6, 3), np.float32))
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.png"]      # no temporary file left


class _FullDiskExr:
    """Stands in for OpenEXR.File when writing: fails as a full disk would, after a partial file."""
    def __init__(self, *a, **k):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, path):
        Path(path).write_bytes(b"v/1\x01 partial")
        raise RuntimeError("No space left on device")


@pytest.mark.parametrize("old_png", [False, True])
def test_a_failed_exr_leaves_the_png_as_it_was(tiny, tmp_path, monkeypatch, capsys, old_png):
    """-o and --exr are written together: the EXR failing replaces neither (a new PNG is not
    left behind, an old one keeps its bytes) and the error is one line naming the EXR."""
    import OpenEXR
    out, exr = tmp_path / "a.png", tmp_path / "a.exr"
    if old_png:
        out.write_bytes(b"old")
    monkeypatch.setattr(OpenEXR, "File", _FullDiskExr)
    assert run(["render", tiny, "-o", out, "--exr", exr]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(exr) in err and "No space left" in err
    assert (out.read_bytes() == b"old") if old_png else not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == (["a.png", "tiny.toml"] if old_png else ["tiny.toml"])


def test_ctrl_c_exits_130_and_writes_nothing(tiny, tmp_path, monkeypatch, capsys):
    import popvol

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(popvol, "solve", interrupted)
    out = tmp_path / "a.png"
    assert run(["render", tiny, "-o", out]) == 130
    assert "interrupted" in capsys.readouterr().err and not out.exists()


def test_stats_are_strict_json(tiny, tmp_path):
    stats = tmp_path / "s.json"
    assert run(["render", tiny, "-o", tmp_path / "a.png", "--stats", stats]) == 0
    doc = json.loads(stats.read_text())
    assert doc["domains"][0]["converged"] is True
    assert _json_safe({"a": [float("nan"), 1.0, {"b": float("inf")}]}) == {"a": [None, 1.0, {"b": None}]}


@pytest.mark.parametrize("data, words", [
    ({"light": {"direction": [0, -1, 0]}, "lights": [{"direction": [0, -1, 0]}]}, "both [light] and [[lights]]"),
    ({"medium": {"type": "procedural", "origin": [0, 0, 0]}}, "medium.origin applies to a medium read from a file"),
    ({"medium": {"type": "procedural", "voxel_size": 0.1}}, "medium.voxel_size applies"),
])
def test_keys_that_would_be_ignored_are_refused(data, words):
    scene = {"medium": {"type": "procedural", "resolution": 8}, "lights": [{"direction": [0, -1, 0]}]}
    scene.update(data)
    if "light" in data:
        scene["lights"] = data["lights"]
    with pytest.raises(PopvolError, match=words.replace("[", r"\[").replace("]", r"\]")):
        scene_from_dict(scene)
