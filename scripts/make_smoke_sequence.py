"""Write a short animated smoke sequence (smoke_0001.npz, smoke_0002.npz, ...) from the OpenVDB
smoke1 plume in ../shared/data/volumes, for examples/smoke_sequence.toml and the tests:

    python scripts/make_smoke_sequence.py [OUT_DIR] [--frames 24] [--downsample 2]

There is no animated volume in the shared data, so the still plume is moved: frame i of N
(t = (i - 1) / (N - 1) from 0 to 1) is the plume advected upward by ``rise`` x t of its height,
spreading sideways by a factor 1 + ``grow`` x t and stretched upward by 1 + ``grow`` x t / 2
about the centre of its base, twisted about the vertical axis by up to ``twist`` x t degrees at
its top, and diluted so that its mass stays the same. Each frame is trilinear resampling of
the still plume (block-averaged by ``downsample`` first) on one padded grid, the same shape,
voxel size and origin for every frame (OUT_DIR defaults to build/smoke_seq/). Files are
written atomically; the same arguments give the same files.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO.parent / "shared" / "data" / "volumes" / "npz" / "smoke1_dense.npz"


def block_mean(d: np.ndarray, k: int) -> np.ndarray:
    """``d`` averaged over k^3 blocks (the trailing partial blocks dropped)."""
    if k == 1:
        return d
    n = [s // k * k for s in d.shape]
    d = d[:n[0], :n[1], :n[2]]
    return d.reshape(n[0] // k, k, n[1] // k, k, n[2] // k, k).mean(axis=(1, 3, 5), dtype=np.float64).astype(np.float32)


def trilinear(d: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``d`` at the (fractional) voxel indices x, y, z, trilinear; 0 outside the grid."""
    out = np.zeros(x.shape, np.float32)
    pts = np.stack([x, y, z])
    i0 = np.floor(pts).astype(np.int64)
    f = (pts - i0).astype(np.float32)
    for corner in range(8):
        o = [(corner >> a) & 1 for a in range(3)]
        idx = [i0[a] + o[a] for a in range(3)]
        w = np.ones(x.shape, np.float32)
        ok = np.ones(x.shape, bool)
        for a in range(3):
            w *= f[a] if o[a] else 1 - f[a]
            ok &= (idx[a] >= 0) & (idx[a] < d.shape[a])
        vals = d[tuple(np.where(ok, idx[a], 0) for a in range(3))]
        out += np.where(ok, w * vals, 0)
    return out


def frames(source: Path = SOURCE, n: int = 24, downsample: int = 2, rise: float = 0.15, grow: float = 0.3,
           twist: float = 25.0):
    """Yield (i, density, voxel_size, world_of_ijk_min) for frames i = 1..n."""
    z = np.load(source)
    d = block_mean(np.asarray(z["density"], np.float32), downsample)
    voxel = np.asarray(z["voxel_size"], np.float64) * downsample
    origin = np.asarray(z["world_of_ijk_min"], np.float64) + 0.5 * (downsample - 1) * np.asarray(z["voxel_size"])
    nx, ny, nz = d.shape
    # room to rise, spread and stretch: padded above by rise + grow / 2 and sideways by grow / 2
    pad_side = [int(np.ceil(s * grow / 2)) + 1 for s in (nx, nz)]
    pad_top = int(np.ceil(ny * (rise + grow / 2))) + 1
    shape = (nx + 2 * pad_side[0], ny + pad_top, nz + 2 * pad_side[1])
    out_origin = origin - voxel * np.array([pad_side[0], 0, pad_side[1]])
    # the base centre, in the still plume's voxel indices
    mass_xz = d.sum(axis=1)
    cx = float((mass_xz.sum(axis=1) * np.arange(nx)).sum() / mass_xz.sum())
    cz = float((mass_xz.sum(axis=0) * np.arange(nz)).sum() / mass_xz.sum())
    X, Y, Z = np.meshgrid(np.arange(shape[0]) - pad_side[0], np.arange(shape[1]),
                          np.arange(shape[2]) - pad_side[1], indexing="ij")
    X, Y, Z = X.astype(np.float32) - cx, Y.astype(np.float32), Z.astype(np.float32) - cz
    for i in range(1, n + 1):
        t = (i - 1) / (n - 1) if n > 1 else 0.0
        sx, sy = 1 + grow * t, 1 + 0.5 * grow * t
        y = (Y - rise * t * ny) / sy
        angle = np.radians(twist * t) * np.clip(y / ny, 0, 1)
        c, s = np.cos(angle), np.sin(angle)
        x = (c * X + s * Z) / sx
        zz = (-s * X + c * Z) / sx
        rho = trilinear(d, x + cx, y, zz + cz) / (sx * sx * sy)
        rho[np.asarray(y < -0.5)] = 0.0          # nothing below the plume's base
        yield i, np.ascontiguousarray(rho, np.float32), voxel, out_origin


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", nargs="?", default=str(REPO / "build" / "smoke_seq"), help="folder (made if missing)")
    ap.add_argument("--frames", type=int, default=24, help="number of frames (default 24)")
    ap.add_argument("--downsample", type=int, default=2, help="block-average the plume by this factor (default 2)")
    ap.add_argument("--rise", type=float, default=0.15, help="upward drift over the sequence, in plume heights")
    ap.add_argument("--grow", type=float, default=0.3, help="sideways spread over the sequence (0.3: 30 %%)")
    ap.add_argument("--twist", type=float, default=25.0, help="twist at the top over the sequence, degrees")
    ap.add_argument("--source", default=str(SOURCE), help="the still plume (.npz with density, voxel_size, "
                                                          "world_of_ijk_min)")
    a = ap.parse_args(argv)
    if not 1 <= a.frames <= 9999 or not 1 <= a.downsample <= 16:
        print("make_smoke_sequence: error: --frames must be in [1, 9999] and --downsample in [1, 16]", file=sys.stderr)
        return 2
    if not Path(a.source).is_file():
        print(f"make_smoke_sequence: error: {a.source}: not found (the shared volume data)", file=sys.stderr)
        return 2
    from popvol.io.files import write_atomically
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    for i, rho, voxel, origin in frames(Path(a.source), a.frames, a.downsample, a.rise, a.grow, a.twist):
        path = out / f"smoke_{i:04d}.npz"
        write_atomically(path, lambda tmp: np.savez_compressed(tmp, density=rho, voxel_size=voxel,
                                                               world_of_ijk_min=origin))
        print(f"{path}: {'x'.join(map(str, rho.shape))}, max {rho.max():.3g}, mass {rho.sum(dtype=np.float64):.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
