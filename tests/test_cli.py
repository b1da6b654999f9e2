"""The command line and scene validation: the main job works, bad input gives one clear line."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from popvol.errors import PopvolError
from popvol.scene import load_scene, scene_from_dict, DEMO_SCENE

REPO = Path(__file__).resolve().parents[1]


def popvol(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "popvol.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_render_demo_writes_png_exr_and_stats(tmp_path):
    out, exr, stats = tmp_path / "cloud.png", tmp_path / "cloud.exr", tmp_path / "stats.json"
    r = popvol("render", "-o", str(out), "--exr", str(exr), "--width", "64", "--height", "36",
               "--resolution", "32", "--stats", str(stats))
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 200 and exr.stat().st_size > 1000
    assert "64x36" in r.stdout and "propagate" in r.stdout
    doc = json.loads(stats.read_text())
    for key in ("load", "resample", "propagate", "render"):
        assert doc["seconds"][key] >= 0
    d = doc["domains"][0]
    assert d["iterations"] > 0 and d["residual"] <= doc["method"]["tolerance"]
    b = d["budget_per_unit_irradiance"]
    assert abs(b["balance_error"]) < 1e-4
    assert b["injected"] > 0 and b["escaped"] > 0.5 * b["injected"]
    from PIL import Image
    im = np.asarray(Image.open(out))
    assert im.shape == (36, 64, 3) and im.std() > 5      # a cloud, not a flat image


def test_example_toml_is_the_demo():
    a = load_scene(REPO / "examples" / "demo.toml")
    b = load_scene()
    np.testing.assert_array_equal(a.medium.density, b.medium.density)
    for key in ("scale", "albedo", "g"):
        np.testing.assert_array_equal(getattr(a.medium, key), getattr(b.medium, key))
    np.testing.assert_array_equal(a.camera.origin, b.camera.origin)
    assert vars(a.method) == vars(b.method)


def write_scene(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


MEDIUM = '[medium]\ntype = "procedural"\nresolution = 16\n'
LIGHT = '[[lights]]\ndirection = [0, -1, 0]\n'


@pytest.mark.parametrize("snippet,words", [
    (MEDIUM + 'albedo = 1.5\n' + LIGHT, ["medium.albedo", "[0, 1]"]),
    (MEDIUM + 'g = 1.0\n' + LIGHT, ["medium.g", "(-1, 1)"]),
    (MEDIUM + 'g = nan\n' + LIGHT, ["medium.g"]),
    (MEDIUM + 'scale = -2\n' + LIGHT, ["medium.scale"]),
    (MEDIUM + '[[lights]]\ndirection = [0, 0, 0]\n', ["direction"]),
    (MEDIUM + '[[lights]]\ntype = "spot"\ndirection = [0, -1, 0]\n', ["lights[0].type", "directional"]),
    (MEDIUM + LIGHT + '[camera]\nwidth = 0\n', ["camera.width", ">= 1"]),
    (MEDIUM + LIGHT + '[camera]\nheight = -3\n', ["camera.height"]),
    (MEDIUM + LIGHT + '[camera]\nfov = 190\n', ["camera.fov", "(0, 180)"]),
    (MEDIUM + LIGHT + '[camera]\norigin = [0, 0, 0]\ntarget = [0, 0, 0]\n', ["camera.target"]),
    (MEDIUM + LIGHT + '[method]\nsolver = "magic"\n', ["method.solver", "sweep"]),
    (MEDIUM + LIGHT + '[method]\nresolution = 100000\n', ["method.resolution", "4096"]),
    (MEDIUM + LIGHT + '[method]\nresolution = 4096\n', ["method.resolution", "GiB"]),
    (MEDIUM + 'albdo = 0.5\n' + LIGHT, ["unknown key medium.albdo"]),
    (MEDIUM + LIGHT + '[method]\nhandover = 0.05\n', ["method.handover", "method.handover_scale"]),
    (MEDIUM + LIGHT + '[method]\nhandover_scale = -1\n', ["method.handover_scale", "[0, 100]"]),
    ('[medium]\ntype = "file"\nfile = "nope.npz"\n' + LIGHT, ["nope.npz"]),
    (MEDIUM, ["lights"]),
    ('this is not toml', ["invalid TOML"]),
])
def test_bad_scene_gives_one_clear_line(tmp_path, snippet, words):
    err = render_error(tmp_path, snippet, words)
    assert "s.toml" in err or "nope.npz" in err


def render_error(tmp_path, scene_text, words):
    """Render the scene; it must fail with exit 2 and one line naming every word."""
    p = write_scene(tmp_path, scene_text)
    r = popvol("render", str(p), "-o", str(tmp_path / "x.png"), "--width", "8", "--height", "8")
    assert r.returncode == 2, (r.stdout, r.stderr)
    err = r.stderr.strip()
    assert err.startswith("popvol: error: ") and "\n" not in err and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("optics,words", [
    ('albedo = [0.9, 0.8]\n', ["medium.albedo", "three (RGB)"]),
    ('scale = [1, 2, -3]\n', ["medium.scale", "[0, inf]"]),
    ('albedo = {grid = "wrong_shape"}\n', ["medium.albedo grid", "(3, 3, 3)", "(4, 4, 4)"]),
    ('albedo = {grid = "too_big"}\n', ["medium.albedo grid", "outside [0, 1]", "(0, 0, 0)"]),
    ('g = {grid = "g_one"}\n', ["medium.g grid", "outside (-1, 1)"]),
    ('albedo = {grid = "nope"}\n', ["no array named 'nope'", "density"]),
    ('albedo = {file = "x.npz", grid = "a", colour = 1}\n', ["unknown key medium.albedo.colour"]),
    ('g = {grid = "g_neg"}\n[method]\ndecay = "paper"\n', ["decay = 'paper'", "g >= 0"]),
])
def test_bad_optics_give_one_clear_line(tmp_path, optics, words):
    n = (4, 4, 4)
    np.savez(tmp_path / "m.npz", density=np.ones(n, np.float32), wrong_shape=np.ones((3, 3, 3), np.float32),
             too_big=np.full(n, 1.5, np.float32), g_one=np.ones(n, np.float32),
             g_neg=np.full(n, -0.3, np.float32))
    text = '[medium]\nfile = "m.npz"\n' + optics.split("[method]")[0] + LIGHT
    if "[method]" in optics:
        text += "[method]" + optics.split("[method]")[1]
    render_error(tmp_path, text, words)


def test_bad_density_files(tmp_path):
    rho = np.ones((4, 4, 4), np.float32)
    rho[1, 2, 3] = np.nan
    np.savez(tmp_path / "nan.npz", density=rho)
    np.savez(tmp_path / "neg.npz", density=-np.ones((4, 4, 4), np.float32))
    np.savez(tmp_path / "flat.npz", density=np.ones((4, 4), np.float32))
    for name, word in (("nan", "NaN"), ("neg", "negative"), ("flat", "3-D")):
        p = write_scene(tmp_path, f'[medium]\nfile = "{name}.npz"\n' + LIGHT, f"{name}.toml")
        with pytest.raises(PopvolError, match=word) as e:
            load_scene(p)
        assert f"{name}.npz" in str(e.value)


def test_missing_scene_and_unwritable_output(tmp_path):
    r = popvol("render", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "missing.toml" in r.stderr and "not found" in r.stderr
    r = popvol("render", "-o", str(tmp_path / "no" / "dir" / "x.png"))
    assert r.returncode == 2 and "does not exist" in r.stderr


def test_scene_from_dict_is_plain_data():
    d = {**DEMO_SCENE, "medium": {**DEMO_SCENE["medium"], "resolution": 16}, "method": {"resolution": 16}}
    s = scene_from_dict(d)
    assert s.medium.shape == (16, 12, 16) and s.method.resolution == 16
    with pytest.raises(PopvolError, match="medium.albedo"):
        scene_from_dict({**d, "medium": {**d["medium"], "albedo": -0.1}})


def test_bench_quick_writes_well_formed_figures(tmp_path):
    """`popvol bench --quick` (a smoke test of the benchmark, not a timing test)."""
    out = tmp_path / "bench.json"
    r = popvol("bench", "--quick", "--json", str(out))
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert res["machine"]["cpus"] >= 1
    prop = res["propagation"][0]
    for key in ("sweep_cell_updates_per_s", "jacobi_cell_updates_per_s", "stream_cells_per_s",
                "render_camera_samples_per_s"):
        assert prop[key] > 0, key
    demo = res["demo"]
    assert demo["total_s"] > 0 and demo["residual"] <= 1e-3 and demo["method"].startswith("moment")
    assert set(demo["solve_stages_s"]) >= {"resample", "propagate", "diffusion", "fields"}


def test_reference_without_mitsuba_says_how_to_install(monkeypatch):
    from popvol.reference import import_mitsuba
    monkeypatch.setitem(sys.modules, "mitsuba", None)        # import mitsuba -> ImportError
    with pytest.raises(PopvolError, match=r"pip install 'popvol\[reference\]'"):
        import_mitsuba("scalar_rgb")
    with pytest.raises(PopvolError, match="--variant"):
        import_mitsuba("cuda_rgb")


def test_compare_against_a_black_reference_reports_flip_as_unavailable(tmp_path):
    """FLIP takes its exposure range from the reference; a black one made flip-evaluator exit
    the whole process. popvol renders at the reference's size and reports FLIP n/a."""
    from popvol.io.images import write_exr
    ref = tmp_path / "ref.exr"
    write_exr(ref, np.zeros((10, 12, 3), np.float32))
    r = popvol("compare", "--reference", str(ref), "--resolution", "16", "--json", str(tmp_path / "c.json"))
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert "FLIP n/a" in r.stdout
    assert json.loads((tmp_path / "c.json").read_text())["flip"] is None
