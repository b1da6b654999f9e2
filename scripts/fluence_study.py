"""Is popvol's scattered *fluence* wrong, or only its *angular model*? An independent 3-D Monte
Carlo of a sun lighting a medium's voxel grid, against popvol's solved fields (with ../shared
beside the checkout):

    python scripts/fluence_study.py [--resolution 64,128,256] [--angles 0,90,180] [--photons N]
                                    [--block 2] [--batches 4] [--seed 1] [--solver ordinates]
                                    [--scene SCENE.toml]

What it measures, per sun direction (scenes/accuracy/wdas_angle_<A>.toml: one sun each; the
fields do not depend on the camera, so the three angles are three sun directions; or the scene
``--scene``, lit by one sun, in place of the angles) and per popvol resolution (the light
domain's; the medium's voxels are the same at every resolution):

* The Monte Carlo (Numba, one thread, nothing of popvol's code): photons of unit irradiance
  enter over a plane perpendicular to the sun covering the projection of the box of the
  non-empty voxels (each carries that area / N), delta tracking with the majorant
  max sigma_t, HG scattering, the albedo as a weight (Russian roulette below 0.01). The medium
  is the scene's density, trilinear between voxel centres, clamped to the edge value in the
  outer half voxel, zero outside the grid's cells (popvol's convention, re-implemented).
  Tallies on a grid of blocks of b^3 voxels: a *track-length* estimator with exact
  segment-by-cell splitting (Amanatides-Woo DDA over the blocks along every straight flight
  between tentative collisions), so each block gets the integral of the fluence over its
  volume / its volume: the unscattered fluence (photons before their first real collision),
  and for the scattered light (after >= 1 real collision) its fluence, first-moment vector
  (track length x direction), its second Legendre moment about the sun's direction d
  (track length x P2(u . d), P2(x) = (3x^2 - 1)/2; / the fluence = B, in [-1/2, 1]), its
  in-scattered source toward the scene's camera, int L_s(w) f_hg(w . w_o; g) dw, w_o the unit
  vector from the block's centre to the camera, and its fluence by the eighteen-ordinate
  walk's cell of the sphere it travels in (the ordinate nearest its direction, walk.ORDINATES18
  in the sun's domain frame, domains.light_frame), and the fluence and first moment of the light
  scattered once and of the light scattered twice.
  A medium whose voxels are not cubes is put on cubes as wide as their smallest side
  (``on_cubic_voxels``), for the Monte Carlo and popvol alike.
  The noise is the spread over ``--batches`` independent batches (different seeds).
* popvol: ``popvol.solve`` per unit irradiance; on the voxel centres the walk's fluence phi
  (unscattered part included), its unscattered part direct = exp(-tau), phia (= phi x the
  walk's anisotropy along the sun's direction d; the unscattered part is a delta lobe, A = 1),
  the diffusion stage's phid and flux J (world axes). popvol's scattered fluence = phi - direct
  + phid, its scattered first moment = (phia - direct) d + J, and its source toward the camera
  (the lobes of kernels/render.py walk_lobes + lobe_toward, i.e. the renderer without the
  gather): (phi - direct) f_hg(d . w_o; g A_rest) + phid f_hg(J/|J| . w_o; g min(|J|/phid, cap)).
  With the ordinates' walks (``--solver ordinates``) the walk's scattered light is itself one lobe
  about its own first moment in phid and J (pipeline.ordinate_fields): "diff%" is then 100 and
  J.d/pd and |J|/pd are that light's mean cosines.
  Averaged over the same blocks (the mean of the voxel-centre values).

Printed per angle and resolution, over blocks holding density > 0, grouped by the sun's optical
depth tau = -ln(direct) of the block: the popvol / MC ratio of the scattered fluence
(density-weighted sums, +- the MC's standard error from the batches), the mean cosine of the
scattered light along d (F . d / phi) and its |F| / phi, for both, and the popvol / MC ratio of
the source toward the camera; then popvol's parts: "diff%" the diffusion stage's share of its
scattered fluence, "walk A" the walk's scattered light's mean cosine along d, J.d/pd and |J|/pd
the diffusion stage's (the renderer caps |J|/phid at lobe_cap = 0.5). First the unscattered check (MC unscattered / popvol direct).
Last, an image-level estimate of the multiply scattered light's error: the blocks weighted by
sigma_s x (transmittance to the camera) / (r^2 cos^3 of the off-axis angle) within the view
(what each block adds to the sum of the pixels), with the single scattering (popvol's direct,
the same on both sides) added: "lobes" is popvol's fields and lobes, "magnitude" popvol's
scattered fluence times the MC's S / phi in each block (popvol's fluence, the true angular
distribution), "1-lobe(MC F)" one HG lobe about the MC's own first moment F/|F| (mean cosine
|F|/phi) with the MC's own fluence (the angular model alone, with exact moments), "1-lobe about
d (MC A)" one HG lobe about d with the MC's fluence and A = F . d / phi (popvol's walk model
fed exact moments), "2-lobe about d (MC A, B)" two HG lobes about d matching the MC's
fluence, A and B (what a walk that also tallied sum(W a^2) could render: a mixture of HG(a_v)
lobes about d has Legendre coefficients P_l = sum(W a^l) / sum(W)); the closure
(``two_point``): weights 1/2 at A -+ sqrt(B - A^2); where a point would leave [-1, 1] it sits
on the bound and the other point and the weights keep the mean and variance; B - A^2 clamped
to [0, 1 - A^2] (B < A^2 is no mixture of HG lobes about d: then one lobe); "18 ordinates,
HG(k) each" the MC's fluence in each ordinate's cell of the sphere as a lobe HG(k) about that
ordinate, k in ``KERNELS``. "1-lobe(MC F) per order 1, >= 2" one HG lobe about its own
first moment for the light scattered once and one for the rest, "... per order 1, 2, >= 3" the
same with the light scattered twice apart too (the MC's fluences and moments by order),
"popvol's lobe less the MC's order 1, + its lobe" popvol's scattered fluence and moment less the
MC's once-scattered light's as one lobe, plus that light's own. A lobe HG(a) about d scatters
toward w_o as f_hg(d . w_o; g a), as in kernels/render.py. Each ratio is +- the
spread over the batches. Before it, per band: the MC's A, B, the HG lobe's B = A^2 (of the
band's A; <A^2> the mean over the blocks, weighted as the band's sums), B<A^2% the share, so weighted,
of blocks with B < A^2, the three models' source toward the camera / the MC's (density-weighted,
as above) and img% the band's share of the MC's multiple scattering in the image sum.

The MC is cached in the system's temporary folder (popvol_fluence_study/), keyed by a tally version tag, a hash of what it depends on (the
density, the optics, the sun's direction, the camera's position), the photons, block, batches
and seed.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numba as nb
import numpy as np

import popvol

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import _scatter            # noqa: E402  (HG sampling, the tests' oracle's)
from order_bands import on_cubes           # noqa: E402  (scripts/, beside this one)
CACHE = Path(tempfile.gettempdir()) / "popvol_fluence_study"
BANDS = [(0.0, 0.5), (0.5, 2.0), (2.0, 5.0), (5.0, 10.0), (10.0, math.inf)]
INV_4PI = 1.0 / (4.0 * math.pi)
# tally rows
PHI, FX, FY, FZ, SCAM, UNSC, P2D = range(7)
ORD = 7                          # then 18 rows: the scattered fluence by the ordinate it lies nearest
ONCE = ORD + 18                  # then 4 rows: the fluence and first moment of the light scattered once,
TWICE = ONCE + 4                 # and 4 of the light scattered twice
NTAL = TWICE + 4
CACHE_TAG = "v5"                 # bump when the tallies change (v2: + P2D, v3: + ORD, v4: + ONCE, v5: + TWICE)


# ----------------------------------------------------------------------------- Monte Carlo
@nb.njit(inline="always", fastmath=False)
def _density(rho, x, y, z):
    """rho at continuous index (x, y, z) (voxel centres at integers): trilinear, clamped to the
    edge in the outer half voxel, 0 outside [-1/2, n - 1/2]."""
    nx, ny, nz = rho.shape
    if x < -0.5 or y < -0.5 or z < -0.5 or x > nx - 0.5 or y > ny - 0.5 or z > nz - 0.5:
        return 0.0
    x = min(max(x, 0.0), nx - 1.0)
    y = min(max(y, 0.0), ny - 1.0)
    z = min(max(z, 0.0), nz - 1.0)
    i = min(int(x), nx - 2)
    j = min(int(y), ny - 2)
    k = min(int(z), nz - 2)
    fx, fy, fz = x - i, y - j, z - k
    c00 = rho[i, j, k] * (1 - fz) + rho[i, j, k + 1] * fz
    c01 = rho[i, j + 1, k] * (1 - fz) + rho[i, j + 1, k + 1] * fz
    c10 = rho[i + 1, j, k] * (1 - fz) + rho[i + 1, j, k + 1] * fz
    c11 = rho[i + 1, j + 1, k] * (1 - fz) + rho[i + 1, j + 1, k + 1] * fz
    return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx


@nb.njit(inline="always")
def _f_hg(mu, g):
    d = 1.0 + g * g - 2.0 * g * mu
    return (1.0 - g * g) * INV_4PI / (d * math.sqrt(d))


@nb.njit(inline="always")
def _first_crossing(p, u, i, b):
    """Along one axis, a flight from p in direction u within block i (blocks of b units): the
    step to the next block (-1, 0, 1), the distance to its first block face and between faces."""
    if u > 0.0:
        return 1, ((i + 1) * b - p) / u, b / u
    if u < 0.0:
        return -1, (i * b - p) / u, -b / u
    return 0, 1e300, 1e300


@nb.njit(inline="always")
def _to_box_exit(px, py, pz, ux, uy, uz, n, far):
    """The distance from p along u to where it leaves the box [0, n] (q coordinates), at most
    ``far``."""
    te = far
    for ax in range(3):
        p = px if ax == 0 else (py if ax == 1 else pz)
        u = ux if ax == 0 else (uy if ax == 1 else uz)
        if u > 0.0:
            te = min(te, (n[ax] - p) / u)
        elif u < 0.0:
            te = min(te, -p / u)
    return te


@nb.njit(inline="always")
def _tally(tal, wo, d, E, b, nc, px, py, pz, ux, uy, uz, L, w, scattered, g):
    """Add w x (length of the flight p + t u, 0 <= t < L, in each block) to the block's tallies
    (Amanatides-Woo over blocks of b voxel units; coordinates q = index + 1/2, grid [0, n])."""
    ix = min(max(int(px / b), 0), nc[0] - 1)
    iy = min(max(int(py / b), 0), nc[1] - 1)
    iz = min(max(int(pz / b), 0), nc[2] - 1)
    sx, tx, dx = _first_crossing(px, ux, ix, b)
    sy, ty, dy = _first_crossing(py, uy, iy, b)
    sz, tz, dz = _first_crossing(pz, uz, iz, b)
    o_near, best = 0, -2.0
    if scattered:
        for o in range(E.shape[0]):
            c = ux * E[o, 0] + uy * E[o, 1] + uz * E[o, 2]
            if c > best:
                o_near, best = o, c
    t = 0.0
    while True:
        tn = min(tx, ty, tz, L)
        l = tn - t
        if l > 0.0:
            wl = w * l
            if scattered:
                tal[PHI, ix, iy, iz] += wl
                tal[FX, ix, iy, iz] += wl * ux
                tal[FY, ix, iy, iz] += wl * uy
                tal[FZ, ix, iy, iz] += wl * uz
                mu = ux * wo[0, ix, iy, iz] + uy * wo[1, ix, iy, iz] + uz * wo[2, ix, iy, iz]
                tal[SCAM, ix, iy, iz] += wl * _f_hg(mu, g)
                c = ux * d[0] + uy * d[1] + uz * d[2]
                tal[P2D, ix, iy, iz] += wl * (1.5 * c * c - 0.5)
                tal[ORD + o_near, ix, iy, iz] += wl
                if scattered <= 2:
                    r = ONCE if scattered == 1 else TWICE
                    tal[r, ix, iy, iz] += wl
                    tal[r + 1, ix, iy, iz] += wl * ux
                    tal[r + 2, ix, iy, iz] += wl * uy
                    tal[r + 3, ix, iy, iz] += wl * uz
            else:
                tal[UNSC, ix, iy, iz] += wl
        t = tn
        if t >= L:
            return
        if tx <= ty and tx <= tz:
            ix += sx
            tx += dx
            if ix < 0 or ix >= nc[0]:
                return
        elif ty <= tz:
            iy += sy
            ty += dy
            if iy < 0 or iy >= nc[1]:
                return
        else:
            iz += sz
            tz += dz
            if iz < 0 or iz >= nc[2]:
                return


@nb.njit
def _mc(rho, sig_vox, albedo, g, d, E, e1, e2, centre, half1, half2, b, wo, n_photons, seed, tal):
    """n_photons photons along d entering over the rectangle centre + a e1 + c e2 (|a| <= half1,
    |c| <= half2); q coordinates (voxel units, grid [0, n]); sig_vox: sigma_t per unit density
    per voxel length. Adds the raw track lengths (voxel units) to ``tal``; returns (real
    collisions, tentative collisions)."""
    np.random.seed(seed)
    n = rho.shape
    nq = (float(n[0]), float(n[1]), float(n[2]))
    nc = (tal.shape[1], tal.shape[2], tal.shape[3])
    rmax = 0.0
    for i in range(n[0]):
        for j in range(n[1]):
            for k in range(n[2]):
                rmax = max(rmax, rho[i, j, k])
    maj = sig_vox * rmax
    R = 2.0 * (nq[0] + nq[1] + nq[2])
    n_real = 0
    n_tent = 0
    for _ in range(n_photons):
        a = half1 * (2.0 * np.random.random() - 1.0)
        c = half2 * (2.0 * np.random.random() - 1.0)
        px = centre[0] + a * e1[0] + c * e2[0] - R * d[0]
        py = centre[1] + a * e1[1] + c * e2[1] - R * d[1]
        pz = centre[2] + a * e1[2] + c * e2[2] - R * d[2]
        ux, uy, uz = d[0], d[1], d[2]
        # enter the grid's box [0, n]^3
        t0, t1 = -1e300, 1e300
        miss = False
        for ax in range(3):
            p = px if ax == 0 else (py if ax == 1 else pz)
            u = ux if ax == 0 else (uy if ax == 1 else uz)
            if abs(u) < 1e-300:
                if p < 0.0 or p > nq[ax]:
                    miss = True
                continue
            ta, tb = (0.0 - p) / u, (nq[ax] - p) / u
            if ta > tb:
                ta, tb = tb, ta
            t0, t1 = max(t0, ta), min(t1, tb)
        if miss or t0 >= t1:
            continue
        px += t0 * ux
        py += t0 * uy
        pz += t0 * uz
        w = 1.0
        scattered = 0              # real collisions so far
        while True:
            s = -math.log(1.0 - np.random.random()) / maj
            te = max(_to_box_exit(px, py, pz, ux, uy, uz, nq, 1e300), 0.0)
            L = min(s, te)
            _tally(tal, wo, d, E, b, nc, px, py, pz, ux, uy, uz, L, w, scattered, g)
            if s >= te:
                break
            px += s * ux
            py += s * uy
            pz += s * uz
            n_tent += 1
            sig = sig_vox * _density(rho, px - 0.5, py - 0.5, pz - 0.5)
            if np.random.random() * maj < sig:
                n_real += 1
                w *= albedo
                if w < 0.01:
                    if np.random.random() < 0.5:
                        w *= 2.0
                    else:
                        break
                ux, uy, uz = _scatter(ux, uy, uz, g)
                scattered += 1
    return n_real, n_tent


@nb.njit
def _transmittance_to(rho, sig_vox, cam, out, mask):
    """exp(-optical depth) from each voxel centre where ``mask`` to ``cam`` (q coordinates),
    midpoint rule, steps of at most 1/4 voxel, within the grid's box."""
    n = rho.shape
    for i in range(n[0]):
        for j in range(n[1]):
            for k in range(n[2]):
                if not mask[i, j, k]:
                    continue
                px, py, pz = i + 0.5, j + 0.5, k + 0.5
                vx, vy, vz = cam[0] - px, cam[1] - py, cam[2] - pz
                r = math.sqrt(vx * vx + vy * vy + vz * vz)
                vx, vy, vz = vx / r, vy / r, vz / r
                te = _to_box_exit(px, py, pz, vx, vy, vz, n, r)
                m = max(int(math.ceil(te / 0.25)), 1)
                h = te / m
                tau = 0.0
                for s in range(m):
                    t = (s + 0.5) * h
                    tau += _density(rho, px + t * vx - 0.5, py + t * vy - 0.5, pz + t * vz - 0.5)
                out[i, j, k] = math.exp(-sig_vox * h * tau)


# ----------------------------------------------------------------------------- helpers
def blocks(a: np.ndarray, b: int) -> np.ndarray:
    """Mean of ``a`` (..., nx, ny, nz) over blocks of b^3 voxels (partial blocks at the far
    ends: the mean of the voxels they hold)."""
    if b == 1:
        return a.astype(np.float64)
    *lead, nx, ny, nz = a.shape
    cx, cy, cz = -(-nx // b), -(-ny // b), -(-nz // b)
    pad = [(0, 0)] * len(lead) + [(0, cx * b - nx), (0, cy * b - ny), (0, cz * b - nz)]
    s = np.pad(a.astype(np.float64), pad).reshape(*lead, cx, b, cy, b, cz, b).sum(axis=(-5, -3, -1))
    return s / block_counts((nx, ny, nz), b)


def block_counts(shape, b: int) -> np.ndarray:
    ones = np.ones(shape)
    nx, ny, nz = shape
    cx, cy, cz = -(-nx // b), -(-ny // b), -(-nz // b)
    return np.pad(ones, [(0, cx * b - nx), (0, cy * b - ny), (0, cz * b - nz)]).reshape(
        cx, b, cy, b, cz, b).sum(axis=(1, 3, 5))


def f_hg(mu, g):
    d = 1.0 + g * g - 2.0 * g * mu
    return (1.0 - g * g) * INV_4PI / (d * np.sqrt(d))


def grey(x) -> float:
    return float(np.ravel(np.asarray(x, np.float64))[0])


def scene_path(angle: int | Path) -> Path:
    """The suite's WDAS cloud with its sun at ``angle`` degrees from the view, or the scene
    ``angle`` itself where that is a path (``--scene``)."""
    if isinstance(angle, Path):
        return angle
    return ROOT / "scenes" / "accuracy" / f"wdas_angle_{angle:03d}.toml"


def label(angle: int | Path) -> str:
    return angle.stem if isinstance(angle, Path) else f"angle {angle:3d}"


def geometry(scene):
    """q-space geometry (q = voxel index + 1/2; the grid is [0, n]^3), isotropic voxels."""
    m = scene.medium
    vs = np.asarray(m.voxel_size, np.float64)
    if not np.allclose(vs, vs[0], rtol=1e-6):
        raise SystemExit("fluence_study: needs cubic voxels")
    corner = np.asarray(m.origin, np.float64) - 0.5 * vs        # world position of q = 0
    return vs[0], corner


def load(angle: int | Path, resolution: int, solver: str):
    """The scene (:func:`scene_path`) at the light domains' ``resolution``, its medium on cubic
    voxels (:func:`on_cubic_voxels`)."""
    scene = popvol.load_scene(str(scene_path(angle)), resolution=resolution, solver=solver)
    return dataclasses.replace(scene, medium=on_cubic_voxels(scene.medium))


def on_cubic_voxels(medium):
    """``medium`` itself where its voxels are cubes; else the same box on cubes as wide as its
    smallest side (order_bands.on_cubes: the density sampled at their centres as a light domain
    samples it). The Monte Carlo and popvol then both see that medium, which differs from the
    scene's where the density is not linear across a voxel."""
    voxel = np.asarray(medium.voxel_size, np.float64)
    if np.allclose(voxel, voxel.min(), rtol=1e-6):
        return medium
    cubes = on_cubes(medium, float(voxel.min()), "fluence_study")
    print(f"fluence_study: the medium's {medium.density.shape} voxels of {voxel.tolist()} resampled to "
          f"{cubes.density.shape} cubes of {voxel.min():g}")
    return cubes


def scene_key(scene) -> str:
    """A short hash of what the MC's tallies depend on: the density, sigma_t's scale, the albedo,
    g, the voxel grid, the sun's direction and the camera's position."""
    m = scene.medium
    h = hashlib.sha1(np.ascontiguousarray(m.density, np.float32).tobytes())
    for v in (m.scale, m.albedo, m.g, m.voxel_size, m.origin, scene.lights[0].direction, scene.camera.origin):
        h.update(np.asarray(v, np.float64).tobytes())
    return h.hexdigest()[:12]


def run_mc(scene, n_photons: int, b: int, batches: int, seed: int, angle: int) -> dict:
    """The MC's per-batch block tallies, as fluence per unit irradiance (cached)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    tag = angle.stem if isinstance(angle, Path) else f"a{angle:03d}"
    path = CACHE / f"mc_{CACHE_TAG}_{tag}_{scene_key(scene)}_n{n_photons}_b{b}_k{batches}_s{seed}.npz"
    if path.exists():
        z = np.load(path)
        return {k: z[k] for k in z.files}
    m = scene.medium
    rho = np.ascontiguousarray(m.density, np.float32)
    vs, corner = geometry(scene)
    sig_vox = grey(m.scale) * vs
    albedo, g = grey(m.albedo), grey(m.g)
    d = np.asarray(scene.lights[0].direction, np.float64)
    d = d / np.linalg.norm(d)
    e1 = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    # the source covers the projection of the box of the non-empty voxels (+1 voxel: the
    # trilinear support); light missing it crosses no density
    nz_idx = np.argwhere(rho > 0)
    lo = np.maximum(nz_idx.min(0) - 1, 0).astype(np.float64)
    hi = np.minimum(nz_idx.max(0) + 2, rho.shape).astype(np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    centre = corners.mean(0)
    a1 = (corners - centre) @ e1
    a2 = (corners - centre) @ e2
    half1, half2 = np.abs(a1).max(), np.abs(a2).max()
    area_q = 4 * half1 * half2                                   # in voxel units^2
    nc = tuple(-(-s // b) for s in rho.shape)
    # direction from each block's centre to the camera
    cam_q = (np.asarray(scene.camera.origin, np.float64) - corner) / vs
    cen = [blocks_centre(c, b, s) for c, s in zip(nc, rho.shape)]
    X, Y, Z = np.meshgrid(*cen, indexing="ij")
    wo = np.stack([cam_q[0] - X, cam_q[1] - Y, cam_q[2] - Z])
    wo /= np.linalg.norm(wo, axis=0)
    wo = np.ascontiguousarray(wo, np.float32)
    per = n_photons // batches
    counts = block_counts(rho.shape, b)
    out = []
    t0 = time.perf_counter()
    real = tent = 0
    for k in range(batches):
        tal = np.zeros((NTAL,) + nc, np.float64)
        r, t = _mc(rho, sig_vox, albedo, g, d, ordinates_world(d), e1, e2, centre, half1, half2, float(b), wo, per,
                   seed * 1000 + k, tal)
        real += r
        tent += t
        # fluence = sum(w l) x (power per photon) / (block volume), all in voxel units
        out.append((tal * (area_q / per) / counts).astype(np.float32))
    secs = time.perf_counter() - t0
    res = {"tallies": np.stack(out), "seconds": np.float64(secs), "real": np.int64(real),
           "tentative": np.int64(tent), "photons": np.int64(per * batches)}
    np.savez(path, **res)
    return res


def ordinates_world(d) -> np.ndarray:
    """float64 (18, 3): the eighteen ordinates' unit directions (walk.ORDINATES18, in a sun's
    domain frame d, u, v: domains.light_frame) in the world's frame."""
    from popvol.domains import light_frame
    from popvol.walk import ORDINATES18
    e = np.asarray(ORDINATES18, np.float64)
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    return np.ascontiguousarray(e @ light_frame(d))


def blocks_centre(c: int, b: int, n: int) -> np.ndarray:
    """q coordinate of the centre of each of c blocks of b voxels along an axis of n voxels."""
    lo = np.arange(c) * b
    hi = np.minimum(lo + b, n)
    return 0.5 * (lo + hi).astype(np.float64)


def camera_weight(scene, rho, sig_vox, vs, corner, b):
    """Per block: sum over its voxels of rho x T(voxel -> camera) / (r^2 cos^3) within the view,
    the share of the sum of the pixels a unit source sigma_s S adds (up to a constant)."""
    cam = scene.camera
    cam_q = (np.asarray(cam.origin, np.float64) - corner) / vs
    mask = rho > 0
    T = np.zeros(rho.shape, np.float64)
    _transmittance_to(rho, sig_vox, cam_q, T, mask)
    fwd, right, up = cam.basis()
    I, J, K = np.meshgrid(*(np.arange(s) + 0.5 for s in rho.shape), indexing="ij")
    v = np.stack([I - cam_q[0], J - cam_q[1], K - cam_q[2]], axis=-1)
    zf = v @ fwd
    sx, sy = (v @ right) / zf, (v @ up) / zf
    th = math.tan(math.radians(cam.fov) / 2)
    inview = (zf > 0) & (np.abs(sx) <= th * cam.width / cam.height) & (np.abs(sy) <= th)
    r2 = (v ** 2).sum(-1)
    cos3 = (zf / np.sqrt(r2)) ** 3
    W = np.where(inview & mask, rho * T / (r2 * cos3), 0.0)
    return blocks(W, b) * block_counts(rho.shape, b)


def two_point(A, B):
    """The two-point closure: weights and points (w1, a1, w2, a2) on [-1, 1] with mean A and
    second moment B (the Legendre P1 and P2 of a mixture of HG lobes about d). The variance
    B - A^2 is clamped to [0, 1 - A^2] (B < A^2 cannot come from HG lobes about d: one lobe
    there). Weights 1/2 at A -+ sigma; where a point would leave [-1, 1], that point sits on
    the bound (+1 or -1) and the other at A - var/(1 - A) (resp. A + var/(1 + A)), the weights
    set by the mean (same mean and variance)."""
    A = np.clip(np.asarray(A, np.float64), -1.0, 1.0)
    var = np.clip(np.asarray(B, np.float64) - A * A, 0.0, 1.0 - A * A)
    sig = np.sqrt(var)
    a1, a2 = A - sig, A + sig
    w1 = np.full(A.shape, 0.5)
    hi = a2 > 1.0
    lo = a1 < -1.0
    x = A - var / np.maximum(1.0 - A, 1e-30)                   # partner of a point at +1
    a1 = np.where(hi, x, a1)
    a2 = np.where(hi, 1.0, a2)
    w1 = np.where(hi, (1.0 - A) / np.maximum(1.0 - x, 1e-30), w1)
    y = A + var / np.maximum(1.0 + A, 1e-30)                   # partner of a point at -1
    a1 = np.where(lo, -1.0, a1)
    a2 = np.where(lo, y, a2)
    w1 = np.where(lo, (y - A) / np.maximum(y + 1.0, 1e-30), w1)
    return w1, a1, 1.0 - w1, a2


def hg_lobe(phi, F, g, wo):
    """The source toward the camera of light of fluence ``phi`` and first moment ``F`` (3, ...)
    as one HG lobe about F / |F| with mean cosine |F| / phi: phi f_hg(w_o . F / |F|; g |F| / phi)."""
    fk = np.linalg.norm(F, axis=0)
    mu = (F * wo).sum(0) / np.maximum(fk, 1e-30)
    gm = 0.9999
    return np.maximum(phi, 0.0) * f_hg(mu, np.clip(g * np.minimum(fk / np.maximum(phi, 1e-30), 1.0), -gm, gm))


def model_sources(t, g, d, wo):
    """From MC tallies t (NTAL, cx, cy, cz): the source toward the camera (int L f_hg(w . w_o))
    of one HG lobe about the MC's own first moment F/|F|, of one HG lobe about d with A = F.d/phi,
    and of the two-lobe closure about d with A and B = P2 tally / phi; each with the MC's
    fluence. Lobes about d: a lobe HG(a) about d scatters toward w_o as f_hg(d . w_o; g a)
    (the convention of kernels/render.py walk_lobes + lobe_toward, and of popvol_fields)."""
    phi = t[PHI]
    phim = np.maximum(phi, 1e-30)
    F = t[FX:FZ + 1]
    gm = 0.9999
    one_f = hg_lobe(phi, F, g, wo)
    A = np.clip(np.einsum("i,i...->...", d, F) / phim, -1.0, 1.0)
    B = t[P2D] / phim
    mu_d = np.einsum("i,i...->...", d, wo)
    one_d = phi * f_hg(mu_d, np.clip(g * A, -gm, gm))
    w1, a1, w2, a2 = two_point(A, B)
    two_d = phi * (w1 * f_hg(mu_d, np.clip(g * a1, -gm, gm)) + w2 * f_hg(mu_d, np.clip(g * a2, -gm, gm)))
    # the fluence in each ordinate's cell of the sphere, as a lobe HG(k) about that ordinate: a
    # lobe HG(k) about e scatters toward w_o as f_hg(e . w_o; g k)
    E = ordinates_world(d)
    kernels = []
    for k in KERNELS:
        s = np.zeros_like(phi)
        for o in range(18):
            s += t[ORD + o] * f_hg(np.einsum("i,i...->...", E[o], wo), g * k)
        kernels.append(s)
    # the light scattered once (twice) and the rest, each one HG lobe about its own first moment
    phi1, F1 = t[ONCE], t[ONCE + 1:ONCE + 4]
    phi2, F2 = t[TWICE], t[TWICE + 1:TWICE + 4]

    by_order = hg_lobe(phi1, F1, g, wo) + hg_lobe(phi - phi1, F - F1, g, wo)
    by_order3 = hg_lobe(phi1, F1, g, wo) + hg_lobe(phi2, F2, g, wo) + hg_lobe(phi - phi1 - phi2, F - F1 - F2, g, wo)
    return (one_f, one_d, two_d, *kernels, by_order, by_order3)


#: the anisotropies k of the eighteen-ordinate models (``model_sources``)
KERNELS = (0.0, 0.3, 0.5, 0.7, 0.85)


def popvol_fields(sol, scene):
    """popvol's fields per unit irradiance on the voxels (float64): direct, scattered fluence,
    scattered first moment (3, ...), and the lobes' source toward the camera."""
    m = scene.medium
    d = np.asarray(sol.directions[0], np.float64)
    phi, phia, direct = (np.asarray(a[0, 0], np.float64) for a in (sol.phi, sol.phia, sol.direct))
    phid = np.asarray(sol.phid[0, 0], np.float64)
    J = np.asarray(sol.flux[0, 0], np.float64)
    walk_s = phi - direct
    scat = walk_s + phid
    F = (phia - direct)[None] * d[:, None, None, None] + J
    # the lobes toward the camera (kernels/render.py walk_lobes and lobe_toward)
    vs = geometry(scene)[0]
    cam = np.asarray(scene.camera.origin, np.float64)
    I, Jx, K = np.meshgrid(*(np.arange(s) for s in m.density.shape), indexing="ij")
    pos = np.stack([I, Jx, K]) * vs + np.asarray(m.origin, np.float64)[:, None, None, None]
    wo = cam[:, None, None, None] - pos
    wo /= np.linalg.norm(wo, axis=0)
    g = grey(m.g)
    gmax = 0.9999
    p = np.maximum(phi, 0)
    wdir = np.minimum(np.maximum(direct, 0), p)
    wrest = p - wdir
    grest = np.clip(g * (phia - wdir) / np.maximum(wrest, 1e-30), -gmax, gmax)
    mu_d = np.einsum("i,i...->...", d, wo)
    jn = np.sqrt((J ** 2).sum(0))
    mu_j = np.einsum("i...,i...->...", J, wo) / np.maximum(jn, 1e-30)
    cap = float(sol.lobe_cap[0])
    gd = np.clip(g * np.minimum(jn / np.maximum(phid, 1e-30), cap), -gmax, gmax)
    S = wrest * f_hg(mu_d, grest) + np.maximum(phid, 0) * f_hg(mu_j, gd)
    single = direct * f_hg(mu_d, g)
    return {"direct": direct, "scat": scat, "F": F, "S": S, "single": single, "walk_s": walk_s, "phid": phid, "J": J}


# ----------------------------------------------------------------------------- the study
def study(angle: int | Path, resolutions, n_photons: int, b: int, batches: int, seed: int, solver: str = "sweep") -> None:
    scene = load(angle, resolutions[0], solver)
    m = scene.medium
    rho = np.ascontiguousarray(m.density, np.float32)
    vs, corner = geometry(scene)
    sig_vox = grey(m.scale) * vs
    g = grey(m.g)
    d = np.asarray(scene.lights[0].direction, np.float64)
    d /= np.linalg.norm(d)
    mc = run_mc(scene, n_photons, b, batches, seed, angle)
    tal = mc["tallies"].astype(np.float64)                      # (K, NTAL, cx, cy, cz)
    K = tal.shape[0]
    print(f"\n=== {label(angle)}: sun d = ({d[0]:.3f}, {d[1]:.3f}, {d[2]:.3f}), albedo {grey(m.albedo)}, "
          f"g {g}, sigma_t max {grey(m.scale) * rho.max():.3g}/unit, voxel {vs:.3f}, blocks of {b}^3")
    print(f"MC: {int(mc['photons'])} photons in {K} batches, {float(mc['seconds']):.0f} s on 1 thread, "
          f"{int(mc['real']) / int(mc['photons']):.1f} real and {int(mc['tentative']) / int(mc['photons']):.1f} "
          f"tentative collisions per photon")
    rho_b = blocks(rho, b)
    W_cam = camera_weight(scene, rho, sig_vox, vs, corner, b)
    sel = rho_b > 0
    mc_mean = tal.mean(0)
    cam_q = (np.asarray(scene.camera.origin, np.float64) - corner) / vs
    cen = [blocks_centre(-(-s // b), b, s) for s in rho.shape]
    X, Y, Z = np.meshgrid(*cen, indexing="ij")
    wo_b = np.stack([cam_q[0] - X, cam_q[1] - Y, cam_q[2] - Z])
    wo_b /= np.linalg.norm(wo_b, axis=0)
    for res in resolutions:
        scene = load(angle, res, solver)
        t0 = time.perf_counter()
        sol = popvol.solve(scene)
        ts = time.perf_counter() - t0
        pf = popvol_fields(sol, scene)
        P = {k: blocks(v, b) for k, v in pf.items()}
        tau = -np.log(np.maximum(P["direct"], 1e-300))
        print(f"\n-- {label(angle)}, resolution {res} (popvol solve {ts:.1f} s); blocks with density > 0: {sel.sum()}")
        # the unscattered check
        print("unscattered check, MC / popvol direct (density-weighted):")
        for lo, hi in BANDS[:4]:
            bm = sel & (tau >= lo) & (tau < hi)
            if not bm.any():
                continue
            w = rho_b[bm]
            pop = (w * P["direct"][bm]).sum()
            rk = np.array([(w * tal[k, UNSC][bm]).sum() / pop for k in range(K)])
            print(f"  tau {lo:>4}-{hi:<4} n={bm.sum():6d}  x{rk.mean():.4f} +- {rk.std(ddof=1) / math.sqrt(K):.4f}")
        hdr = (f"{'tau band':>10} {'blocks':>6} {'pop/MC phi_s':>15} {'MC A_d':>7} {'pop A_d':>7} "
               f"{'MC |F|/phi':>10} {'pop |F|/phi':>11} {'pop/MC S_cam':>14} {'diff%':>6} "
               f"{'walkA':>6} {'J.d/pd':>6} {'|J|/pd':>6}")
        print(hdr)
        rows = [(f"{lo}-{hi}" if hi < math.inf else f">{lo}", sel & (tau >= lo) & (tau < hi)) for lo, hi in BANDS]
        rows.append(("all", sel))
        for name, bm in rows:
            if bm.sum() < 8:
                continue
            w = rho_b[bm]
            pop_phi = (w * P["scat"][bm]).sum()
            rk = np.array([pop_phi / (w * tal[k, PHI][bm]).sum() for k in range(K)])
            r = pop_phi / (w * mc_mean[PHI][bm]).sum()
            sk = np.array([(w * P["S"][bm]).sum() / (w * tal[k, SCAM][bm]).sum() for k in range(K)])
            s = (w * P["S"][bm]).sum() / (w * mc_mean[SCAM][bm]).sum()
            Fm = mc_mean[FX:FZ + 1][:, bm]
            Fp = P["F"][:, bm]
            mc_ad = (w * (d @ Fm)).sum() / (w * mc_mean[PHI][bm]).sum()
            pop_ad = (w * (d @ Fp)).sum() / pop_phi
            mc_fn = (w * np.linalg.norm(Fm, axis=0)).sum() / (w * mc_mean[PHI][bm]).sum()
            pop_fn = (w * np.linalg.norm(Fp, axis=0)).sum() / pop_phi
            dfrac = (w * P["phid"][bm]).sum() / pop_phi
            ws = (w * P["walk_s"][bm]).sum()
            walk_a = (w * (d @ (P["F"][:, bm] - P["J"][:, bm]))).sum() / max(ws, 1e-300)
            pd = max((w * P["phid"][bm]).sum(), 1e-300)
            j_d = (w * (d @ P["J"][:, bm])).sum() / pd
            j_n = (w * np.linalg.norm(P["J"][:, bm], axis=0)).sum() / pd
            print(f"{name:>10} {bm.sum():6d} {r:7.3f}+-{rk.std(ddof=1) / math.sqrt(K):.3f} {mc_ad:7.3f} "
                  f"{pop_ad:7.3f} {mc_fn:10.3f} {pop_fn:11.3f} {s:7.3f}+-{sk.std(ddof=1) / math.sqrt(K):.3f} "
                  f"{100 * dfrac:6.1f} {walk_a:6.3f} {j_d:6.3f} {j_n:6.3f}")
        # the second moment about d (MC): how far the light is from one HG lobe about d
        ones = [model_sources(tal[k], g, d, wo_b) for k in range(K)]
        one_m = model_sources(mc_mean, g, d, wo_b)
        phim = np.maximum(mc_mean[PHI], 1e-30)
        A_blk = (d @ mc_mean[FX:FZ + 1].reshape(3, -1)).reshape(phim.shape) / phim
        B_blk = mc_mean[P2D] / phim
        print("second Legendre moment about d (MC; density x fluence weighted): B = P2 tally / phi, an HG "
              "lobe about d has B = A^2; S_cam of one lobe about d (1d) / of the 2-lobe closure (2d) / MC")
        print(f"{'tau band':>10} {'MC A':>6} {'MC B':>6} {'A^2':>6} {'<A^2>':>6} {'B<A^2%':>6} "
              f"{'1F/MC S':>13} {'1d/MC S':>13} {'2d/MC S':>13} {'img%':>5}")
        img_all = (W_cam[sel] * mc_mean[SCAM][sel]).sum()
        for name, bm in rows:
            if bm.sum() < 8:
                continue
            w = rho_b[bm]
            wp = (w * mc_mean[PHI][bm]).sum()
            Ab = (w * mc_mean[PHI][bm] * A_blk[bm]).sum() / wp
            Bb = (w * mc_mean[P2D][bm]).sum() / wp
            A2 = (w * mc_mean[PHI][bm] * A_blk[bm] ** 2).sum() / wp
            below = 100 * (w * mc_mean[PHI][bm] * (B_blk[bm] < A_blk[bm] ** 2)).sum() / wp
            cols = []
            for j in range(3):
                r = (w * one_m[j][bm]).sum() / (w * mc_mean[SCAM][bm]).sum()
                rk = np.array([(w * ones[k][j][bm]).sum() / (w * tal[k, SCAM][bm]).sum() for k in range(K)])
                cols.append(f"{r:7.3f}+-{rk.std(ddof=1) / math.sqrt(K):.3f}")
            img = 100 * (W_cam[bm] * mc_mean[SCAM][bm]).sum() / img_all
            print(f"{name:>10} {Ab:6.3f} {Bb:6.3f} {Ab * Ab:6.3f} {A2:6.3f} {below:6.1f} " + " ".join(cols)
                  + f" {img:5.1f}")
        # image-level estimate
        Wb = W_cam[sel]
        single = (Wb * P["single"][sel]).sum()
        ms_pop = (Wb * P["S"][sel]).sum()

        def image(tk, models):
            """Multiple-scattering sums over the view: MC, popvol lobes, magnitude, 1-lobe(F),
            1-lobe about d, 2-lobe about d."""
            ph = np.maximum(tk[PHI], 1e-30)
            ms_mc = (Wb * tk[SCAM][sel]).sum()
            ms_mag = (Wb * (P["scat"] * tk[SCAM] / ph)[sel]).sum()
            # popvol's scattered light less the MC's once-scattered light, each one lobe
            phi1, F1 = tk[ONCE], tk[ONCE + 1:ONCE + 4]
            hyb = (hg_lobe(phi1, F1, g, wo_b) + hg_lobe(np.maximum(P["scat"] - phi1, 0.0), P["F"] - F1, g, wo_b))
            return np.array([ms_mc, ms_pop, ms_mag] + [(Wb * x[sel]).sum() for x in models] + [(Wb * hyb[sel]).sum()])

        im = image(mc_mean, one_m)
        imk = np.array([image(tal[k], ones[k]) for k in range(K)])
        names = (["lobes", "magnitude", "1-lobe(MC F)", "1-lobe about d (MC A)", "2-lobe about d (MC A, B)"]
                 + [f"18 ordinates, HG({k}) each" for k in KERNELS] + ["1-lobe(MC F) per order 1, >= 2", "1-lobe(MC F) per order 1, 2, >= 3",
                    "popvol's lobe less the MC's order 1, + its lobe"])
        tot = single + im[0]
        print(f"image estimate (sum over the view; single scattering {100 * single / tot:.1f} % of the MC's), "
              f"pop/MC, multiple only | total (single + multiple):")
        for j, nm in enumerate(names, start=1):
            rm = imk[:, j] / imk[:, 0]
            rt = (single + imk[:, j]) / (single + imk[:, 0])
            print(f"  {nm:>26}: x{im[j] / im[0]:.3f}+-{rm.std(ddof=1) / math.sqrt(K):.3f} | "
                  f"x{(single + im[j]) / tot:.3f}+-{rt.std(ddof=1) / math.sqrt(K):.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", default="64,128", help="popvol resolutions, comma-separated")
    ap.add_argument("--angles", default="0,90,180")
    ap.add_argument("--photons", type=int, default=400_000)
    ap.add_argument("--block", type=int, default=2, help="tally blocks of b^3 voxels")
    ap.add_argument("--batches", type=int, default=4, help="independent batches, for the MC's noise")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--solver", default="sweep", help="popvol's experimental.solver (e.g. ordinates)")
    ap.add_argument("--scene", default=None, help="a scene lit by one sun, in place of --angles")
    a = ap.parse_args()
    scene = Path(a.scene).resolve() if a.scene else None
    os.chdir(ROOT)
    res = [int(x) for x in a.resolution.split(",")]
    for angle in [scene] if scene else (int(x) for x in a.angles.split(",")):
        study(angle, res, a.photons, a.block, a.batches, a.seed, a.solver)


if __name__ == "__main__":
    main()
