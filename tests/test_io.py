"""Volume and image IO (src/popvol/io) against independent oracles: the shared data's
reference_stats.json (computed with pyopenvdb from the original .vdb files), the Mitsuba .vol
byte layout built here with struct, the sRGB formula, and PIL/OpenEXR reading the written files.
"""
import gc
import hashlib
import json
import struct

import numpy as np
import pytest

from conftest import shared_file
from popvol.errors import PopvolError
from popvol.io import images
from popvol.io.volumes import VolumeData, read_npz, read_vol, read_volume, write_vol

NAMES = ("wdas_cloud_sixteenth", "smoke1", "vpt_dragon_fog")


def reference(name: str) -> dict:
    return json.loads(shared_file("reference_stats.json").read_text())["files"][f"vdb/{name}.vdb"]


@pytest.fixture(scope="module")
def loaded():
    """Each grid read once per module (npz and vol), keyed by (name, kind)."""
    cache = {}

    def get(name, kind):
        if (name, kind) not in cache:
            rel = f"npz/{name}_dense.npz" if kind == "npz" else f"vol/{name}.vol"
            cache[name, kind] = read_volume(shared_file(rel))
        return cache[name, kind]
    return get


# -- the shared data: npz ---------------------------------------------------------------------------

@pytest.mark.parametrize("rel", [f"npz/{n}_dense.npz" for n in NAMES] + [f"vol/{n}.vol" for n in NAMES])
def test_shared_file_is_the_referenced_one(rel):
    """sha256 from reference_stats.json: the data the other tests compare against is unchanged."""
    p = shared_file(rel)
    ref = json.loads(shared_file("reference_stats.json").read_text())["files"][rel]
    assert p.stat().st_size == ref["bytes"]
    assert hashlib.sha256(p.read_bytes()).hexdigest() == ref["sha256"]


@pytest.mark.parametrize("name", NAMES)
def test_npz_matches_reference_stats(name, loaded):
    ref = reference(name)
    vol = loaded(name, "npz")
    assert isinstance(vol, VolumeData)
    d = vol.density
    assert d.dtype == np.float32 and d.flags.c_contiguous
    assert list(d.shape) == ref["dense_shape_xyz"]
    assert list(d.shape) == [hi - lo + 1 for lo, hi in zip(ref["ijk_min"], ref["ijk_max"])]
    assert float(d.sum(dtype=np.float64)) == pytest.approx(ref["sum"], rel=1e-5)
    assert float(d.mean(dtype=np.float64)) == pytest.approx(ref["mean_over_bbox"], rel=1e-5)
    assert float(d.max()) == pytest.approx(ref["max"], rel=1e-7)
    assert float(d.min()) == ref["min"]
    assert int(np.count_nonzero(d)) == ref["nonzero_voxels"]
    lo = np.asarray(ref["ijk_min"])
    for s in ref["samples"]:
        idx = tuple(np.asarray(s["ijk"]) - lo)
        assert float(d[idx]) == pytest.approx(s["value"], rel=1e-7, abs=1e-12), s
    np.testing.assert_allclose(vol.voxel_size, ref["voxel_size"], rtol=1e-12)
    # origin = world position of the centre of array index (0, 0, 0) = voxel ijk_min
    np.testing.assert_allclose(vol.origin, ref["world_of_ijk_min"], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_npz_world_of_sample_voxels(name, loaded):
    """World position of a voxel = origin + index * voxel = ijk * voxel + translation, with the
    translation recovered from world_of_ijk_min (reference_stats' note: no rotation)."""
    ref = reference(name)
    vol = loaded(name, "npz")
    vs, lo = np.asarray(ref["voxel_size"]), np.asarray(ref["ijk_min"])
    translation = np.asarray(ref["world_of_ijk_min"]) - lo * vs
    for s in ref["samples"]:
        ijk = np.asarray(s["ijk"])
        np.testing.assert_allclose(vol.origin + (ijk - lo) * vol.voxel_size, ijk * vs + translation,
                                   rtol=1e-12, atol=1e-9)


# -- the shared data: vol ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_vol_equals_npz(name, loaded):
    ref = reference(name)
    a, b = loaded(name, "npz"), loaded(name, "vol")
    assert b.density.dtype == np.float32 and b.density.shape == a.density.shape
    np.testing.assert_array_equal(b.density, a.density)
    # the header bbox is float32: agreement to float32 rounding of the bbox coordinates
    p = shared_file(f"vol/{name}.vol")
    bbox = np.array(struct.unpack_from("<6f", p.read_bytes()[:48], 24), np.float64)
    tol = 4 * np.finfo(np.float32).eps * np.abs(bbox).max()
    np.testing.assert_allclose(b.voxel_size, ref["voxel_size"], rtol=0, atol=tol)
    np.testing.assert_allclose(b.origin, ref["world_of_ijk_min"], rtol=0, atol=tol)
    # the bbox is the AABB of the voxel CELLS: voxel 0's centre is half a voxel inside
    n = np.asarray(ref["dense_shape_xyz"])
    vs, c0 = np.asarray(ref["voxel_size"]), np.asarray(ref["world_of_ijk_min"])
    np.testing.assert_allclose(bbox[:3], c0 - vs / 2, rtol=0, atol=tol)
    np.testing.assert_allclose(bbox[3:], c0 + (n - 0.5) * vs, rtol=0, atol=tol)


@pytest.mark.parametrize("name", NAMES)
def test_vol_header_by_hand(name):
    """Independent reader: the README's numpy recipe gives the same array as read_vol."""
    p = shared_file(f"vol/{name}.vol")
    raw = p.read_bytes()
    assert raw[:3] == b"VOL" and raw[3] == 3
    enc, nx, ny, nz, ch = struct.unpack_from("<5i", raw, 4)
    assert (enc, ch) == (1, 1)
    arr = np.frombuffer(raw, "<f4", offset=48).reshape(nz, ny, nx, ch)[..., 0].transpose(2, 1, 0)
    np.testing.assert_array_equal(read_vol(p).density, arr)


# -- write_vol / read_vol on small arrays ----------------------------------------------------------

def expected_vol_bytes(d, lo, hi):
    """The .vol spec, byte by byte: 'VOL', 3, int32 encoding 1, xres, yres, zres, channels 1,
    6 float32 bbox, then float32 values with x fastest, then y, then z."""
    nx, ny, nz = d.shape
    out = bytearray(b"VOL")
    out += bytes([3])
    out += struct.pack("<i", 1)
    out += struct.pack("<iii", nx, ny, nz)
    out += struct.pack("<i", 1)
    out += struct.pack("<3f", *lo) + struct.pack("<3f", *hi)
    assert len(out) == 48
    for z in range(nz):
        for y in range(ny):
            for x in range(nx):
                out += struct.pack("<f", float(d[x, y, z]))
    return bytes(out)


def test_write_vol_byte_layout_and_round_trip(tmp_path, rng):
    d = rng.random((3, 4, 5)).astype(np.float32) * 7
    d[0, 0, 0] = 0.0
    lo, hi = (-1.5, 0.25, 2.0), (1.5, 2.25, 4.5)
    p = tmp_path / "small.vol"
    write_vol(p, d, lo, hi)
    raw = p.read_bytes()
    assert len(raw) == 48 + 4 * d.size
    assert raw == expected_vol_bytes(d, lo, hi)
    v = read_vol(p)
    np.testing.assert_array_equal(v.density, d)
    voxel = (np.array(hi) - np.array(lo)) / np.array(d.shape)
    np.testing.assert_allclose(v.voxel_size, voxel, rtol=1e-7)
    np.testing.assert_allclose(v.origin, np.array(lo) + voxel / 2, rtol=1e-7, atol=1e-7)
    assert v.source == str(p)
    # read_volume picks the same reader by suffix, case-insensitively
    p2 = tmp_path / "SMALL.VOL"
    p2.write_bytes(raw)
    np.testing.assert_array_equal(read_volume(p2).density, d)


def test_read_vol_of_hand_built_file(tmp_path, rng):
    """A file built with struct (not write_vol) is read as x-fastest data."""
    d = rng.random((2, 3, 4)).astype(np.float32)
    p = tmp_path / "hand.vol"
    p.write_bytes(expected_vol_bytes(d, (0, 0, 0), (2, 3, 4)))
    v = read_vol(p)
    np.testing.assert_array_equal(v.density, d)
    np.testing.assert_allclose(v.voxel_size, 1.0)
    np.testing.assert_allclose(v.origin, 0.5)


def test_write_vol_single_voxel_and_anisotropic(tmp_path):
    p = tmp_path / "one.vol"
    write_vol(p, np.full((1, 1, 1), 2.5, np.float32), (0, 0, 0), (1, 2, 4))
    v = read_vol(p)
    assert v.density.shape == (1, 1, 1) and v.density[0, 0, 0] == 2.5
    np.testing.assert_allclose(v.voxel_size, [1, 2, 4])
    np.testing.assert_allclose(v.origin, [0.5, 1, 2])


def test_npz_defaults_and_scalar_voxel(tmp_path, rng):
    d = rng.random((4, 3, 2)).astype(np.float32)
    p = tmp_path / "plain.npz"
    np.savez(p, density=d)
    v = read_npz(p)
    np.testing.assert_array_equal(v.density, d)
    np.testing.assert_array_equal(v.voxel_size, [1, 1, 1])
    np.testing.assert_array_equal(v.origin, [0, 0, 0])
    p2 = tmp_path / "scalar.npz"
    np.savez(p2, sigma=d.astype(np.float64), voxel_size=np.float64(0.25), world_of_ijk_min=[1.0, 2.0, 3.0])
    v2 = read_volume(p2, "sigma")
    assert v2.density.dtype == np.float32
    np.testing.assert_array_equal(v2.density, d)
    np.testing.assert_array_equal(v2.voxel_size, [0.25] * 3)
    np.testing.assert_array_equal(v2.origin, [1, 2, 3])


def test_npz_origin_is_the_centre_of_the_first_voxel(tmp_path):
    """An .npz may name the centre of voxel (0, 0, 0) ``origin`` (the scene's word) as well as
    ``world_of_ijk_min``; with both, where they agree, the medium lies where either says."""
    d = np.ones((2, 3, 4), np.float32)
    for i, extra in enumerate(({"origin": [1.0, -2.0, 3.0]},
                               {"origin": [1.0, -2.0, 3.0], "world_of_ijk_min": [1.0, -2.0, 3.0]})):
        p = tmp_path / f"o{i}.npz"
        np.savez(p, density=d, voxel_size=0.5, **extra)
        v = read_volume(p)
        np.testing.assert_array_equal(v.origin, [1.0, -2.0, 3.0])


# -- bad input: one PopvolError naming the file ------------------------------------------------------

def _raises_naming(path, fn, *args, match=None):
    with pytest.raises(PopvolError, match=match) as e:
        fn(*args)
    assert str(path) in str(e.value), str(e.value)
    assert "\n" not in str(e.value)
    return str(e.value)


def _valid_vol(tmp_path, name="v.vol", shape=(2, 3, 4)):
    p = tmp_path / name
    write_vol(p, np.ones(shape, np.float32), (0, 0, 0), (1, 1, 1))
    return p


def test_truncated_vol(tmp_path):
    p = _valid_vol(tmp_path)
    p.write_bytes(p.read_bytes()[:-4])
    _raises_naming(p, read_volume, p, match="bytes")
    p.write_bytes(p.read_bytes()[:20])          # not even a whole header
    _raises_naming(p, read_volume, p)
    p.write_bytes(b"")
    _raises_naming(p, read_volume, p)


def test_vol_with_trailing_bytes(tmp_path):
    p = _valid_vol(tmp_path)
    p.write_bytes(p.read_bytes() + b"\0\0\0\0")
    _raises_naming(p, read_volume, p, match="bytes")


@pytest.mark.parametrize("offset,value,what", [
    (0, b"XOL", "magic"), (0, b"vol", "magic (case)"), (3, bytes([2]), "version 2"),
    (3, bytes([4]), "version 4"),
    (4, struct.pack("<i", 2), "encoding 2"), (20, struct.pack("<i", 3), "3 channels"),
    (8, struct.pack("<i", 0), "xres 0"), (12, struct.pack("<i", -1), "yres -1"),
    (24, struct.pack("<f", 5.0), "bbox min > max"), (36, struct.pack("<f", float("nan")), "NaN bbox"),
])
def test_bad_vol_header(tmp_path, offset, value, what):
    p = _valid_vol(tmp_path)
    raw = bytearray(p.read_bytes())
    raw[offset:offset + len(value)] = value
    p.write_bytes(bytes(raw))
    _raises_naming(p, read_volume, p)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -0.5])
def test_vol_with_bad_density(tmp_path, bad):
    d = np.ones((3, 2, 2), np.float32)
    d[2, 1, 0] = bad
    p = tmp_path / "bad.vol"
    write_vol(p, d, (0, 0, 0), (1, 1, 1))
    msg = _raises_naming(p, read_volume, p)
    assert "(2, 1, 0)" in msg            # the first bad voxel, in x, y, z order


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1e-3])
def test_npz_with_bad_density(tmp_path, bad):
    d = np.ones((3, 2, 2), np.float32)
    d[1, 0, 1] = bad
    p = tmp_path / "bad.npz"
    np.savez(p, density=d)
    msg = _raises_naming(p, read_volume, p)
    assert "(1, 0, 1)" in msg


@pytest.mark.parametrize("arr", [np.ones((4, 4), np.float32), np.ones((2, 2, 2, 2), np.float32),
                                 np.ones((0, 2, 2), np.float32), np.ones((2, 2, 2), bool),
                                 np.ones((2, 2, 2), complex), np.array(["a", "b"]).reshape(1, 1, 2)])
def test_npz_with_bad_array(tmp_path, arr):
    p = tmp_path / "bad.npz"
    np.savez(p, density=arr)
    _raises_naming(p, read_volume, p)


@pytest.mark.parametrize("extra", [{"voxel_size": [0.0, 1.0, 1.0]}, {"voxel_size": [-1.0]},
                                   {"voxel_size": [1.0, 2.0]}, {"voxel_size": [np.nan] * 3},
                                   {"world_of_ijk_min": [0.0, np.inf, 0.0]}, {"origin": [1.0, 2.0]},
                                   {"origin": [0.0, 0.0, 1.0], "world_of_ijk_min": [0.0, 0.0, 2.0]}])
def test_npz_with_bad_geometry(tmp_path, extra):
    p = tmp_path / "geom.npz"
    np.savez(p, density=np.ones((2, 2, 2), np.float32), **extra)
    _raises_naming(p, read_volume, p)


def test_npz_missing_array_name(tmp_path):
    p = tmp_path / "named.npz"
    np.savez(p, density=np.ones((2, 2, 2), np.float32), other=np.ones(3))
    msg = _raises_naming(p, read_volume, p, "temperature")
    assert "density" in msg and "other" in msg       # lists the arrays that are there
    q = tmp_path / "nodensity.npz"
    np.savez(q, sigma=np.ones((2, 2, 2), np.float32))
    _raises_naming(q, read_volume, q)


def test_npz_object_array_is_refused_without_pickle(tmp_path):
    p = tmp_path / "obj.npz"
    np.savez(p, density=np.array([{"a": 1}, None], dtype=object))
    _raises_naming(p, read_volume, p)


def test_npy_content_with_npz_suffix(tmp_path):
    np.save(tmp_path / "a.npy", np.ones((2, 2, 2), np.float32))
    p = tmp_path / "a.npz"
    (tmp_path / "a.npy").rename(p)
    _raises_naming(p, read_volume, p)


def test_empty_npz_file(tmp_path):
    p = tmp_path / "empty.npz"
    p.write_bytes(b"")
    _raises_naming(p, read_volume, p)


def test_npz_with_non_numeric_voxel_size(tmp_path):
    p = tmp_path / "str.npz"
    np.savez(p, density=np.ones((2, 2, 2), np.float32), voxel_size=np.array(["a"]))
    _raises_naming(p, read_volume, p)


def test_npz_bad_voxel_size_message_is_one_line(tmp_path):
    p = tmp_path / "vs.npz"
    np.savez(p, density=np.ones((2, 2, 2), np.float32), voxel_size=np.ones((3, 3)))
    _raises_naming(p, read_volume, p)


# np.load leaves its own file handle open when zipfile rejects a truncated archive (numpy, not
# popvol); collect it here so the ResourceWarning does not surface in a later test under -W error
@pytest.mark.filterwarnings("ignore::ResourceWarning")
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_corrupt_npz(tmp_path, rng):
    p = tmp_path / "corrupt.npz"
    p.write_bytes(b"this is not a zip archive")
    _raises_naming(p, read_volume, p)
    good = tmp_path / "good.npz"
    np.savez_compressed(good, density=rng.random((20, 20, 20)).astype(np.float32))
    raw = good.read_bytes()
    p.write_bytes(raw[: len(raw) // 2])                          # truncated archive
    _raises_naming(p, read_volume, p)
    gc.collect()
    flipped = bytearray(raw)
    flipped[len(raw) // 2] ^= 0xFF                               # corrupted member (CRC)
    p.write_bytes(bytes(flipped))
    _raises_naming(p, read_volume, p)


def test_unknown_suffix_missing_file_and_folder(tmp_path):
    p = tmp_path / "cloud.raw"
    p.write_bytes(b"\0" * 64)
    _raises_naming(p, read_volume, p, match="unsupported")
    p = tmp_path / "noext"
    p.write_bytes(b"\0" * 64)
    _raises_naming(p, read_volume, p)
    missing = tmp_path / "missing.npz"
    _raises_naming(missing, read_volume, missing, match="not found")
    _raises_naming(tmp_path / "missing.vol", read_vol, tmp_path / "missing.vol")
    _raises_naming(tmp_path / "missing2.npz", read_npz, tmp_path / "missing2.npz")
    folder = tmp_path / "folder.npz"
    folder.mkdir()
    _raises_naming(folder, read_volume, folder)


def test_vol_with_grid_name(tmp_path):
    p = _valid_vol(tmp_path)
    _raises_naming(p, read_volume, p, "temperature")
    assert read_volume(p, "density").density.shape == (2, 3, 4)


def test_broken_vdb_and_nvdb_are_refused_with_a_clear_message(tmp_path):
    fake = tmp_path / "cloud.vdb"
    fake.write_bytes(b"\0" * 16)
    msg = _raises_naming(fake, read_volume, fake)   # unreadable, or no reader installed
    assert "OpenVDB" in msg or "openvdb" in msg
    fake = tmp_path / "cloud.nvdb"
    fake.write_bytes(b"\0" * 16)
    assert "NanoVDB" in _raises_naming(fake, read_volume, fake)


def test_write_vol_to_missing_folder(tmp_path):
    p = tmp_path / "no" / "such" / "x.vol"
    _raises_naming(p, write_vol, p, np.ones((1, 1, 1)), (0, 0, 0), (1, 1, 1))


# -- images -----------------------------------------------------------------------------------------

def srgb_encode(x):
    """IEC 61966-2-1, written out here."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.abs(x) ** (1 / 2.4) - 0.055)


def test_exr_round_trip_keeps_hdr_float32(tmp_path, rng):
    img = (rng.random((7, 11, 3)) ** 3 * 50).astype(np.float32)
    img[0, 0] = (0.0, 1e3, 65504.0)            # over the display range, the half maximum
    img[1, 2] = (3.1e5, 1e-7, 0.1)             # beyond half precision/range: float32 must keep it
    p = tmp_path / "hdr.exr"
    images.write_exr(p, img)
    back = images.read_exr(p)
    assert back.dtype == np.float32 and back.shape == img.shape
    np.testing.assert_array_equal(back, img)


def test_exr_is_readable_by_openexr_as_float_channels(tmp_path):
    import OpenEXR
    img = np.zeros((4, 5, 3), np.float32)
    img[..., 0], img[..., 1], img[..., 2] = 1.0, 2.0, 1234.5
    p = tmp_path / "c.exr"
    images.write_exr(p, img)
    with OpenEXR.File(str(p), separate_channels=True) as f:
        ch = f.channels()
        assert {"R", "G", "B"} <= set(ch)
        for i, c in enumerate("RGB"):
            assert ch[c].pixels.dtype == np.float32
            np.testing.assert_array_equal(ch[c].pixels, img[..., i])


def test_read_exr_errors(tmp_path):
    import OpenEXR
    missing = tmp_path / "none.exr"
    _raises_naming(missing, images.read_exr, missing)
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr")
    _raises_naming(junk, images.read_exr, junk)
    grey = tmp_path / "grey.exr"
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"Y": np.ones((3, 3), np.float32)}) as f:
        f.write(str(grey))
    _raises_naming(grey, images.read_exr, grey)


def test_png_is_8bit_srgb(tmp_path):
    from PIL import Image
    h, w = 5, 8
    lin = np.linspace(0, 1.5, h * w * 3).reshape(h, w, 3).astype(np.float32)
    p = tmp_path / "a.png"
    images.write_png(p, lin, exposure=0.0, tone="clip")
    im = Image.open(p)
    assert im.mode == "RGB" and im.size == (w, h)
    px = np.asarray(im)
    assert px.shape == (h, w, 3) and px.dtype == np.uint8
    expected = np.round(np.clip(srgb_encode(np.clip(lin, 0, 1)), 0, 1) * 255)
    np.testing.assert_array_equal(px, expected.astype(np.uint8))
    # exposure +1 stop = doubling the linear values
    images.write_png(p, lin, exposure=1.0, tone="clip")
    expected = np.round(np.clip(srgb_encode(np.clip(2 * lin.astype(np.float64), 0, 1)), 0, 1) * 255)
    np.testing.assert_array_equal(np.asarray(Image.open(p)), expected.astype(np.uint8))


def test_tonemap_zero_monotone_and_known_points():
    x = np.linspace(0, 4, 4001).reshape(-1, 1, 1) * np.ones((1, 1, 3))
    t = images.tonemap(x, 0.0, "clip")
    assert t.dtype == np.uint8
    assert np.all(t[0] == 0)
    assert np.all(np.diff(t[:, 0, 0].astype(int)) >= 0)
    assert np.all(t[x[:, 0, 0] >= 1] == 255)
    # known sRGB values: 18 % grey -> 117.9 -> 118, 0.5 -> 187.5 -> 188, 0.0031308 -> 10.3 -> 10
    pts = np.array([0.18, 0.5, 0.0031308, 0.001]).reshape(1, -1, 1) * np.ones((1, 1, 3))
    assert images.tonemap(pts, 0.0, "clip")[0, :, 0].tolist() == [118, 188, 10, 3]
    # exposure shifts by whole stops
    np.testing.assert_array_equal(images.tonemap(x / 4, exposure=2.0, tone="clip"), images.tonemap(x, 0.0, "clip"))
    np.testing.assert_allclose(images.linear_to_srgb([0.0, 1.0]), [0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("bad", ["shape", "nan", "negative"])
def test_image_writers_refuse_bad_pixels(tmp_path, bad):
    img = np.ones((3, 4, 3), np.float32)
    if bad == "shape":
        img = np.ones((3, 4), np.float32)
    elif bad == "nan":
        img[1, 1, 1] = np.nan
    else:
        img[0, 0, 0] = -1
    for name, fn in (("x.png", images.write_png), ("x.exr", images.write_exr)):
        p = tmp_path / name
        _raises_naming(p, fn, p, img)
        assert not p.exists()


def test_write_image_by_suffix(tmp_path):
    img = np.full((2, 3, 3), 0.25, np.float32)
    images.write_image(tmp_path / "a.png", img)
    images.write_image(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(images.read_exr(tmp_path / "a.exr"), img)
    p = tmp_path / "a.jpg"
    _raises_naming(p, images.write_image, p, img)
    p = tmp_path / "missing_dir" / "a.png"
    _raises_naming(p, images.write_image, p, img)
