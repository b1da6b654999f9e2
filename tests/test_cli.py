"""The command line and scene validation: the main job works, bad input gives one clear line."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from popvol.errors import PopvolError
from popvol.method import Method
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
    (MEDIUM + LIGHT + '[method]\nsolver = "sweep"\n', ["method.solver", "experimental", "[experimental]"]),
    (MEDIUM + LIGHT + '[experimental]\nsolver = "magic"\n', ["experimental.solver", "'sweep', 'jacobi'"]),
    (MEDIUM + LIGHT + '[experimental]\nresolution = 64\n', ["experimental.resolution", "[method]"]),
    (MEDIUM + LIGHT + '[experimental]\nsolvr = "sweep"\n', ["unknown key experimental.solvr", "isotropic"]),
    (MEDIUM + LIGHT + '[method]\nresolution = 100000\n', ["method.resolution", "4096"]),
    (MEDIUM + LIGHT + '[method]\nresolution = 4096\n', ["method.resolution", "GiB"]),
    (MEDIUM + 'albdo = 0.5\n' + LIGHT, ["unknown key medium.albdo"]),
    (MEDIUM + LIGHT + '[method]\nhandover = 0.05\n', ["method.handover", "experimental.handover_scale"]),
    (MEDIUM + LIGHT + '[experimental]\nhandover_scale = -1\n', ["experimental.handover_scale", "[0, 100]"]),
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
    ('albedo = [0.9, 0.8]\n', ["medium.albedo", "1 or 3 finite numbers in [0, 1]"]),
    ('scale = [1, 2, -3]\n', ["medium.scale", ">= 0"]),
    ('albedo = {grid = "wrong_shape"}\n', ["medium.albedo grid", "(3, 3, 3)", "(4, 4, 4)"]),
    ('albedo = {grid = "too_big"}\n', ["medium.albedo grid", "outside [0, 1]", "voxel (0, 0, 0): 1.5)"]),
    ('g = {grid = "g_one"}\n', ["medium.g grid", "outside (-1, 1)"]),
    ('albedo = {grid = "nope"}\n', ["s.toml: medium.albedo: ", "no array named 'nope'", "'density'"]),
    ('g = {}\n', ["s.toml: medium.g: ", "no array named 'g'"]),
    ('albedo = {file = "x.npz", grid = "a", colour = 1}\n', ["unknown key medium.albedo.colour"]),
    ('g = {grid = "g_neg"}\n[experimental]\ndecay = "paper"\n', ["decay = 'paper'", "g >= 0"]),
])
def test_bad_optics_give_one_clear_line(tmp_path, optics, words):
    n = (4, 4, 4)
    np.savez(tmp_path / "m.npz", density=np.ones(n, np.float32), wrong_shape=np.ones((3, 3, 3), np.float32),
             too_big=np.full(n, 1.5, np.float32), g_one=np.ones(n, np.float32),
             g_neg=np.full(n, -0.3, np.float32))
    text = '[medium]\nfile = "m.npz"\n' + optics.split("[experimental]")[0] + LIGHT
    if "[experimental]" in optics:
        text += "[experimental]" + optics.split("[experimental]")[1]
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


# 12 voxels across, each 2 mean free paths: well under what light transport caps (the procedural
# cloud's Medium.transport_depth_cap, 6.7), where render would warn of that too (tests/test_dense_slab.py)
TINY = MEDIUM.replace("16", "12")
SMALL = "[camera]\nwidth = 16\nheight = 9\n[method]\nresolution = 8\n"


@pytest.mark.parametrize("scene, warning", [
    (TINY + LIGHT + SMALL.replace("[camera]\n", "[camera]\norigin = [0, 0, 5]\ntarget = [0, 0, 10]\n"),
     "no camera ray crosses the medium"),
    (TINY + "scale = 0\n" + LIGHT + "[background]\nradiance = 0.5\n" + SMALL, "no camera ray crosses the medium"),
    (TINY + "scale = 1e-300\n" + LIGHT + SMALL, "no camera ray crosses the medium"),
    (TINY + LIGHT + "irradiance = 0\n" + SMALL, "the image is black (every pixel 0): no light reaches the camera "
     "from the medium; no light has power"),
    (TINY + "albedo = 0\n" + LIGHT + SMALL, ("the image is black (every pixel 0): no light reaches the camera from "
     "the medium; ", "s.toml: medium.albedo = 0, so the medium absorbs all light")),
    (TINY + LIGHT + SMALL.replace("[method]\n", "[method]\nexposure = -64\n"), "o.png is black at exposure -64 "
     "stops, though the image is not (exposure 'auto' gives"),
    (TINY + LIGHT + SMALL, None),
], ids=["camera looks away", "scale 0", "scale 1e-300", "irradiance 0", "albedo 0", "exposure -64", "a cloud"])
def test_render_warns_when_the_image_shows_no_medium_or_is_black(tmp_path, scene, warning):
    """Such an image is a legitimate render: written, exit status 0, and one warning line on
    stderr saying why it shows nothing, with the likeliest cause (none for an image of the
    cloud); a PNG that its fixed exposure makes black, though the image is not, is one too."""
    path = write_scene(tmp_path, scene)
    out, exr = tmp_path / "o.png", tmp_path / "o.exr"
    r = popvol("render", str(path), "-o", str(out), "--exr", str(exr))
    assert r.returncode == 0, r.stderr
    from popvol.io.images import read_exr
    img = read_exr(exr)
    lines = r.stderr.strip().splitlines()
    if warning is None:
        assert lines == [] and img.max() > 0
        return
    warning, *more = (warning,) if isinstance(warning, str) else warning
    assert len(lines) == 1 and lines[0].startswith("popvol: warning: ") and warning in lines[0], r.stderr
    assert all(w in lines[0] for w in more), lines[0]
    assert out.stat().st_size > 0 and "Traceback" not in r.stderr
    if "exposure -64" in warning:
        from PIL import Image
        assert img.max() > 0 and not np.asarray(Image.open(out)).any()
    elif "black" in warning:
        assert not img.any()
    else:                                        # the background alone, where the scene has one
        assert np.all(img == img[0, 0]) and ("which is black" in lines[0]) == (not img.any())


def test_scene_from_dict_is_plain_data():
    d = {**DEMO_SCENE, "medium": {**DEMO_SCENE["medium"], "resolution": 16}, "method": {"resolution": 16}}
    s = scene_from_dict(d)
    assert s.medium.shape == (16, 12, 16) and s.method.resolution == 16
    with pytest.raises(PopvolError, match="medium.albedo"):
        scene_from_dict({**d, "medium": {**d["medium"], "albedo": -0.1}})


def test_bench_quick_writes_well_formed_figures(tmp_path):
    """`popvol bench --quick` (a smoke test of the benchmark, not a timing test)."""
    out = tmp_path / "bench.json"
    (tmp_path / "no_data").mkdir()         # the WDAS rows skip (tests/test_bench.py runs them) ...
    (tmp_path / "no_data" / "wdas_cloud_sixteenth_dense.npz").write_bytes(b"not a volume")   # ... unreadable
    r = popvol("bench", "--quick", "--data", str(tmp_path / "no_data"), "--json", str(out))
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert res["machine"]["cpus"] >= 1
    prop = res["propagation"][0]
    for key in ("sweep_cell_updates_per_s", "jacobi_cell_updates_per_s", "stream_cells_per_s",
                "render_camera_samples_per_s"):
        assert prop[key]["min"] > 0, key
    demo = res["scenes"]["demo"]
    assert demo["seconds"]["total"]["min"] > 0 and demo["residual"] <= Method().tolerance and demo["method"].startswith("ordinates (18): moment")
    assert set(demo["seconds"]) >= {"load", "resample", "propagate", "diffusion", "fields", "render", "total"}
    # every domain of the demo sweeps and sends, thousands of cells a sweep (a sweep in which no
    # cell passes the Southwell threshold is followed by one in which every pending cell sends)
    assert all(n >= it > 0 for n, it in zip(demo["cells_sent"], demo["iterations"]))
    assert demo["cells_sent_per_s"]["min"] > 0
    assert "not an .npz archive" in res["scenes"]["wdas_sun"]["skipped"] and "wdas_sun: skipped" in r.stdout
    # the procedural field under a point light needs no data: one full-sphere domain (n_phi = 2 n_theta)
    field = res["scenes"]["field_point"]
    assert field["domains"] == 1 and field["domain_shape"][2] == 2 * field["domain_shape"][1]
    assert field["cells_sent"][0] >= field["iterations"][0] > 0 and field["seconds"]["total"]["min"] > 0
    # and under the sun: one domain, cropped to the field (a box, not a sphere), at --quick's 48 cells
    sun = res["scenes"]["field_sun_256"]
    assert sun["domains"] == 1 and sun["resolution"] == 48 and sun["image"] == [96, 64]
    assert sun["cells_sent"][0] >= sun["iterations"][0] > 0 and sun["peak_rss_mb"] > 0


def test_reference_without_mitsuba_says_how_to_install(monkeypatch):
    from popvol.reference import import_mitsuba
    monkeypatch.setitem(sys.modules, "mitsuba", None)        # import mitsuba -> ImportError
    with pytest.raises(PopvolError, match=r"pip install 'popvol\[reference\]'"):
        import_mitsuba("scalar_rgb")
    with pytest.raises(PopvolError, match="--variant"):
        import_mitsuba("cuda_rgb")


def test_compare_against_a_black_reference_is_refused(tmp_path):
    """A black reference has no scale for the metric (its epsilon is 0) and no exposure range
    for FLIP (which once made flip-evaluator exit the whole process): refused in one line."""
    from popvol.io.images import write_exr
    ref = tmp_path / "ref.exr"
    write_exr(ref, np.zeros((10, 12, 3), np.float32))
    r = popvol("compare", "--reference", str(ref), "--resolution", "16", "--json", str(tmp_path / "c.json"))
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"popvol: error: {ref}: the reference is black (every pixel 0); there is nothing to compare with"]
    assert not (tmp_path / "c.json").exists()


# -- hostile values: always one PopvolError line, never a TypeError ---------------------------

@pytest.mark.parametrize("snippet,words", [
    (MEDIUM + LIGHT + '[method]\nspp = "many"\n', ["method.spp", "[1, 4096]"]),
    (MEDIUM + LIGHT + '[method]\nstep = true\n', ["method.step", "[0.001, 16]"]),
    (MEDIUM + LIGHT + '[method]\nresolution = 64.0\n', ["method.resolution", "integer"]),
    (MEDIUM + LIGHT + '[method]\nenvironment_resolution = 1\n', ["method.environment_resolution", "0 or"]),
    (MEDIUM + LIGHT + '[method]\ntolerance = inf\n', ["method.tolerance"]),
    (MEDIUM + LIGHT + '[experimental]\nisotropic = ["walk"]\n', ["experimental.isotropic", "'walk'"]),
    ('method = 3\n' + MEDIUM + LIGHT, ["method must be a table"]),
    ('experimental = "yes"\n' + MEDIUM + LIGHT, ["experimental must be a table"]),
    (MEDIUM + LIGHT + '[camera]\norigin = "here"\n', ["camera.origin", "3 finite numbers"]),
    (MEDIUM + LIGHT + '[camera]\norigin = [1e308, 0, 0]\ntarget = [-1e308, 0, 0]\n', ["camera.target"]),
    (MEDIUM + LIGHT + '[camera]\nwidth = 1e308\n', ["camera.width", "integer"]),
    (MEDIUM + LIGHT + '[camera]\nup = [[0, 1, 0]]\n', ["camera.up"]),
    (MEDIUM + '[[lights]]\ndirection = [0, -1, 0]\nirradiance = [[1, 2, 3]]\n', ["lights[0].irradiance", ">= 0"]),
    (MEDIUM + '[[lights]]\ndirection = [0, -1, 0]\nirradiance = "bright"\n', ["lights[0].irradiance"]),
    (MEDIUM + '[[lights]]\ndirection = [0, -1, 0]\na0 = nan\n', ["lights[0].a0", "[0, 1]"]),
    (MEDIUM + '[[lights]]\ndirection = ["x", 1, 2]\n', ["lights[0].direction"]),
    (MEDIUM + '[[lights]]\ntype = "point"\nposition = [[0], [1, 2]]\n', ["lights[0].position"]),
    (MEDIUM + '[[lights]]\ntype = 3\n', ["lights[0].type", "'directional'"]),
    (MEDIUM + '[[lights]]\ntype = "sky"\nlights = true\n', ["lights[0].lights", "[1, 256]"]),
    (MEDIUM + 'extent = -1\n' + LIGHT, ["medium.extent", "(0, "]),
    (MEDIUM + 'seed = 1e308\n' + LIGHT, ["medium.seed", "integer"]),
    (MEDIUM + 'g = "0.5"\n' + LIGHT, ["medium.g", "(-1, 1)"]),
    (MEDIUM + 'albedo = [0.5, "x", 0.5]\n' + LIGHT, ["medium.albedo"]),
    ('[medium]\ntype = ["file"]\n' + LIGHT, ["medium.type", "'procedural'"]),
    ('[medium]\nfile = 7\n' + LIGHT, ["medium.file", "string"]),
    ('[medium]\nfile = "x.npz"\ngrid = 7\n' + LIGHT, ["medium.grid", "string"]),
    (MEDIUM + LIGHT + '[background]\nradiance = [1, 2]\n', ["background.radiance", "1 or 3"]),
    (MEDIUM + LIGHT + '[background]\ntype = 5\n', ["background.type", "'constant'"]),
])
def test_hostile_scene_values_give_one_line(tmp_path, snippet, words):
    p = write_scene(tmp_path, snippet)
    with pytest.raises(PopvolError) as e:
        load_scene(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)), msg
    for w in words:
        assert w in msg, msg


# -- the method's knobs: declared once, read by the loader, the CLI and the docs --------------

def test_method_defaults_and_validation_come_from_the_knobs():
    from dataclasses import fields
    from popvol.method import KNOBS, Method
    assert [f.name for f in fields(Method)] == [k.name for k in KNOBS]
    m = Method()
    assert all(getattr(m, k.name) == k.default for k in KNOBS)
    assert m.validate("x") is m and m.experimental_changes() == {}
    for k in KNOBS:
        bad = ["nope"] if k.type is str else [k.allowed[1] + 1, "many", True, None]
        for v in bad:
            with pytest.raises(PopvolError, match=rf"^src: {k.table}\.{k.name} = "):
                k.check(v, "src")
        if k.type is not str:
            assert k.check(k.allowed[0], "src") == k.allowed[0]


def test_scene_md_documents_exactly_the_knobs():
    """docs/SCENE.md holds the tables knob_table_markdown() generates (regenerate them from it
    when a knob changes) under [method] and [experimental], and names the CLI's options."""
    from popvol.method import KNOBS, cli_knobs, knob_table_markdown
    doc = (REPO / "docs" / "SCENE.md").read_text()
    method_part = doc.split("## `[method]`")[1].split("## `[experimental]`")[0]
    experimental_part = doc.split("## `[experimental]`")[1].split("\n## ")[0]
    assert knob_table_markdown(False) in method_part, "\n" + knob_table_markdown(False)
    assert knob_table_markdown(True) in experimental_part, "\n" + knob_table_markdown(True)
    documented = [line.split("`")[1] for line in (method_part + experimental_part).splitlines()
                  if line.startswith("| `")]
    assert sorted(documented) == sorted(k.name for k in KNOBS)
    for command in ("render", "compare"):
        for k in cli_knobs(command):
            assert f"`{k.option}`" in method_part


def test_cli_offers_the_cli_knobs_and_no_experimental_ones():
    from click.testing import CliRunner
    from popvol.cli import cli
    from popvol.method import KNOBS, cli_knobs
    assert {k.name for k in cli_knobs("render")} == {"resolution", "spp", "gather", "voxel_depth", "exposure", "tone"}
    assert {k.name for k in cli_knobs("compare")} == {"resolution", "spp", "gather", "voxel_depth"}
    runner = CliRunner()
    for command in ("render", "compare"):
        text = runner.invoke(cli, [command, "--help"]).output
        for k in KNOBS:
            assert (k.option in text) == (k in cli_knobs(command)), (command, k.name)
    for option in ("--solver", "--rule", "--decay", "--isotropic"):
        r = runner.invoke(cli, ["render", option, "x"])
        assert r.exit_code == 2 and "No such option" in r.output


def test_bad_cli_knob_names_the_option(tmp_path):
    r = popvol("render", "-o", str(tmp_path / "x.png"), "--spp", "0")
    assert r.returncode == 2
    assert r.stderr.strip() == "popvol: error: popvol render: --spp = 0 must be an integer in [1, 4096]"


def test_experimental_table_and_python_overrides(tmp_path):
    p = write_scene(tmp_path, MEDIUM + LIGHT + '[method]\nresolution = 16\n'
                    '[experimental]\nisotropic = "walk"\nrule = "paper"\nsolver = "sweep"\n')
    s = load_scene(p)
    assert (s.method.isotropic, s.method.rule, s.method.resolution) == ("walk", "paper", 16)
    assert s.method.experimental_changes() == {"solver": "sweep", "rule": "paper", "isotropic": "walk"}
    with pytest.raises(PopvolError, match=r"experimental\.rule = 'paper' needs experimental\.solver = 'sweep'"):
        load_scene(p, solver="ordinates")
    s = load_scene(p, isotropic="diffusion", solver="jacobi", handover_scale=3, spp=2)
    assert (s.method.isotropic, s.method.solver, s.method.handover_scale, s.method.spp) == \
        ("diffusion", "jacobi", 3.0, 2)
    with pytest.raises(PopvolError, match=r"experimental\.isotropic = 'fast' must be one of 'diffusion', 'walk'"):
        load_scene(p, isotropic="fast")
    with pytest.raises(PopvolError, match="unknown override 'isotropc'"):
        load_scene(p, isotropc="walk")


def test_method_tables_round_trip(tmp_path):
    """method_tables writes every [method] knob and only the changed experimental ones; the
    written scene loads to the same method."""
    import tomli_w
    from popvol.method import KNOBS, Method, method_tables
    t = method_tables(Method())
    assert t["experimental"] == {} and set(t["method"]) == {k.name for k in KNOBS if not k.experimental}
    m = Method(resolution=16, isotropic="walk", decay="paper", tolerance=1e-4, exposure=1)
    t = method_tables(m)
    assert t["experimental"] == {"isotropic": "walk", "decay": "paper"}
    assert type(t["method"]["exposure"]) is float
    d = {**DEMO_SCENE, "medium": {**DEMO_SCENE["medium"], "resolution": 16}, **t}
    p = tmp_path / "written.toml"
    p.write_text(tomli_w.dumps(d))
    assert vars(load_scene(p).method) == vars(m.validate("m"))


def test_a_first_compile_of_a_popvol_kernel_is_said_once():
    """announce_compiling (what `popvol` shows on a terminal while Numba compiles): one line at
    the first compile of one of popvol's kernels, none for other functions' compiles or for a
    kernel already compiled."""
    import numba
    from numba.core import event
    from popvol.cli import COMPILING, announce_compiling

    def other(x):
        return x * 2

    def kernel(x):
        return x + 1
    kernel.__module__ = "popvol.kernels.example"     # where Numba sees it defined

    said = []
    listener = announce_compiling(said.append)
    try:
        numba.njit(other)(1)
        assert said == []
        fast = numba.njit(kernel)
        fast(1)
        fast(1)                 # compiled already
        fast(1.5)               # a second compile (float64)
    finally:
        event.unregister("numba:compile", listener)
    assert said == [COMPILING]
