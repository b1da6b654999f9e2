"""How close popvol's single scattering is to Mitsuba's paths of one bounce, and what limits it
(run from the repository root; needs popvol[reference]):

    python scripts/single_study.py [SCENE ...] [--resolutions 64,128,256] [--spp 512] [--out build/orders]

SCENE: a name of scenes/accuracy/ (default: wdas_density_10 field_sun smoke1 haze
wdas_angle_090) or a scene file lit by one sun (its first light). The reference is Mitsuba 3's
volpath cut at max_depth 2 (the light scattered exactly once), rendered into ``--out`` when
missing (``--spp`` samples per pixel in 4 passes). Printed on the pixels that see the medium
(popvol compare's mask), in popvol compare's metric: relMSE, the brightness ratio and its
ratio in the reference's dimmest 50 % / middle 40 % / brightest 10 %, for

- popvol: ``popvol.render(scene, popvol.solve(scene).single_scattering())`` at each resolution;
- three ray marches written here, at the pixel centres with popvol's step (half the smallest
  voxel) and its trilinear density, that differ only in the sun's unscattered fluence phi_dir
  at a sample: ``linear``, popvol's (the solution's phi_dir on the medium's grid, trilinear, as
  the renderer reads it); ``log``, the same field interpolated trilinearly in ln phi_dir
  (exact along the light where sigma_t is constant between voxel centres); ``upstream``, the
  field on the plane of voxel centres just upstream of the sample times exp(-sigma_t integrated
  from there to the sample) (a semi-Lagrangian step: exact along the light through the
  trilinear density, the field interpolated only across it); ``exact``, a shadow
  ray toward the sun through the trilinear density in quarter-voxel steps, which needs no field
  and so does not depend on the resolution.

Where the suite's full reference exists (build/accuracy/NAME.exr, scripts/accuracy_table.py),
the whole image at 128 cells is measured too: as it is, and with its single scattering (rendered
with the same offsets, so that its noise goes with it) replaced by the ``linear`` and the
``exact`` march's, so that the two differ by phi_dir alone.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numba as nb
import numpy as np

import popvol
from popvol import metrics
from popvol.kernels.render import camera_ray, f_hg, ray_box
from popvol.kernels.sampling import cell_corners, interpolate
from popvol.reference import load_reference, render_reference
from popvol.renderer import render_inputs

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("wdas_density_10", "field_sun", "smoke1", "haze", "wdas_angle_090")
LINEAR, LOG, EXACT, UPSTREAM = 0, 1, 2, 3


@nb.njit(parallel=True, fastmath=True)
def march_single(density, scale, origin, voxel, lo, hi, albedo, g, sun, power, camera, field, mode, step,
                 shadow_step, out):
    """out (height, width): L = sum over segments T_v (1 - exp(-sigma_t ds)) albedo E f_hg(mu; g)
    phi_dir, at the pixel centres, samples at the segments' midpoints (no jitter); phi_dir by
    ``mode``: LINEAR, trilinear ``field`` (phi_dir); LOG, exp of trilinear ``field`` (ln phi_dir);
    UPSTREAM, :func:`upstream` of ``field`` (phi_dir); EXACT, exp(-sigma_t integrated toward the
    sun in steps of ``shadow_step``)."""
    o, basis, tan_half, width, height = camera
    back = (-sun[0], -sun[1], -sun[2])
    for py in nb.prange(height):
        for px in range(width):
            d = camera_ray(camera, px + 0.5, py + 0.5)
            t0, t1 = ray_box(o, d, lo, hi)
            phase = f_hg(-(sun[0] * d[0] + sun[1] * d[1] + sun[2] * d[2]), g)
            L = 0.0
            T = 1.0
            t = t0
            while t < t1 and T >= 1e-4:
                ds = min(step, t1 - t)
                x = (o[0] + (t + 0.5 * ds) * d[0], o[1] + (t + 0.5 * ds) * d[1], o[2] + (t + 0.5 * ds) * d[2])
                t += ds
                c = cell_corners((x[0] - origin[0]) / voxel[0], (x[1] - origin[1]) / voxel[1],
                                 (x[2] - origin[2]) / voxel[2], density.shape)
                rho = interpolate(density, c)
                if rho <= 0.0:
                    continue
                if mode == LINEAR:
                    phi_dir = interpolate(field, c)
                elif mode == LOG:
                    phi_dir = math.exp(interpolate(field, c))
                elif mode == UPSTREAM:
                    phi_dir = upstream(density, scale, origin, voxel, lo, hi, sun, field, x)
                else:
                    phi_dir = shadow_ray(density, scale, origin, voxel, lo, hi, back, x, shadow_step)
                T_seg = math.exp(-scale * rho * ds)
                L += T * (1.0 - T_seg) * albedo * power * phase * phi_dir
                T *= T_seg
            out[py, px] = L


@nb.njit(fastmath=True)
def shadow_ray(density, scale, origin, voxel, lo, hi, back, x, shadow_step, tau_max=1e300):
    """exp(-tau) at x: tau = scale x the trilinear density integrated from x along ``back``
    (unit, toward the sun) to the box [lo, hi], by the midpoint rule in steps of
    ``shadow_step`` (the last one cut at the box), stopped once tau exceeds ``tau_max``."""
    s0, s1 = ray_box(x, back, lo, hi)
    tau = 0.0
    s = 0.0
    while s < s1 and tau <= tau_max:
        dl = min(shadow_step, s1 - s)
        y = (x[0] + (s + 0.5 * dl) * back[0], x[1] + (s + 0.5 * dl) * back[1],
             x[2] + (s + 0.5 * dl) * back[2])
        cy = cell_corners((y[0] - origin[0]) / voxel[0], (y[1] - origin[1]) / voxel[1],
                          (y[2] - origin[2]) / voxel[2], density.shape)
        tau += scale * interpolate(density, cy) * dl
        s += dl
    return math.exp(-tau)


@nb.njit(fastmath=True)
def upstream(density, scale, origin, voxel, lo, hi, sun, field, x):
    """phi_dir at x from the plane of voxel centres just upstream of it across the axis a along
    which the sun travels fastest: phi_dir(y) there (trilinear in ``field``, so bilinear in the
    plane) times exp(-sigma_t integrated from y to x), by a 4-point midpoint rule through the
    trilinear density, y = x - t d_l on that plane. Upstream of the first plane of centres (the
    grid's outer half cell) nothing lies between x and the box's face: the integral runs to it."""
    a = 0
    for k in range(1, 3):
        if abs(sun[k]) > abs(sun[a]):
            a = k
    u = (x[a] - origin[a]) / voxel[a]
    n = density.shape[a]
    plane = math.floor(u) if sun[a] > 0.0 else math.ceil(u)
    inside = 0.0 <= plane <= n - 1.0
    if inside:
        t = (u - plane) * voxel[a] / sun[a]
    else:
        t0, t = ray_box(x, (-sun[0], -sun[1], -sun[2]), lo, hi)
    tau = 0.0
    for i in range(4):
        s = (i + 0.5) * 0.25 * t
        y = (x[0] - s * sun[0], x[1] - s * sun[1], x[2] - s * sun[2])
        cy = cell_corners((y[0] - origin[0]) / voxel[0], (y[1] - origin[1]) / voxel[1],
                          (y[2] - origin[2]) / voxel[2], density.shape)
        tau += scale * interpolate(density, cy) * 0.25 * t
    if not inside:
        return math.exp(-tau)
    y = (x[0] - t * sun[0], x[1] - t * sun[1], x[2] - t * sun[2])
    cy = cell_corners((y[0] - origin[0]) / voxel[0], (y[1] - origin[1]) / voxel[1],
                      (y[2] - origin[2]) / voxel[2], density.shape)
    return interpolate(field, cy) * math.exp(-tau)


def scene_path(name: str) -> Path:
    path = Path(name)
    return path if path.suffix == ".toml" else ROOT / "scenes" / "accuracy" / f"{name}.toml"


def row(label: str, img: np.ndarray, ref, mask) -> str:
    b = metrics.band_ratios(img, ref.image, mask)
    return (f"| {label} | {metrics.relmse(img, ref.image, mask):.4f} | x{metrics.brightness_ratio(img, ref.image, mask):.3f} | "
            + " / ".join(f"x{b[k]:.3f}" for k in ("dim", "mid", "bright")) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--resolutions", default="64,128,256")
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--out", default=str(ROOT / "build" / "orders"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.scenes:
        path = scene_path(name)
        scene = popvol.load_scene(path)
        ref_path = out / f"{path.stem}_d2.exr"
        if not ref_path.exists():
            print(f"rendering {ref_path} (max_depth 2, {args.spp} spp) ...", flush=True)
            render_reference(scene, ref_path, args.spp, "llvm_ad_rgb", passes=4, max_depth=2, resume=False)
        ref = load_reference(ref_path)
        h, w = ref.image.shape[:2]
        med = scene.medium
        if not (np.all(med.scale == med.scale[0]) and not med.albedo_per_voxel and not med.g_per_voxel
                and np.all(np.asarray(med.albedo) == np.asarray(med.albedo).ravel()[0])):
            print(f"{name}: skipped (the marches here take grey, constant optics)")
            continue
        mask = metrics.medium_mask(ref.image, popvol.load_scene(path, width=w, height=h))
        noise = metrics.noise_relmse(ref.variance, ref.image, mask) if ref.variance is not None else float("nan")
        print(f"\n{path.stem}: {w}x{h}, reference {ref.spp} spp (noise relMSE {noise:.4f}), {int(mask.sum())} "
              f"medium pixels, largest voxel {float(med.density.max() * med.scale[0] * med.voxel_size.min()):.2f} "
              "mean free paths\n")
        print("| single scattering | relMSE | brightness | dim / mid / bright |")
        print("|---|---|---|---|")
        lo, hi = med.bounds
        step = 0.5 * float(med.voxel_size.min())
        exact_done = False
        for n in (int(r) for r in args.resolutions.split(",")):
            sc = popvol.load_scene(path, width=w, height=h, resolution=n)
            sol = popvol.solve(sc)
            l = int(np.flatnonzero(~sol.is_point & sol.unscattered)[0])
            single = sol.single_scattering()
            print(row(f"popvol, {n} cells", popvol.render(sc, single), ref, mask))
            camera = render_inputs(sc, single, jitter=False)[5]
            power = np.asarray(sol.irradiance[l], np.float64)
            phi_dir = np.ascontiguousarray(sol.direct[l, 0], np.float32)
            fields = {LINEAR: phi_dir, LOG: np.log(np.maximum(phi_dir, 1e-30)).astype(np.float32)}
            modes = [(LINEAR, f"linear phi_dir, {n} cells"), (LOG, f"log phi_dir, {n} cells"),
                     (UPSTREAM, f"upstream plane, {n} cells")]
            if not exact_done:
                modes.append((EXACT, "exact (shadow rays)"))
                exact_done = True
            for mode, label in modes:
                img = np.zeros((h, w))
                march_single(med.density, float(med.scale[0]), med.origin, med.voxel_size, lo, hi,
                             float(np.asarray(med.albedo).ravel()[0]), float(med.g), sol.directions[l], 1.0, camera,
                             fields.get(mode, phi_dir), mode, step, 0.5 * step, img)
                print(row(label, img[..., None] * power, ref, mask))
                if mode == EXACT:
                    exact = img[..., None] * power
                if mode == LINEAR:
                    linear = img[..., None] * power
            whole_ref = ROOT / "build" / "accuracy" / f"{path.stem}.exr"
            if whole_ref.exists() and n == 128:
                full = load_reference(whole_ref)
                if full.image.shape == ref.image.shape:
                    fmask = metrics.medium_mask(full.image, sc)
                    whole = popvol.render(sc, sol)
                    rest = whole - popvol.render(sc, single)     # the same offsets: its noise cancels
                    share = metrics.luminance(ref.image)[fmask].sum() / metrics.luminance(full.image)[fmask].sum()
                    print(f"\nthe whole image at 128 cells against {whole_ref.relative_to(ROOT)} (order 1 is "
                          f"{100 * share:.0f} % of it): relMSE {metrics.relmse(whole, full.image, fmask):.4f}; with "
                          "its single scattering marched at the pixel centres, from popvol's phi_dir "
                          f"{metrics.relmse(rest + linear, full.image, fmask):.4f}, from shadow rays "
                          f"{metrics.relmse(rest + exact, full.image, fmask):.4f}\n")


if __name__ == "__main__":
    main()
