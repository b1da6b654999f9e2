"""Warm start between the frames of an animation: what it saves and that it changes nothing.

    .venv/bin/python scripts/warm_start_study.py [--frames 8] [--dt 0.041667] [--cut 5]

A slowly moving sequence: the procedural cumulus (medium.time advancing by ``--dt`` seconds a
frame, 24 frames per second by default; at 64 cells the wind moves the detail by about 0.05
voxel a frame) lit by the demo's sun and 3-light sky, method resolution 64. Every frame is
solved cold (``popvol.solve(scene)``) and warm (``popvol.solve(scene, warm=previous warm
solution)``) and rendered from both. Frame ``--cut`` switches to another seed (a cut: a
different cloud), warm-started from the frame before it.

Per frame: the walk's sweeps and the conjugate-gradient iterations summed over the domains,
cold and warm; how many domains were warm-started; solve seconds; and how far the warm frame
is from the cold one: relMSE of the images (popvol.metrics.relmse, scale-free), and the largest
difference of the diffusion fluence phi_d and flux J over the largest value (the walk's fields
are bitwise the same: the walk always starts cold); "motion" is the relMSE of the cold image
against the previous frame's, how much the sequence moves. Seconds are wall clock on a shared
machine: the iteration counts are the measure.

Why a warm start saves no more: for each warm-started domain, the initial residual
||b - A x0|| / ||b|| of the warm start (x0 the previous frame's phi, scaled as pcg does), split
into the cells next to a change of the diffusion region (cells that joined or left it, and
their neighbours) and the rest, beside the change of the source ||b - b_prev|| / ||b||.

Then the check behind that choice (see pipeline.solve): the walk is not additive. For the first
frame's sun, it walks the light of a checkerboard half of the face and of the other half
separately and compares their sum with the whole light walked at once, next to the change that
the tolerance itself makes (1e-3 against 1e-6): a warm start that propagates a correction to the
previous frame's state relies on that additivity.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import popvol
from popvol import diffusion
from popvol.metrics import relmse
from popvol.walk import handover_factor, medium_factors, walk_box


def scene(t: float, seed: int, resolution: int, width: int, height: int):
    return popvol.scene_from_dict({
        "medium": {"type": "procedural", "style": "cumulus", "resolution": resolution, "seed": seed,
                   "time": t, "extent": 2.0, "scale": 40.0, "albedo": 0.99, "g": 0.85},
        "lights": [{"type": "directional", "direction": [-0.9, -0.4, -0.35], "irradiance": [5.0, 4.85, 4.5]},
                   {"type": "sky", "zenith": [0.05, 0.12, 0.35], "horizon": [0.25, 0.33, 0.45],
                    "ground": [0.12, 0.13, 0.15], "lights": 3}],
        "camera": {"origin": [0.0, 0.1, 2.4], "target": [0.0, 0.72, 0.0], "fov": 40.0,
                   "width": width, "height": height},
        "method": {"resolution": resolution}})


def timed_solve(s, warm=None):
    t0 = time.perf_counter()
    sol = popvol.solve(s, warm=warm)
    return sol, time.perf_counter() - t0


def max_rel(a, b) -> float:
    scale = float(np.abs(b).max())
    return float(np.abs(a - b).max()) / scale if scale > 0 else 0.0


def totals(sol) -> tuple[int, int, int]:
    d = sol.stats()["domains"]
    return (sum(x["iterations"] for x in d), sum(x["diffusion_iterations"] for x in d),
            sum(bool(x["warm"]) for x in d))


class ResidualParts:
    """Wraps diffusion.pcg while installed: for each warm start, the parts of its initial residual
    (module docstring), by the domain's call order within a solve."""

    def __init__(self):
        self.pcg, self.rows, self.prev_b, self.index = diffusion.pcg, [], {}, 0

    def __enter__(self):
        diffusion.pcg = self.record
        return self

    def __exit__(self, *exc):
        diffusion.pcg = self.pcg

    def record(self, D, sah3, mask, h, b, rtol, max_iterations, bw=None, x0=None):
        """Keeps the arguments (the parts are worked out after the timed solve: :meth:`parts`)."""
        i, self.index = self.index, self.index + 1
        if x0 is not None:
            self.rows.append((D, sah3, mask, h, b, bw, x0, self.prev_b.get(i)))
        self.prev_b[i] = b
        return self.pcg(D, sah3, mask, h, b, rtol, max_iterations, bw, x0)

    def parts(self):
        """Per warm start: (whole, near a region change, elsewhere, cells near, region cells,
        source change), relative to ||b|| (the source change NaN where the grid changed)."""
        for D, sah3, mask, h, b, bw, x0, pb in self.rows:
            x = diffusion.fill_gaps(x0, mask)
            space = diffusion.RowSpace(D, sah3, mask, h, np.ones(b.shape, np.float32) if bw is None else bw)
            Axv = space.vector(np.float64)
            space.apply(space.pack(x, np.float64), Axv)
            Ax = space.unpack(Axv)
            xAx = float(np.dot(x.ravel().astype(np.float64), Ax.ravel()))
            scale = float(np.dot(x.ravel().astype(np.float64), b.ravel())) / xAx if xAx > 0 else 0.0
            r = b - scale * Ax.astype(np.float64)
            changed = mask != (x0 != 0)
            near = changed.copy()
            for axis in range(3):
                near |= np.roll(changed, 1, axis) | np.roll(changed, -1, axis)
            near &= mask
            bn = float(np.linalg.norm(b))
            db = float(np.linalg.norm(b - pb)) / bn if pb is not None and pb.shape == b.shape else float("nan")
            yield (np.linalg.norm(r) / bn, np.linalg.norm(r[near]) / bn, np.linalg.norm(r[~near]) / bn,
                   int(near.sum()), int(mask.sum()), db)


def walk_additivity(s) -> None:
    """The walk's superposition defect against the change its tolerance makes."""
    m, light = s.method, s.lights[0]
    dom = light.domain(s.medium, m)
    st, ss, g = dom.resample(s.medium, 0)
    Th, Dh = medium_factors(st, ss, g, dom.h, m.decay)
    ho = (m.handover_scale, handover_factor(st, ss, g, dom.h))
    face = np.full(dom.shape[1:], dom.h ** 2, np.float32)

    def walk(inj, tol):
        return walk_box(Th, Dh, inj.astype(np.float32), 1.0, dom.h, m.rule, m.solver, tol, 0, handover=ho)

    def rel(a, b):
        return (np.linalg.norm(a.phi - b.phi) / np.linalg.norm(b.phi),
                np.linalg.norm(a.handed[0] - b.handed[0]) / np.linalg.norm(b.handed[0]))

    ref = walk(face, 1e-6)
    half = np.indices(face.shape).sum(axis=0) % 2 == 0
    a, b = walk(np.where(half, face, 0), 1e-6), walk(np.where(half, 0, face), 1e-6)
    summed = dataclasses.replace(ref, phi=a.phi + b.phi, handed=a.handed + b.handed)
    print(f"\nwalk of the sun, frame 0 ({'x'.join(map(str, dom.shape))} cells): relative L2 difference of "
          "phi and of the handed-over power Q0")
    for name, (x, y) in (("tolerance 1e-3 against 1e-6", rel(walk(face, 1e-3), ref)),
                         ("two halves walked apart, summed, against together", rel(summed, ref))):
        print(f"  {name:52s} phi {x:.1e}   Q0 {y:.1e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--dt", type=float, default=1 / 24, help="seconds of medium.time per frame")
    ap.add_argument("--t0", type=float, default=1.0)
    ap.add_argument("--cut", type=int, default=5, help="frame that switches to another seed (-1: none)")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    args = ap.parse_args()

    popvol.solve(scene(args.t0, 7, 16, 8, 8))          # compile the kernels outside the timings
    print(f"procedural cumulus, medium and method resolution {args.resolution}, sun + 3-light sky "
          f"(4 domains), dt = {args.dt:g} s a frame, cut to seed 3 at frame {args.cut}")
    print(f"{'frame':>5} {'seed':>4} {'sweeps c/w':>11} {'CG c/w':>9} {'warm':>4} {'s cold':>7} {'s warm':>7}"
          f" {'relMSE':>8} {'dphi_d':>8} {'dJ':>8} {'motion':>8}")
    prev = prev_cold_img = None
    sums = np.zeros(4)
    parts = ResidualParts()
    for f in range(args.frames):
        seed = 3 if 0 <= args.cut <= f else 7
        s = scene(args.t0 + f * args.dt, seed, args.resolution, args.width, args.height)
        cold, tc = timed_solve(s)
        parts.index = 0
        with parts:
            warm, tw = timed_solve(s, prev)
        ic, iw = popvol.render(s, cold), popvol.render(s, warm)
        assert all(np.array_equal(getattr(cold, n), getattr(warm, n)) for n in ("phi", "phia", "direct"))
        (sc, cc, _), (sw, cw, nw) = totals(cold), totals(warm)
        print(f"{f:5d} {seed:4d} {sc:5d}/{sw:<5d} {cc:4d}/{cw:<4d} {nw:2d}/{len(warm.domains)} {tc:7.3f} {tw:7.3f}"
              f" {relmse(iw, ic):8.1e} {max_rel(warm.phid, cold.phid):8.1e} {max_rel(warm.flux, cold.flux):8.1e}"
              f" {relmse(prev_cold_img, ic) if prev_cold_img is not None else 0.0:8.1e}")
        if f == args.cut and prev_cold_img is not None:
            print(f"      cut: the cold image moved by relMSE {relmse(prev_cold_img, ic):.1e} from the previous "
                  f"frame's; the warm one is {relmse(iw, ic):.1e} from the cold one: no smear")
        elif f > 0:
            sums += (cc, cw, tc, tw)
        prev, prev_cold_img = warm, ic
    if sums[1] > 0:
        print(f"frames 1..{args.frames - 1} but the cut: CG iterations {sums[0]:.0f} cold, {sums[1]:.0f} warm "
              f"({sums[0] / sums[1]:.2f}x fewer); solve seconds {sums[2]:.2f} cold, {sums[3]:.2f} warm")
    print("\nthe warm starts' initial residual ||b - A x0|| / ||b|| (frames but the first, by domain: whole, on the "
          "cells next to a region change, elsewhere; those cells, region cells; the source's change ||b - b_prev|| / ||b||)")
    for r, near, rest, n_near, n, db in parts.parts():
        print(f"  {r:5.2f} = {near:5.2f} near ({n_near} of {n} cells) + {rest:5.2f} elsewhere;   "
              f"source change {db:5.2f}")
    walk_additivity(scene(args.t0, 7, args.resolution, args.width, args.height))


if __name__ == "__main__":
    main()
