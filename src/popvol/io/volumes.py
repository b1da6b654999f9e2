"""Volume readers: dense NumPy .npz and Mitsuba .vol grids here; OpenVDB .vdb through io/vdb.py.

Convention (OpenVDB style): ``density[i, j, k]`` is indexed x, y, z and the centre of voxel
(i, j, k) is at ``origin + (i, j, k) * voxel_size``; the medium is the union of the voxel
cells, [origin - voxel/2, origin + (n - 1/2) voxel].
"""
from __future__ import annotations

import contextlib
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import check
from ..errors import PopvolError
from .files import why_missing

SUFFIXES = (".npz", ".vol", ".vdb")
VOL_HEADER_BYTES = 48


@dataclass(frozen=True)
class VolumeData:
    density: np.ndarray      # float32 (nx, ny, nz), finite, >= 0
    voxel_size: np.ndarray   # float64 (3,), world units
    origin: np.ndarray       # float64 (3,), world position of the centre of voxel (0, 0, 0)
    source: str


def validate_density(density, source: str, field: str = "density", signed: bool = False) -> np.ndarray:
    """The density checks every reader shares; returns float32, C-contiguous. ``signed`` grids
    (e.g. a per-voxel g) may be negative."""
    from ..medium import check_float32_range
    d = np.asarray(density)
    if d.ndim != 3 or min(d.shape) < 1:
        raise PopvolError(f"{source}: {field} must be a 3-D array with every size >= 1, got shape {d.shape}")
    if not (np.issubdtype(d.dtype, np.floating) or np.issubdtype(d.dtype, np.integer)):
        raise PopvolError(f"{source}: {field} has dtype {d.dtype}; it must be numeric")
    if np.issubdtype(d.dtype, np.floating):
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(d)
        if bad.any():
            first = tuple(int(v) for v in np.argwhere(bad)[0])
            raise PopvolError(f"{source}: {field} has {int(bad.sum())} NaN/inf voxels (first at {first}); it must be finite")
        check_float32_range(d, source, field)
    d = np.ascontiguousarray(d, np.float32)
    bad = ~np.isfinite(d)
    if bad.any():
        first = tuple(int(v) for v in np.argwhere(bad)[0])
        raise PopvolError(f"{source}: {field} has {int(bad.sum())} NaN/inf voxels (first at {first}); it must be finite")
    if not signed and d.min() < 0:
        at = tuple(int(v) for v in np.unravel_index(int(np.argmin(d)), d.shape))
        raise PopvolError(f"{source}: {field} has negative values (min {float(d.min()):g} at {at}); it must be >= 0")
    return d


def _vec3(value, source: str, field: str, default: float) -> np.ndarray:
    """float64 (3,) from a file's 1 or 3 numbers (``default`` where the file has none)."""
    if value is None:
        return np.full(3, default, np.float64)
    if isinstance(value, np.ndarray):
        value = np.repeat(value.ravel(), 3) if value.size == 1 else value.ravel()
    return check.vector(value, field, source)


def read_npz(path, grid: str | None = None, signed: bool = False, where: str = "") -> VolumeData:
    """Dense grid from .npz: array ``grid`` (default ``density``), optional ``voxel_size``
    (1 or 3 values) and ``world_of_ijk_min`` or ``origin`` (centre of voxel (0, 0, 0), the
    scene's ``[medium] origin``; both only where they agree); defaults 1 and 0. ``where``: what
    asked for the grid ("scene.toml: medium.g: "), put before a missing array's message."""
    path = Path(path)
    key = grid or "density"
    with _npz_member(path, key, where) as z:
        density = z[key]
        voxel = z["voxel_size"] if "voxel_size" in z.files else None
        centres = {k: _vec3(z[k], str(path), k, 0.0) for k in ("world_of_ijk_min", "origin") if k in z.files}
    if len(centres) == 2 and not np.allclose(*centres.values(), rtol=1e-6, atol=0.0):
        a, b = (v.tolist() for v in centres.values())
        raise PopvolError(f"{path}: world_of_ijk_min = {a} and origin = {b} disagree; keep one "
                          "(the centre of voxel (0, 0, 0))")
    voxel = _vec3(voxel, str(path), "voxel_size", 1.0)
    if np.any(voxel <= 0):
        raise PopvolError(f"{path}: voxel_size = {voxel.tolist()} must be > 0")
    origin = next(iter(centres.values()), np.zeros(3))
    return VolumeData(validate_density(density, str(path), key, signed), voxel, origin, str(path))


#: Bytes per voxel of a grid while it is read and checked: the file's array, its float32 copy
#: and the masks of the checks (beside the array's own itemsize).
BYTES_PER_READ_VOXEL = 4 + 2


def _names(names, most: int = 12, width: int = 40) -> str:
    """An archive's array names for a one-line message: at most ``most``, each cut to ``width``
    characters, and how many more there are."""
    shown = [repr(n if len(n) <= width else n[:width] + "...") for n in names[:most]]
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return (", ".join(shown) + more) or "(none)"


@contextlib.contextmanager
def _npz_member(path: Path, key: str, where: str = ""):
    """The open archive of .npz ``path`` once array ``key``'s header is checked
    (:func:`_check_npz_member`); what the archive or NumPy rejects becomes a one-line PopvolError
    naming the file."""
    try:
        # open the file ourselves: np.load leaks its handle when it rejects a file
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
            if key not in z.files:
                raise PopvolError(f"{where}{path}: no array named {check._show(key)}; arrays in the file: "
                                  f"{_names(z.files)}")
            _check_npz_member(z, key, path)
            yield z
    except PopvolError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as e:
        if "pickled" in str(e):             # NumPy's word for anything that is neither zip nor .npy
            raise PopvolError(f"{path}: is not an .npz archive (NumPy's zip of arrays, numpy.savez)") from None
        raise PopvolError(f"{path}: cannot read as .npz ({e})") from None
    except (TypeError, AttributeError):     # np.load gave a plain array: .npy content
        raise PopvolError(f"{path}: holds a single .npy array, not an .npz archive; save it with "
                          f"numpy.savez(path, density=array)") from None


def _check_npz_member(z, key: str, path: Path) -> None:
    """Before reading array ``key`` of an open .npz: its header must be an array's, describe no
    more data than the archive holds, and fit in memory (a forged header can declare 10^15
    voxels in a few bytes)."""
    from ..domains import check_memory
    name = key if key in z.zip.namelist() else key + ".npy"
    info = z.zip.getinfo(name)
    with z.zip.open(name) as member:
        version = np.lib.format.read_magic(member)
        read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                else np.lib.format.read_array_header_2_0)
        shape, _, dtype = read(member)
    if dtype.hasobject or dtype.itemsize == 0:
        raise PopvolError(f"{path}: array {key!r} has dtype {dtype}; it must be numeric")
    count = 1
    for n in shape:
        count *= int(n)
    if count * dtype.itemsize > info.file_size:
        raise PopvolError(f"{path}: array {key!r} declares shape {tuple(shape)} ({count * dtype.itemsize} bytes) "
                          f"but the archive holds {info.file_size} bytes for it; the file is corrupt")
    check_memory(count * (dtype.itemsize + BYTES_PER_READ_VOXEL), f"{path}: array {key!r}",
                 f"reading {'x'.join(map(str, shape))} voxels")


def read_vol(path, signed: bool = False) -> VolumeData:
    """Mitsuba grid volume (.vol): 'VOL', version 3, int32 encoding (1 = float32), int32
    xres, yres, zres, channels, 6 float32 bbox (the world AABB of the voxel cells), then
    float32 data with x fastest."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise PopvolError(f"{path}: cannot read ({e.strerror})") from None
    nx, ny, nz, lo, hi = _vol_header(raw[:VOL_HEADER_BYTES], len(raw), path)
    data = np.frombuffer(raw, "<f4", offset=VOL_HEADER_BYTES).reshape(nz, ny, nx)
    density = validate_density(data.transpose(2, 1, 0), str(path), "density", signed)
    voxel = (hi - lo) / np.array([nx, ny, nz])
    return VolumeData(density, voxel, lo + voxel / 2, str(path))


def _vol_header(head: bytes, size: int, path: Path) -> tuple[int, int, int, np.ndarray, np.ndarray]:
    """(nx, ny, nz, bbox min, bbox max) of a .vol file from its first VOL_HEADER_BYTES bytes
    ``head`` and its size in bytes; a one-line PopvolError where either is not what popvol reads."""
    if len(head) < VOL_HEADER_BYTES or head[:3] != b"VOL":
        raise PopvolError(f"{path}: not a Mitsuba .vol file (header must start with 'VOL')")
    if head[3] != 3:
        raise PopvolError(f"{path}: .vol version {head[3]}; popvol reads version 3")
    encoding, nx, ny, nz, channels = struct.unpack_from("<5i", head, 4)
    bbox = np.array(struct.unpack_from("<6f", head, 24), np.float64)
    if encoding != 1:
        raise PopvolError(f"{path}: .vol encoding {encoding}; popvol reads encoding 1 (float32)")
    if channels != 1:
        raise PopvolError(f"{path}: header says {channels} channels; popvol reads 1-channel density grids")
    if min(nx, ny, nz) < 1:
        raise PopvolError(f"{path}: .vol resolution {nx}x{ny}x{nz} must be >= 1 along every axis")
    expected = VOL_HEADER_BYTES + 4 * nx * ny * nz
    if size != expected:
        raise PopvolError(f"{path}: file has {size} bytes but its {nx}x{ny}x{nz} header needs {expected}")
    lo, hi = bbox[:3], bbox[3:]
    if not np.all(np.isfinite(bbox)) or np.any(hi <= lo):
        raise PopvolError(f"{path}: .vol bbox {bbox.tolist()} must have max > min on every axis")
    return nx, ny, nz, lo, hi


#: the first bytes of an OpenVDB file (its magic number, int32 0x56444220, little-endian)
VDB_MAGIC = b" BDV"


def check_volume_header(path, grid: str | None = None) -> None:
    """A one-line PopvolError unless ``path`` looks readable by :func:`read_volume`, from its
    headers alone (cheap enough for every frame of a sequence before the first renders): a
    .npz's archive directory and the header of array ``grid``; a .vol's header and size; a
    .vdb's magic number (its grids are only read with the frame). Unknown types and .nvdb are
    refused as read_volume refuses them."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".vol", ".vdb"):
        read_volume(path, grid)                 # raises, naming what popvol reads
    if suffix == ".npz":
        with _npz_member(path, grid or "density"):
            return
    try:
        with open(path, "rb") as f:
            if suffix == ".vol":
                _vol_header(f.read(VOL_HEADER_BYTES), path.stat().st_size, path)
            elif f.read(4) != VDB_MAGIC:
                raise PopvolError(f"{path}: not an OpenVDB file (no VDB magic number at its start)")
    except OSError as e:
        raise PopvolError(f"{path}: cannot read ({e.strerror or e})") from None


def write_vol(path, density, bbox_min, bbox_max) -> None:
    """Write a 1-channel float32 Mitsuba .vol; ``density`` (nx, ny, nz) indexed x, y, z."""
    d = np.asarray(density, np.float32)
    nx, ny, nz = d.shape
    header = b"VOL" + bytes([3]) + struct.pack("<5i", 1, nx, ny, nz, 1)
    header += struct.pack("<6f", *np.asarray(bbox_min, float), *np.asarray(bbox_max, float))
    try:
        Path(path).write_bytes(header + np.ascontiguousarray(d.transpose(2, 1, 0), "<f4").tobytes())
    except OSError as e:
        raise PopvolError(f"{path}: cannot write ({e.strerror})") from None


def read_volume(path, grid: str | None = None, signed: bool = False, field: str | None = None) -> VolumeData:
    """Read a grid, choosing the reader by suffix (.npz, .vol, .vdb). Densities must be >= 0;
    ``signed`` grids (a per-voxel g) may be negative. ``field``: where the path came from (e.g.
    ``"scene.toml: medium.file"``), named where the path is not a file or has no such array."""
    path = Path(path)
    where = f"{field}: " if field else ""
    if not path.exists():
        raise PopvolError(f"{where}volume file {path} {why_missing(path)}")
    if not path.is_file():
        raise PopvolError(f"{where}{path} is {'a folder' if path.is_dir() else 'not a file'}; it must name a volume "
                          f"file ({', '.join(SUFFIXES)})")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return read_npz(path, grid, signed, where)
    if suffix == ".vol":
        if grid not in (None, "density"):
            raise PopvolError(f"{path}: .vol files hold one unnamed grid; remove medium.grid = {grid!r}")
        return read_vol(path, signed)
    if suffix == ".vdb":
        from .vdb import read_vdb
        density, voxel, origin, _ = read_vdb(path, grid)
        return VolumeData(validate_density(density, str(path), grid or "density", signed), voxel, origin,
                          str(path))
    if suffix == ".nvdb":
        raise PopvolError(f"{path}: NanoVDB is not read (no light, maintained reader on PyPI); read the "
                          "OpenVDB .vdb it came from, or convert it to .npz (e.g. warp-lang: "
                          "wp.Volume.load_from_nvdb(f).array().numpy())")
    raise PopvolError(f"{path}: unsupported volume type {suffix or '(none)'}; supported: {', '.join(SUFFIXES)}")
