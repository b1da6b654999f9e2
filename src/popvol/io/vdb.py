"""OpenVDB (.vdb) grids, read through Debian's ``pyopenvdb`` in Debian's own Python.

There is no OpenVDB wheel on PyPI. Debian's ``python3-openvdb`` (OpenVDB 10) is built against
Debian's NumPy 1.24 and cannot be imported beside NumPy 2 ("_ARRAY_API not found"), so popvol
runs a small script in Debian's interpreter (``/usr/bin/python3``, or ``$POPVOL_VDB_PYTHON``)
that reads the grid, densifies its active bounding box (active tiles included, half-float grids
decoded by OpenVDB itself) and hands back a dense float32 array with its transform through a
temporary .npz. Install with ``apt-get install python3-openvdb``.
"""
from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ..errors import PopvolError

_READER = r"""
import json, sys
import numpy as np
try:
    import pyopenvdb as vdb
except ImportError as e:
    print(json.dumps({"error": "import", "detail": str(e)})); sys.exit(0)
def detail(e):
    # a damaged file can make OpenVDB's message gigabytes of padding: its words at both ends
    text = str(e)
    return " ".join((text if len(text) < 20000 else text[:10000] + " ... " + text[-10000:]).split())[:300]
path, name, out, max_bytes = sys.argv[1:5]
try:
    grids = vdb.readAllGridMetadata(path)
except Exception as e:
    print(json.dumps({"error": "read", "detail": detail(e)})); sys.exit(0)
names = [g.name for g in grids]
if name == "":
    name = "density" if "density" in names else (names[0] if len(names) == 1 else "")
if name not in names:
    print(json.dumps({"error": "grid", "names": names})); sys.exit(0)
try:
    g = vdb.read(path, name)
except Exception as e:
    print(json.dumps({"error": "read", "detail": detail(e)})); sys.exit(0)
kind = type(g).__name__
if kind not in ("FloatGrid", "DoubleGrid"):
    print(json.dumps({"error": "type", "kind": kind, "name": name})); sys.exit(0)
lo, hi = g.evalActiveVoxelBoundingBox()
shape = tuple(int(h) - int(l) + 1 for l, h in zip(lo, hi))
if min(shape) < 1 or g.activeVoxelCount() == 0:
    print(json.dumps({"error": "empty", "name": name})); sys.exit(0)
count = shape[0] * shape[1] * shape[2]
if count * 4 > int(max_bytes):
    print(json.dumps({"error": "memory", "name": name, "shape": shape})); sys.exit(0)
xf = g.transform
o = np.array(xf.indexToWorld(tuple(lo)), float)
axes = np.array([np.array(xf.indexToWorld(tuple(l + (a == b) for a, l in enumerate(lo))), float) - o
                 for b in range(3)])
if not xf.isLinear or np.abs(axes - np.diag(np.diag(axes))).max() > 1e-9 * np.abs(axes).max():
    print(json.dumps({"error": "transform", "name": name})); sys.exit(0)
arr = np.zeros(shape, np.float32)
g.copyToArray(arr, ijk=tuple(lo))
np.savez(out, density=arr, voxel_size=np.diag(axes), world_of_ijk_min=o,
         ijk_min=np.array(lo), background=np.array(g.background, float))
print(json.dumps({"ok": True, "name": name, "names": names, "shape": shape}))
"""


def debian_python() -> str | None:
    """The interpreter that has pyopenvdb: $POPVOL_VDB_PYTHON or /usr/bin/python3 if present."""
    exe = os.environ.get("POPVOL_VDB_PYTHON") or "/usr/bin/python3"
    return exe if shutil.which(exe) else None


#: the file formats whose layout :func:`cut_short` knows (OpenVDB 2.2 to 11 write 220-224)
KNOWN_FILE_VERSIONS = range(220, 225)


def cut_short(path: Path) -> str | None:
    """Why the OpenVDB file at ``path`` is certainly cut short, or None (complete, or not a
    layout known here, so OpenVDB itself decides). Reads the header as OpenVDB writes it (io/
    Archive.cc: the magic number 0x56444220, the file version, the library's, whether grid offsets
    follow, a UUID, the file's metadata) and each grid's descriptor (name, type, parent, and the
    byte offsets of its start, its data and its end). A grid that ends beyond the last byte, or a
    header that does, is a truncated file. OpenVDB reads such a file for up to a minute and
    gigabytes of memory before it refuses it (a length read from the missing bytes)."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            data = f.read(1 << 20)
    except OSError:                             # unreadable: OpenVDB's reader says so
        return None
    pos = 0

    def take(n: int) -> bytes:
        nonlocal pos
        if n < 0 or pos + n > len(data):
            raise EOFError
        pos += n
        return data[pos - n:pos]

    def u32() -> int:
        return struct.unpack("<I", take(4))[0]

    def string() -> bytes:
        return take(u32())

    if len(data) < 8 or struct.unpack("<q", data[:8])[0] != 0x56444220:
        return None                             # not an OpenVDB file: OpenVDB says so
    pos = 8
    try:
        version = u32()
        if version not in KNOWN_FILE_VERSIONS:
            return None
        u32(), u32()                            # the library's major and minor version
        offsets = take(1)[0]
        take(36)                                # the UUID
        for _ in range(u32()):                  # the file's metadata: name, type, value
            string(), string(), take(u32())
        if not offsets:
            return None
        for _ in range(u32()):
            name = string().split(b"\x1e")[0].decode("utf-8", "replace")
            string(), string()                  # the grid's type and its instance parent
            start, block, end = struct.unpack("<qqq", take(24))
            if end > size:
                return f"grid {name!r} ends at byte {end:,} but the file has {size:,} bytes: it is truncated"
            if not pos < end <= size:              # a descriptor that points back: not a layout known here
                return None
            pos = end
    except EOFError:
        if len(data) == size:                   # the whole file read, and the header not ended
            return f"the file ends after {size:,} bytes, inside its header: it is truncated"
    return None


def reader_detail(text: str) -> str:
    """The OpenVDB reader's reason for refusing a file, for a one-line message: its words (at
    most 300 characters of them, from both ends of a long text), or a note that it gave none."""
    text = str(text)
    words = " ".join((text if len(text) < 20000 else text[:10000] + " ... " + text[-10000:]).split())[:300]
    return words or "OpenVDB gives no reason: is the file truncated or corrupt?"


def read_vdb(path, grid: str | None = None):
    """Dense grid ``grid`` (default ``density``, or the only grid) of an OpenVDB file.

    Returns (density float32 [x, y, z] over the active bounding box, voxel_size (3,), origin (3,)
    = world position of the centre of voxel (0, 0, 0), the grid's name).
    """
    path = Path(path)
    exe = debian_python()
    hint = "install OpenVDB's Python module with: apt-get install python3-openvdb"
    chosen = os.environ.get("POPVOL_VDB_PYTHON")
    if exe is None and chosen:
        raise PopvolError(f"{path}: POPVOL_VDB_PYTHON={chosen} is not a program that can be run; point it to a "
                          "python3 that has pyopenvdb, or unset it to use /usr/bin/python3")
    if exe is None:
        raise PopvolError(f"{path}: reading .vdb needs Debian's python3 with pyopenvdb; {hint} "
                          "(or set POPVOL_VDB_PYTHON to an interpreter that has it)")
    reader = f"POPVOL_VDB_PYTHON={exe}" if chosen else exe
    short = cut_short(path) if path.is_file() else None
    if short:
        raise PopvolError(f"{path}: not a readable OpenVDB file ({short})")
    from ..domains import available_memory
    from .volumes import BYTES_PER_READ_VOXEL
    # The dense float32 copy (4 bytes per voxel) exists in the reader and in this process, which
    # then checks it (BYTES_PER_READ_VOXEL more): refuse in the reader, before it allocates.
    bytes_per_voxel = 4 + 4 + BYTES_PER_READ_VOXEL
    max_bytes = int(0.8 * available_memory() * 4 / bytes_per_voxel)
    with tempfile.TemporaryDirectory(prefix="popvol-vdb-") as tmp:
        out = Path(tmp) / "grid.npz"
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
        try:
            proc = subprocess.run([exe, "-I", "-c", _READER, str(path), grid or "", str(out),
                                   str(max_bytes)],
                                  capture_output=True, text=True, env=env, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise PopvolError(f"{path}: the OpenVDB reader ({reader}) failed to run: {e}") from None
        lines = [l for l in proc.stdout.splitlines() if l.startswith("{")]
        if proc.returncode != 0 or not lines:
            last = (proc.stderr.strip().splitlines() or [""])[-1]
            detail = reader_detail(last) if last else ("unexpected output, not the reader's report" if proc.stdout.strip()
                                                      else "no output")
            raise PopvolError(f"{path}: the OpenVDB reader ({reader}) failed: {detail}")
        msg = json.loads(lines[-1])
        err = msg.get("error")
        if err == "import":
            raise PopvolError(f"{path}: {reader} has no pyopenvdb ({reader_detail(msg['detail'])}); {hint}")
        if err == "read":
            raise PopvolError(f"{path}: not a readable OpenVDB file ({reader_detail(msg['detail'])})")
        if err == "grid":
            if not msg["names"]:
                raise PopvolError(f"{path}: holds no grids (is it truncated, or not an OpenVDB file?)")
            names = ", ".join(repr(n) for n in msg["names"])
            wanted = f"no grid named {grid!r}" if grid else "several grids and none is named 'density'"
            raise PopvolError(f"{path}: {wanted}; grids in the file: {names} (choose one with medium.grid)")
        if err == "type":
            raise PopvolError(f"{path}: grid {msg['name']!r} is a {msg['kind']}; popvol reads scalar "
                              "float or double grids")
        if err == "empty":
            raise PopvolError(f"{path}: grid {msg['name']!r} has no active voxels")
        if err == "memory":
            from ..domains import check_memory
            shape = msg["shape"]
            count = int(np.prod(shape, dtype=np.int64))
            check_memory(count * bytes_per_voxel, f"{path}: grid {msg['name']!r}",
                         f"densifying its active bounding box of {'x'.join(map(str, shape))} voxels")
        if err == "transform":
            raise PopvolError(f"{path}: grid {msg['name']!r} has a rotated, sheared or non-linear "
                              "transform; popvol reads axis-aligned (scale + translate) grids")
        with np.load(out) as z:
            return (z["density"].copy(), z["voxel_size"].astype(np.float64),
                    z["world_of_ijk_min"].astype(np.float64), msg["name"])
