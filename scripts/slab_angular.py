"""The scattered light's angular shape inside a front-lit slab: what one HG lobe per cell makes
of it, against the plane-parallel Monte Carlo.

The eighteen-ordinate walk keeps, per cell, the scattered light's fluence phi and first moment
F, and the gathered last bounce emits it as one lobe f_hg(w . F/|F|; g a1), a1 = |F| / phi (the
HG lobe of mean cosine a1 convolved with the phase function: docs/METHOD.md, "Gathered last
bounce"). This script measures how far that lobe's emission is from the true emission, sigma_s
times the scattered radiance convolved with HG_g, direction by direction, layer by layer, in a
slab lit along its normal by a collimated beam: tests/montecarlo.py's slab_legendre_mc gives the
radiance's Legendre moments <P_l> (l <= 48; independent of popvol), from which the true emission
toward the cosine mu_e to the beam is sum_l (2 l + 1) <P_l> g^l P_l(mu_e) / 4 pi. One lobe has
the moments a1^l instead. The walk (popvol's, on a slab of --cells layers, --width times as
wide as deep each way; its centre's columns) gives its own a1. Prints a Markdown table: per
layer, the Monte Carlo's scattered fluence and <P_1>, <P_2>, <P_3>, the walk's fluence and a1,
and the ratio of the one lobe's emission (with the walk's a1) to the true one at mu_e = 1, 0.9,
0.7, 0.5, 0, -0.5, -1.

    python scripts/slab_angular.py [--tau 8] [--g 0.877] [--albedo 0.99] [--cells 16] [--width 9]
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.polynomial import legendre

from popvol.walk import direct_fluence, medium_factors, scatter_factor, walk_box

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from montecarlo import slab_legendre_mc       # noqa: E402

LMAX = 48
MU_E = np.array([1.0, 0.9, 0.7, 0.5, 0.0, -0.5, -1.0])


def emission(moments: np.ndarray, g: float) -> np.ndarray:
    """4 pi times the emission toward MU_E of unit-fluence light of Legendre moments
    ``moments`` (<P_l>, l = 0..LMAX) scattered by HG_g (its Legendre coefficients are g^l)."""
    l = np.arange(len(moments))
    return legendre.legval(MU_E, (2 * l + 1) * moments * g ** l)


def walk_moments(tau: float, albedo: float, g: float, cells: int, width: float) -> tuple[np.ndarray, np.ndarray]:
    """The eighteen-ordinate walk's scattered fluence and a1 = F_d / phi per layer, in the
    centre (a column an eighth of the depth across) of a slab of optical thickness tau, unit
    depth and ``width`` times as wide each way, lit along its normal (the light that leaves
    through the sides is lost to the centre only where it would come back in a wider slab)."""
    h = 1.0 / cells
    n = int(round(width * cells))
    shape = (cells, n, n)
    sigma_t = np.full(shape, tau, np.float32)
    sigma_s = (albedo * sigma_t).astype(np.float32)
    Th, Dh = medium_factors(sigma_t, sigma_s, np.full(shape, g, np.float32), h, "poisson")
    r = walk_box(Th, Dh, np.full(shape[1:], h * h, np.float32), 1.0, h, solver="ordinates", tolerance=1e-5,
                 scatter=scatter_factor(sigma_s, h), ordinates=18)
    half = max(cells // 16, 1)
    centre = slice(n // 2 - half, n // 2 + half)
    direct = direct_fluence(sigma_t, h)[:, centre, centre].mean(axis=(1, 2))
    phi = r.phi[:, centre, centre].mean(axis=(1, 2)) - direct
    flux = r.flux[0][:, centre, centre].mean(axis=(1, 2)) - direct
    return phi, flux / phi


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tau", type=float, default=8.0, help="the slab's optical thickness")
    ap.add_argument("--g", type=float, default=0.877)
    ap.add_argument("--albedo", type=float, default=0.99)
    ap.add_argument("--cells", type=int, default=16, help="the walk's layers (and the Monte Carlo's)")
    ap.add_argument("--width", type=float, default=9.0,
                    help="the walk's slab, in depths across (at 9 its centre no longer changes with it)")
    ap.add_argument("--photons", type=int, default=300_000)
    args = ap.parse_args()
    mc = slab_legendre_mc(args.albedo, args.g, args.tau, args.cells, lmax=LMAX, n_photons=args.photons, seed=1)
    phi_mc = mc[:, 0]
    moments = mc / phi_mc[:, None]
    phi_w, a1_w = walk_moments(args.tau, args.albedo, args.g, args.cells, args.width)
    l = np.arange(LMAX + 1)
    print(f"Slab of optical thickness {args.tau:g}, albedo {args.albedo:g}, g {args.g:g}, {args.cells} layers; "
          f"one lobe's emission / the true one toward mu_e = {', '.join(f'{m:g}' for m in MU_E)}\n")
    print("| depth | Monte Carlo: scattered fluence, <P_1> / <P_2> / <P_3> | walk: fluence, a1 | one lobe / truth |")
    print("|---|---|---|---|")
    for k in range(0, args.cells, max(args.cells // 10, 1)):
        truth = emission(moments[k], args.g)
        one = emission(np.clip(a1_w[k], -0.999, 0.999) ** l, args.g)
        print(f"| {(k + 0.5) / args.cells:.2f} | {phi_mc[k]:.3f}, {moments[k, 1]:.3f} / {moments[k, 2]:.3f} / "
              f"{moments[k, 3]:.3f} | {phi_w[k]:.3f}, {a1_w[k]:.3f} | "
              + " / ".join(f"{x:.2f}" for x in one / truth) + " |", flush=True)


if __name__ == "__main__":
    main()
