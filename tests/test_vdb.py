"""OpenVDB input through Debian's pyopenvdb (popvol/io/vdb.py), against the shared data's
reference statistics (computed with pyopenvdb and cross-checked with bpy's openvdb 12) and the
dense .npz exports; and the errors for what popvol cannot read."""
import json
import subprocess
import textwrap

import numpy as np
import pytest

from conftest import SHARED, shared_file
from popvol.errors import PopvolError
from popvol.io.vdb import cut_short, debian_python, reader_detail
from popvol.io.volumes import read_volume


def _have_pyopenvdb() -> bool:
    exe = debian_python()
    return bool(exe) and subprocess.run([exe, "-I", "-c", "import pyopenvdb"], capture_output=True).returncode == 0


needs_reader = pytest.mark.skipif(not _have_pyopenvdb(),
                                  reason="Debian's python3-openvdb is not installed (apt-get install python3-openvdb)")


@pytest.fixture(scope="module")
def stats():
    p = SHARED / "reference_stats.json"
    if not p.exists():
        pytest.skip(f"{p} not found: the shared volume data is not beside this checkout")
    return json.loads(p.read_text())["files"]


@needs_reader
@pytest.mark.parametrize("name", ["wdas_cloud_sixteenth", "smoke1", "vpt_dragon_fog"])
def test_vdb_matches_reference_stats_and_npz(name, stats):
    """WDAS has active tiles, smoke1 is blosc + half float, the dragon is file version 224."""
    path = shared_file(f"vdb/{name}.vdb")
    s = stats[f"vdb/{name}.vdb"]
    v = read_volume(path)
    assert list(v.density.shape) == s["dense_shape_xyz"]
    assert v.density.sum(dtype=np.float64) == pytest.approx(s["sum"], rel=1e-6)
    assert v.density.max() == pytest.approx(s["max"])
    assert int(np.count_nonzero(v.density)) == s["nonzero_voxels"]
    lo = np.array(s["ijk_min"])
    for sample in s["samples"]:
        assert v.density[tuple(np.array(sample["ijk"]) - lo)] == pytest.approx(sample["value"], rel=1e-6)
    np.testing.assert_allclose(v.voxel_size, s["voxel_size"], rtol=1e-7)
    np.testing.assert_allclose(v.origin, s["world_of_ijk_min"], rtol=1e-7, atol=1e-9)
    with np.load(shared_file(f"npz/{name}_dense.npz")) as z:
        np.testing.assert_array_equal(v.density, z["density"])


def _write_vdb(path, body):
    """Make a .vdb with Debian's pyopenvdb (``vdb`` and ``np`` are in scope in ``body``)."""
    script = "import numpy as np, pyopenvdb as vdb, sys\npath = sys.argv[1]\n" + textwrap.dedent(body)
    subprocess.run([debian_python(), "-I", "-c", script, str(path)], check=True, capture_output=True)


@needs_reader
def test_grid_choice_and_missing_grid_names_the_ones_that_exist(tmp_path):
    p = tmp_path / "two.vdb"
    _write_vdb(p, """
        a = vdb.FloatGrid(); a.name = "smoke"; a.copyFromArray(np.ones((3, 4, 5), np.float32))
        b = vdb.FloatGrid(); b.name = "temperature"; b.copyFromArray(np.full((2, 2, 2), 7, np.float32))
        vdb.write(path, grids=[a, b])
    """)
    assert read_volume(p, "temperature").density.shape == (2, 2, 2)
    assert read_volume(p, "smoke").density.shape == (3, 4, 5)
    with pytest.raises(PopvolError, match=r"no grid named 'density'.*'smoke', 'temperature'"):
        read_volume(p, "density")
    with pytest.raises(PopvolError, match="several grids and none is named 'density'"):
        read_volume(p)


@needs_reader
def test_single_grid_of_any_name_and_its_transform(tmp_path):
    p = tmp_path / "one.vdb"
    _write_vdb(p, """
        g = vdb.FloatGrid(); g.name = "fog"
        g.copyFromArray(np.arange(24, dtype=np.float32).reshape(2, 3, 4), ijk=(5, -2, 1))
        g.transform = vdb.createLinearTransform(voxelSize=0.5); g.transform.translate((1.0, 2.0, 3.0))
        vdb.write(path, grids=[g])
    """)
    v = read_volume(p)               # the only grid is read whatever its name
    # the value-0 voxel at ijk (5, -2, 1) is inactive, but its neighbours span the same box
    np.testing.assert_array_equal(v.density, np.arange(24, dtype=np.float32).reshape(2, 3, 4))
    np.testing.assert_allclose(v.voxel_size, 0.5)
    np.testing.assert_allclose(v.origin, 0.5 * np.array([5, -2, 1]) + [1.0, 2.0, 3.0])


@needs_reader
def test_a_nonzero_background_fills_the_inactive_voxels_of_the_active_box_only(tmp_path):
    """docs/SCENE.md: the medium is the active bounding box; its inactive voxels hold the grid's
    background (as OpenVDB's own dense copy gives them), and outside the box it is empty."""
    p = tmp_path / "fog.vdb"
    _write_vdb(p, """
        g = vdb.FloatGrid(0.5); g.name = "density"
        a = g.getAccessor(); a.setValueOn((0, 0, 0), 2.0); a.setValueOn((3, 1, 0), 3.0)
        vdb.write(path, grids=[g])
    """)
    v = read_volume(p)
    expected = np.full((4, 2, 1), 0.5, np.float32)
    expected[0, 0, 0], expected[3, 1, 0] = 2.0, 3.0
    np.testing.assert_array_equal(v.density, expected)


@needs_reader
@pytest.mark.parametrize("body, message", [
    ("""
        g = vdb.Vec3SGrid(); g.name = "density"; g.copyFromArray(np.ones((2, 2, 2, 3), np.float32))
        vdb.write(path, grids=[g])
     """, "Vec3SGrid"),
    ("""
        g = vdb.FloatGrid(); g.name = "density"; g.copyFromArray(np.ones((2, 2, 2), np.float32))
        g.transform = vdb.createLinearTransform(voxelSize=1.0); g.transform.rotate(0.5, vdb.Axis.Z)
        vdb.write(path, grids=[g])
     """, "rotated"),
    ("""
        g = vdb.FloatGrid(); g.name = "density"
        vdb.write(path, grids=[g])
     """, "no active voxels"),
])
def test_grids_popvol_cannot_use_are_clear_errors(tmp_path, body, message):
    p = tmp_path / "bad.vdb"
    _write_vdb(p, body)
    with pytest.raises(PopvolError, match=message) as e:
        read_volume(p)
    assert str(p) in str(e.value)


@needs_reader
def test_sparse_grid_too_large_to_densify_is_refused_before_allocating(tmp_path):
    """Two active voxels 10^5 apart: a bounding box of 10^15 voxels, a few bytes on disk."""
    p = tmp_path / "sparse.vdb"
    _write_vdb(p, """
        g = vdb.FloatGrid(); g.name = "density"
        a = g.getAccessor(); a.setValueOn((0, 0, 0), 1.0); a.setValueOn((100000, 100000, 100000), 1.0)
        vdb.write(path, grids=[g])
    """)
    with pytest.raises(PopvolError, match=r"grid 'density'.*100001x100001x100001 voxels.*GiB") as e:
        read_volume(p)
    assert str(p) in str(e.value)


@needs_reader
def test_unreadable_vdb(tmp_path):
    p = tmp_path / "junk.vdb"
    p.write_bytes(b"this is not an OpenVDB file" * 10)
    with pytest.raises(PopvolError, match="not a readable OpenVDB file") as e:
        read_volume(p)
    assert str(p) in str(e.value)


def test_missing_reader_says_how_to_install(tmp_path, monkeypatch):
    p = tmp_path / "a.vdb"
    p.write_bytes(b"x")
    monkeypatch.delenv("POPVOL_VDB_PYTHON", raising=False)
    monkeypatch.setattr("popvol.io.vdb.debian_python", lambda: None)
    with pytest.raises(PopvolError, match="apt-get install python3-openvdb"):
        read_volume(p)


def test_a_reader_that_is_not_there_or_not_one_is_named_by_its_variable(tmp_path, monkeypatch):
    """POPVOL_VDB_PYTHON set to a program that does not exist, or to one that is not the reader
    (it prints something else): the message names the variable and says what went wrong."""
    p = tmp_path / "a.vdb"
    p.write_bytes(b"x")
    monkeypatch.setenv("POPVOL_VDB_PYTHON", str(tmp_path / "no-such-python"))
    with pytest.raises(PopvolError, match=r"POPVOL_VDB_PYTHON=.*no-such-python is not a program that can be run"):
        read_volume(p)
    monkeypatch.setenv("POPVOL_VDB_PYTHON", "/bin/echo")
    with pytest.raises(PopvolError, match=r"reader \(POPVOL_VDB_PYTHON=/bin/echo\) failed: unexpected output"):
        read_volume(p)


@pytest.mark.parametrize("keep", [8, 64, 150, 0.1, 0.5, -1])
def test_a_truncated_vdb_is_refused_at_once(tmp_path, keep):
    """A .vdb cut short (a download that stopped) is refused from its own header, in well under a
    second: its grid's end offset lies past the file's last byte, or the header itself does.
    OpenVDB took up to a minute and gigabytes of memory to refuse such a file, and its message
    was gigabytes of padding. The complete file's header is not refused."""
    src = shared_file("vdb/vpt_dragon_fog.vdb")
    data = src.read_bytes()
    n = {0.1: len(data) // 10, 0.5: len(data) // 2, -1: len(data) - 1}.get(keep, keep)
    p = tmp_path / "cut.vdb"
    p.write_bytes(data[:n])
    with pytest.raises(PopvolError, match="it is truncated") as e:
        read_volume(p)
    msg = str(e.value)
    assert str(p) in msg and "\n" not in msg and len(msg) < 300
    assert cut_short(src) is None


def test_a_reader_message_is_one_short_line():
    """What the OpenVDB reader says is cut to its words at both ends, at most 300 characters (a
    damaged file once made OpenVDB's message 1.6 GB of padding); an empty one gets a reason."""
    words = reader_detail("'Map" + " " * 1_000_000 + "\n\t is not registered'")
    assert words == "'Map ... is not registered'"
    assert len(reader_detail("x " * 10_000)) <= 300
    assert "truncated or corrupt" in reader_detail("")


def test_nanovdb_is_a_clear_error(tmp_path):
    p = tmp_path / "a.nvdb"
    p.write_bytes(b"x")
    with pytest.raises(PopvolError, match="NanoVDB"):
        read_volume(p)
