"""A narrow collimated beam entering a thick homogeneous cube (optical depth 10, albedo 0.99,
g 0.8): transmitted, reflected and side-escaping fractions and the lateral spread of the
fluence against a 3-D Monte Carlo random walk, at two grid resolutions.

POP's rules as written need not converge under grid refinement: lateral transport is a walk
whose step is the cell size (docs/METHOD.md, "Diffusion stage"). They do not; the walk test below
is a change detector that pins that known limitation at its measured behaviour (figures in
docs/ACCURACY_NOTES.md). The one-lobe sweeps with the isotropic stage done as diffusion (what
point lights use, and suns with ``solver = "sweep"``) converge, and so does the six-ordinate walk
(the default for suns); both are held to the Monte Carlo here.
"""
import numpy as np
import pytest

from popvol.diffusion import solve_diffusion
from popvol.walk import handover_factor, medium_factors, scatter_factor, walk_box
from popvol.scene import Method

TAU, ALBEDO, G, HALFWIDTH = 10.0, 0.99, 0.8, 0.125


def pop_beam(n, rule="moment", decay="poisson", solver="sweep", isotropic="walk", handover=0.5, ordinates=6):
    """The cube [0,1]^3 as an n^3 domain along +x; the beam enters the centre of the x = 0 face
    (``ordinates``: the directions of the "ordinates" solver, 6 or 18)."""
    h = 1.0 / n
    shape = (n, n, n)
    sigma_t = np.full(shape, TAU, np.float32)
    sigma_s, g = ALBEDO * sigma_t, np.full(shape, G, np.float32)
    Th, Dh = medium_factors(sigma_t, sigma_s, g, h, decay)
    c = (np.arange(n) + 0.5) * h - 0.5                     # lateral cell-centre offsets
    inside = (np.abs(c) < HALFWIDTH)
    inj = (inside[:, None] & inside[None, :]).astype(np.float32) * h * h
    hand = (handover, handover_factor(sigma_t, sigma_s, g, h)) if isotropic == "diffusion" else None
    r = walk_box(Th, Dh, inj, 1.0, h, rule=rule, solver=solver, tolerance=1e-5, max_iterations=100000,
                 handover=hand, scatter=scatter_factor(sigma_s, h), ordinates=ordinates)
    if hand is not None:                                   # the pipeline's diffusion stage
        r.diffusion = solve_diffusion(*r.handed, sigma_t, sigma_s, g, h, rtol=1e-6)
        r.budget.add_diffusion(r.diffusion)
    b = r.budget
    r2 = c[:, None] ** 2 + c[None, :] ** 2
    phi = r.phi.astype(np.float64)
    if r.diffusion is not None:                            # same grid (n <= diffusion resolution)
        phi = phi + r.diffusion.phi
    return {"transmitted": b.transmitted / b.injected, "reflected": b.reflected / b.injected,
            "side": b.side / b.injected, "absorbed": b.absorbed / b.injected,
            "r2_mean": float((phi * r2).sum() / phi.sum()), "iterations": r.iterations}


@pytest.fixture(scope="module")
def mc():
    from montecarlo import cube_beam_mc
    return cube_beam_mc(TAU, ALBEDO, G, HALFWIDTH, n_photons=100_000, seed=3)


@pytest.fixture(scope="module")
def pop():
    """The walk alone (the papers' POP with the moment rule)."""
    return {n: pop_beam(n) for n in (16, 32)}


@pytest.fixture(scope="module")
def ordinates():
    """The six-ordinate walk, alone (experimental.solver = "ordinates")."""
    return {n: pop_beam(n, solver="ordinates") for n in (16, 32)}


@pytest.fixture(scope="module")
def one_lobe():
    """The one-lobe sweeps with the diffusion stage at the default rule, decay and hand-over
    scale (what point lights use, and suns with solver = "sweep")."""
    m = Method()
    return {n: pop_beam(n, m.rule, m.decay, "sweep", "diffusion", m.handover_scale) for n in (32, 64)}


def _report(mc, pop):
    keys = ("transmitted", "reflected", "side", "absorbed", "r2_mean")
    lines = ["            " + " ".join(f"{k:>11}" for k in keys)]
    lines.append("MC          " + " ".join(f"{mc[k]:11.4f}" for k in keys))
    for n, p in pop.items():
        lines.append(f"POP n={n:<4}  " + " ".join(f"{p[k]:11.4f}" for k in keys))
    return "\n".join(lines)


def _assert_converges(mc, results, move, bound):
    """Every fraction moves by < ``move`` between the two grids of ``results`` and lies within
    ``bound`` of Monte Carlo on the finer one; returns the finer one's figures."""
    report = _report(mc, results)
    print(report)
    coarse, fine = (results[n] for n in sorted(results))
    for k in ("transmitted", "reflected", "side", "absorbed"):
        assert abs(fine[k] - coarse[k]) < move, (k, report)
        assert abs(fine[k] - mc[k]) < bound, (k, report)
    return fine


def test_beam_energy_is_conserved(pop, one_lobe, ordinates):
    for p in list(pop.values()) + list(one_lobe.values()) + list(ordinates.values()):
        assert p["transmitted"] + p["reflected"] + p["side"] + p["absorbed"] == pytest.approx(1.0, abs=2e-5)


def test_one_lobe_sweeps_with_diffusion_converge_and_stay_near_monte_carlo(mc, one_lobe):
    """The one-lobe sweeps (moment + poisson, diffusion stage, hand-over scale 2) change by
    < 0.02 in every fraction from 32^3 to 64^3 and lies within 0.15 of Monte Carlo (measured at
    64^3: T 0.234, R 0.231, side 0.437, absorbed 0.098 against 0.154, 0.185, 0.560, 0.101; the
    side escape is still 22 % low). It converges from above: side 0.480, 0.463, 0.449, 0.442,
    0.437 at 16, 24, 32, 48, 64 cells, so the coarse 16^3 -> 32^3 step moves it by 0.032; a
    larger scale hands over sooner and converges faster (scale 6: 0.490 -> 0.493,
    test_diffusion.py) but made the WDAS cloud darker (docs/ACCURACY.md)."""
    fine = _assert_converges(mc, one_lobe, move=0.02, bound=0.15)
    assert fine["side"] > 0.35                     # the walk alone: 0.013 (below)


def test_walk_alone_does_not_converge(mc, pop):
    """The papers' POP (moment rule, no diffusion stage): lateral transport is a walk with step h,
    so side escape and lateral spread fall as the grid is refined, away from Monte Carlo (0.56
    and 0.074). Measured: side 0.068 -> 0.013, spread 0.045 -> 0.031 from 16^3 to 32^3.
    A change detector of that known limitation, not an accuracy test: its bounds (the side
    escape at least halves and stays below 0.1) come from those measured figures, and it fails
    when a change makes the walk's lateral transport converge (or much less resolution-bound)."""
    print(_report(mc, pop))
    coarse, fine = pop[16], pop[32]
    assert fine["side"] < 0.5 * coarse["side"] < 0.1 < mc["side"]
    assert fine["r2_mean"] < coarse["r2_mean"] < mc["r2_mean"]


def test_six_ordinates_converge_to_monte_carlo(mc, ordinates):
    """The default for suns. With one lobe per lattice direction, light sent sideways keeps going
    sideways, so the walk alone converges under refinement and to the Monte Carlo: every fraction within 0.025
    of it at 32^3 and moving by < 0.01 from 16^3 (measured: T 0.157, R 0.188, side 0.544,
    absorbed 0.111 at 32^3 against 0.154, 0.185, 0.560, 0.101; 16^3 within 0.005 of that), and
    the lateral spread within 20 % (0.064 against 0.074), where the one-lobe walk gives side
    0.013 and spread 0.031 (above)."""
    fine = _assert_converges(mc, ordinates, move=0.01, bound=0.025)
    assert fine["r2_mean"] == pytest.approx(mc["r2_mean"], rel=0.2), _report(mc, ordinates)


def test_beam_monte_carlo_oracle_conserves_energy(mc):
    total = mc["transmitted"] + mc["reflected"] + mc["side"] + mc["absorbed"]
    assert total == pytest.approx(1.0, abs=0.01)     # roulette makes the sum unbiased, not exact
