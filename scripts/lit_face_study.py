"""How a sun's unscattered fluence is interpolated just inside a lit face (run from the
repository root; the Mitsuba part needs popvol[reference]):

    python scripts/lit_face_study.py [--resolution 64,128,192] [--spp 1024] [--out build/lit_face]

The medium is a ball of unit density (sigma_t 1 per voxel, albedo 0.99, g 0.877) of radius 24.5
voxels in a 64^3 grid, its edge a ramp one voxel wide (density clip(24.5 - r, 0, 1)), lit by a sun
at 90 degrees to the view. popvol computes phi_dir = exp(-tau) at its light domain's cell centres
(Eq. 22) and brings it to the medium's voxel centres trilinearly (kernels.sampling.domain_to_world).
Where a ray from the sun enters the medium, phi_dir has a kink: 1 outside, falling inside. Linear
interpolation across it is too low near the kink, however fine the domain, and too high deeper,
where exp(-tau) is convex.

Printed per resolution, over the voxels in the ramp (0 < density < 1) and inside (density 1),
grouped by the exact phi_dir at their centres (shadow rays toward the sun through the trilinear
density, steps of 1/20 voxel): popvol's phi_dir / the exact one (sums over the group); for the
ramp's voxels where the exact value is above 0.9, also the exact values at the domain's cell
centres interpolated as popvol does / the exact value at the voxel, which says whether the
interpolation or the domain's own values make the difference. With ``--spp`` > 0, the single
scattering (``Solution.single_scattering()``) against Mitsuba's paths of one bounce
(``max_depth = 2``, rendered into ``--out`` when missing): the sum over the pixels that see the
ball, popvol / Mitsuba.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import popvol
from popvol import metrics
from popvol.pipeline import seen_voxels

ROOT = Path(__file__).resolve().parents[1]
N = 64
RADIUS = 24.5
SUN = np.array([-0.6, -0.8, 0.0])
STEP = 0.05           # voxels, of the shadow rays


def ball_scene(path: Path) -> Path:
    """Write the ball's volume and scene into ``path`` (a folder); return the scene file."""
    path.mkdir(parents=True, exist_ok=True)
    x = np.arange(N) - (N - 1) / 2
    r = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2)
    density = np.clip(RADIUS - r, 0.0, 1.0).astype(np.float32)
    np.savez(path / "ball.npz", density=density, voxel_size=np.array([1.0]),
             world_of_ijk_min=np.full(3, -(N - 1) / 2))
    scene = path / "ball.toml"
    scene.write_text(f"""# scripts/lit_face_study.py: a ball of unit density with a one-voxel ramp, lit from the side
[medium]
file = "ball.npz"
scale = 1.0
albedo = 0.99
g = 0.877

[[lights]]
type = "directional"
direction = [{SUN[0]}, {SUN[1]}, {SUN[2]}]
irradiance = [1.0, 1.0, 1.0]

[background]
radiance = [0.0, 0.0, 0.0]

[camera]
origin = [0.0, 0.0, 200.0]
target = [0.0, 0.0, 0.0]
fov = 20.0
width = 96
height = 96
""")
    return scene


def corners(p: np.ndarray, shape) -> list[tuple[np.ndarray, np.ndarray]]:
    """The trilinear stencil of index-space points p (m, 3) in a grid of ``shape``, clamped to
    the edge: eight (corner indices int (m, 3), weights (m,))."""
    s = np.array(shape)
    p = np.clip(p, 0, s - 1 - 1e-9)
    i = np.floor(p).astype(int)
    f = p - i
    out = []
    for c in np.ndindex(2, 2, 2):
        w = np.prod(np.where(np.array(c) == 1, f, 1 - f), axis=1)
        out.append((np.minimum(i + c, s - 1), w))
    return out


def trilinear(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """a (nx, ny, nz) at index-space points p (m, 3), trilinear, clamped to the edge."""
    return sum(w * a[tuple(c.T)] for c, w in corners(p, a.shape))


def exact_direct(density: np.ndarray, q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """exp(-tau) at index-space points q (m, 3), tau along -d (toward the sun) through the
    trilinear density (sigma_t = density per voxel)."""
    tau = np.zeros(len(q))
    for k in range(int(2 * N / STEP)):
        tau += trilinear(density, q - d * (k + 0.5) * STEP) * STEP
    return np.exp(-tau)


def study(scene_path: Path, resolution: int, masks, single_ref) -> None:
    scene = popvol.load_scene(scene_path, resolution=resolution)
    sol = popvol.solve(scene)
    med = scene.medium
    density = med.density.astype(np.float64)
    d = SUN / np.linalg.norm(SUN)
    idx = np.argwhere(seen_voxels(med) & (med.density > 0))
    exact = exact_direct(density, idx.astype(np.float64), d)
    pop = sol.direct[0, 0][tuple(idx.T)].astype(np.float64)
    rho = density[tuple(idx.T)]
    dom = sol.domains[0].domain
    print(f"\n{resolution} cells (light domain {dom.shape[0]}x{dom.shape[1]}x{dom.shape[2]}, "
          f"cells {dom.h:.2f} voxels): popvol phi_dir / exact, by the exact value")
    for name, part in (("ramp", rho < 1), ("inside", rho >= 1)):
        cells = []
        for lo, hi in ((0.9, 1.01), (0.6, 0.9), (0.3, 0.6), (0.1, 0.3), (0.01, 0.1)):
            b = part & (exact >= lo) & (exact < hi)
            if b.any():
                cells.append(f"[{lo}, {min(hi, 1.0)}) x{pop[b].sum() / exact[b].sum():.3f} ({b.sum()})")
        print(f"  {name:6s} " + "  ".join(cells))
    # the same interpolation applied to exact values at the domain's cell centres
    sel = np.flatnonzero((rho < 1) & (exact > 0.9))
    loc = ((med.origin + idx[sel] * med.voxel_size) - dom.origin) @ dom.frame.T / dom.h - 0.5
    interp = np.zeros(len(sel))
    for c, w in corners(loc, dom.shape):
        centre = dom.origin + ((c + 0.5) @ dom.frame) * dom.h
        interp += w * exact_direct(density, (centre - med.origin) / med.voxel_size, d)
    print(f"  ramp, exact > 0.9: the exact values at the domain's cell centres, interpolated, / exact "
          f"x{interp.sum() / exact[sel].sum():.3f}")
    if single_ref is not None:
        y = metrics.luminance(popvol.render(scene, sol.single_scattering()))
        ref = metrics.luminance(single_ref)
        print(f"  single scattering / Mitsuba's max_depth 2: x{y[masks].sum() / ref[masks].sum():.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", default="64,128,192")
    ap.add_argument("--spp", type=int, default=0, help="Mitsuba's samples per pixel (0: no Mitsuba)")
    ap.add_argument("--out", default=str(ROOT / "build" / "lit_face"))
    args = ap.parse_args()
    scene_path = ball_scene(Path(args.out))
    single, mask = None, None
    if args.spp > 0:
        from popvol.reference import load_reference, render_reference
        ref_path = Path(args.out) / "ball_d2.exr"
        if not ref_path.exists():
            print(f"rendering {ref_path} (max_depth 2, {args.spp} spp) ...", flush=True)
            render_reference(popvol.load_scene(scene_path), ref_path, args.spp, "llvm_ad_rgb", passes=8,
                             max_depth=2, resume=False)
        single = load_reference(ref_path).image
        mask = metrics.medium_mask(single, popvol.load_scene(scene_path))
    for r in (int(x) for x in args.resolution.split(",")):
        study(scene_path, r, mask, single)


if __name__ == "__main__":
    main()
