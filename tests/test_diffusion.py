"""The diffusion stage (popvol/diffusion.py): its operator against a sparse matrix assembled
here from the finite-volume formulas, its solver against scipy's direct solve, energy
conservation, the analytic point-source solution of the diffusion equation, and the narrow-beam
Monte Carlo of test_beam.py, where the hybrid walk + diffusion converges under refinement."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from popvol import diffusion
from popvol.kernels import diffusion as K
from popvol.walk import handover_factor, medium_factors, walk_box


def random_medium(rng, shape, empty=0.2):
    sigma_t = rng.uniform(0.5, 20.0, shape) * (rng.random(shape) > empty)
    sigma_s = sigma_t * rng.uniform(0.5, 1.0, shape)
    g = rng.uniform(-0.3, 0.9, shape)
    return sigma_t.astype(np.float32), sigma_s.astype(np.float32), g.astype(np.float32)


def assemble(D, sah3, mask, h, bw=None):
    """The matrix of kernels/diffusion.py's balance, written out cell by cell (boundary faces
    weighted by bw, default 1)."""
    bw = np.ones(D.shape) if bw is None else bw
    shape = D.shape
    idx = -np.ones(shape, int)
    cells = list(zip(*np.nonzero(mask)))
    for n, c in enumerate(cells):
        idx[c] = n
    A = sp.lil_matrix((len(cells), len(cells)))
    for n, (k, i, j) in enumerate(cells):
        A[n, n] += sah3[k, i, j]
        for dk, di, dj in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            q = (k + dk, i + di, j + dj)
            inside = all(0 <= q[a] < shape[a] for a in range(3))
            Dp = float(D[k, i, j])
            if inside and mask[q]:
                Dq = float(D[q])
                G = h * 2 * Dp * Dq / (Dp + Dq)          # harmonic mean, face h^2 over distance h
                A[n, n] += G
                A[n, idx[q]] -= G
            else:
                A[n, n] += bw[k, i, j] * h * h * 2 * Dp / (4 * Dp + h)  # Marshak: J = phi_face / 2
    return A.tocsr(), cells


def test_operator_and_solver_match_a_sparse_direct_solve(rng):
    shape, h = (7, 6, 5), 0.1
    st, ss, g = random_medium(rng, shape)
    D, sah3, mask = diffusion.coefficients(st, ss, g, h)
    bw = rng.uniform(0.57, 1.0, shape).astype(np.float32)
    A, cells = assemble(D, sah3, mask, h, bw)
    assert abs(A - A.T).max() < 1e-12                     # symmetric
    x = rng.random(shape) * mask
    space = diffusion.RowSpace(D, sah3, mask, h, bw)       # A on the region's cells alone
    out = space.vector(np.float64, padding=7.0)
    space.apply(space.pack(x, np.float64), out)
    xv = np.array([x[c] for c in cells])
    np.testing.assert_allclose([space.unpack(out)[c] for c in cells], A @ xv, rtol=1e-6, atol=1e-9)
    assert np.all(space.unpack(out)[~mask] == 0)
    assert np.all(out.reshape(-1)[len(cells):] == 7.0)      # the padding is left as it was
    np.testing.assert_array_equal(space.unpack(space.pack(x, np.float64)), x)
    b = rng.random(shape) * mask
    phi, it, res = diffusion.pcg(D, sah3, mask, h, b, 1e-10, 10_000, bw)
    direct = spla.spsolve(A.tocsc(), np.array([b[c] for c in cells]))
    np.testing.assert_allclose([phi[c] for c in cells], direct, rtol=1e-7, atol=1e-12)
    assert res <= 1e-10


def test_the_solve_refuses_what_does_not_fit_in_memory(rng, monkeypatch):
    """diffusion.RowSpace checks its rows' memory before allocating them: with (pretend) 1 MB
    available a 7x6x5 problem still fits, one of 64^3 cells does not, and the error names the
    setting to lower, in one line."""
    import popvol.domains
    from popvol.errors import PopvolError
    monkeypatch.setattr(popvol.domains, "available_memory", lambda: 1e6)
    st, ss, g = random_medium(rng, (7, 6, 5))
    D, sah3, mask = diffusion.coefficients(st, ss, g, 0.1)
    diffusion.RowSpace(D, sah3, mask, 0.1, np.ones(mask.shape, np.float32))
    big = np.ones((64, 64, 64))
    D, sah3, mask = diffusion.coefficients(big, 0.9 * big, 0.5 * big, 0.1)
    with pytest.raises(PopvolError, match=r"^method.diffusion_resolution: the diffusion solve's 262144 region cells needs about [^\n]*lower it$"):
        diffusion.RowSpace(D, sah3, mask, 0.1, np.ones(mask.shape, np.float32))


def test_boundary_weight_is_the_smooth_surfaces_share_of_the_staircase():
    """1 / |n|_1 for the unit normal n: 1 on a face-aligned plane, 1/sqrt(2) on a plane at 45
    degrees to two axes, 1/sqrt(3) on one at equal angles to all three (away from the grid's
    edges, where the smoothing sees the zero padding), in the region cells next to the plane."""
    n = 24
    c = np.arange(n) + 0.5
    X, Y, Z = np.meshgrid(c, c, c, indexing="ij")
    for normal, expected in (((1, 0, 0), 1.0), ((1, 1, 0), 2 ** -0.5), ((1, 1, 1), 3 ** -0.5)):
        s = np.dot(np.stack([X, Y, Z], -1) - n / 2, np.array(normal, float))
        mask = s < 0
        w = diffusion.boundary_weight(mask)
        band = mask & (s > -1.5) & np.all((np.stack([X, Y, Z]) > 5) & (np.stack([X, Y, Z]) < n - 5), axis=0)
        assert band.sum() > 50
        np.testing.assert_allclose(w[band], expected, rtol=0.03)


@pytest.mark.parametrize("R,sigma_tr,sigma_a", [(12, 1.0, 0.0005), (12, 0.3, 0.0005), (20, 1.0, 0.0002),
                                                (12, 1.0, 0.01)])
def test_sphere_with_a_uniform_source_matches_the_analytic_solution(R, sigma_tr, sigma_a):
    """A homogeneous sphere (radius R cells, g = 0) with a uniform source and Marshak boundary:
    phi(r) = q / sigma_a (1 - C sinh(kr) / (kr)), k = sqrt(sigma_a / D), C from phi + 2 D phi' = 0
    at R. Its absorbed share of the source (set by the leak when sigma_a is small) within 7 %.
    Measured +4 to +6 % with the boundary weight; -5 to -15 % without it (the staircase of cell
    faces leaks through about 1.5x the sphere's area)."""
    n = 2 * R + 4
    c = (np.arange(n) + 0.5) - n / 2
    X, Y, Z = np.meshgrid(c, c, c, indexing="ij")
    inside = X**2 + Y**2 + Z**2 < R**2
    sigma_t = np.where(inside, sigma_tr, 0.0).astype(np.float32)
    sigma_s = np.where(inside, sigma_tr - sigma_a, 0.0).astype(np.float32)
    Q0 = inside.astype(np.float32)
    r = diffusion.solve_diffusion(Q0, np.zeros_like(Q0), sigma_t, sigma_s, np.zeros_like(sigma_t), 1.0, rtol=1e-6)
    D = 1 / (3 * sigma_tr)
    k = np.sqrt(sigma_a / D)
    f = np.sinh(k * R) / (k * R)
    fp = (k * R * np.cosh(k * R) - np.sinh(k * R)) / (k * R * R)
    C = 1 / (f + 2 * D * fp)
    absorbed = 1 - C * (4 * np.pi / k**3) * (k * R * np.cosh(k * R) - np.sinh(k * R)) / (4 / 3 * np.pi * R**3)
    assert r.absorbed / r.source == pytest.approx(absorbed, rel=0.07)


def test_power_balance_source_equals_absorbed_plus_leaked(rng):
    shape, h = (10, 9, 8), 0.05
    st, ss, g = random_medium(rng, shape)
    Q0 = (rng.random(shape) * (st > 0)).astype(np.float32)
    Q1 = (Q0 * rng.uniform(-0.5, 0.5, shape)).astype(np.float32)
    r = diffusion.solve_diffusion(Q0, Q1, st, ss, g, h, rtol=1e-10)
    assert r.source == pytest.approx(r.absorbed + sum(r.leaked), rel=1e-6)
    assert r.phi.min() >= -1e-6 * r.phi.max()     # the dipole may dent, not flip, the fluence


def test_point_source_follows_the_analytic_diffusion_solution():
    """An isotropic point source of power P in an infinite medium: phi(r) = P exp(-r / L) /
    (4 pi D r), L = sqrt(D / sigma_a). The cube is 12 L wide, so its boundary hardly matters."""
    n, side = 49, 4.0
    h = side / n
    sigma_a, sigma_s, g = 1.0, 4.0, 0.5                   # sigma_tr = 3: D = 1/9, L = 1/3
    st = np.full((n, n, n), sigma_a + sigma_s, np.float32)
    ss = np.full((n, n, n), sigma_s, np.float32)
    gg = np.full((n, n, n), g, np.float32)
    Q0 = np.zeros((n, n, n), np.float32)
    c = n // 2
    Q0[c, c, c] = 1.0
    r = diffusion.solve_diffusion(Q0, np.zeros_like(Q0), st, ss, gg, h, rtol=1e-9)
    D, L = 1 / 9, 1 / 3
    # beyond a few cells the discrete solution is within ~1.5 % (it falls as h^2: 0.5 % at n = 81)
    for m in range(6, 16):                                 # 6 cells (0.49 = 1.5 L) to 15 (3.7 L)
        dist = m * h
        exact = np.exp(-dist / L) / (4 * np.pi * D * dist)
        assert r.phi[c + m, c, c] == pytest.approx(exact, rel=0.03), m
        assert r.phi[c, c - m, c] == pytest.approx(exact, rel=0.03), m
    assert r.absorbed + sum(r.leaked) == pytest.approx(1.0, rel=1e-6)
    assert sum(r.leaked) < 0.02                            # the boundary is 6 L away


TAU, ALBEDO, G, HALFWIDTH = 10.0, 0.99, 0.8, 0.125


def hybrid_beam(n, handover=6.0):
    h = 1.0 / n
    shape = (n, n, n)
    st = np.full(shape, TAU, np.float32)
    ss, g = ALBEDO * st, np.full(shape, G, np.float32)
    Th, Dh = medium_factors(st, ss, g, h, "poisson")
    c = (np.arange(n) + 0.5) * h - 0.5
    inside = np.abs(c) < HALFWIDTH
    inj = (inside[:, None] & inside[None, :]).astype(np.float32) * h * h
    r = walk_box(Th, Dh, inj, 1.0, h, tolerance=1e-5, handover=(handover, handover_factor(st, ss, g, h)))
    r.diffusion = diffusion.solve_diffusion(*r.handed, st, ss, g, h, rtol=1e-6)   # the pipeline's diffusion stage
    r.budget.add_diffusion(r.diffusion)
    b = r.budget
    r2 = c[:, None] ** 2 + c[None, :] ** 2
    phi = r.phi.astype(np.float64) + r.diffusion.phi
    return {"transmitted": b.transmitted / b.injected, "reflected": b.reflected / b.injected,
            "side": b.side / b.injected, "absorbed": b.absorbed / b.injected,
            "balance": b.balance_error, "r2_mean": float((phi * r2).sum() / phi.sum())}


def test_hybrid_beam_converges_under_refinement_and_is_near_monte_carlo():
    """The walk alone loses the side escape as the grid is refined (0.068 -> 0.013 of the light
    from 16^3 to 32^3, Monte Carlo: 0.56; test_beam.py). With the diffusion stage (hand-over
    scale 6: light hands over about as soon as its lobe has spread) every fraction
    moves by < 0.01 between 16^3 and 32^3 and lies within 0.07 of Monte Carlo (measured: T 0.211,
    R 0.198, side 0.494, absorbed 0.098 at 32^3 against 0.154, 0.185, 0.560, 0.101), and the
    lateral spread within 10 % (0.0694 against 0.0742)."""
    from montecarlo import cube_beam_mc
    mc = cube_beam_mc(TAU, ALBEDO, G, HALFWIDTH, n_photons=100_000, seed=3)
    coarse, fine = hybrid_beam(16), hybrid_beam(32)
    for p in (coarse, fine):
        assert abs(p["balance"]) < 1e-5
    for k in ("transmitted", "reflected", "side", "absorbed"):
        assert abs(fine[k] - coarse[k]) < 0.01, k
        assert abs(fine[k] - mc[k]) < 0.07, (k, fine[k], mc[k])
    assert fine["r2_mean"] == pytest.approx(mc["r2_mean"], rel=0.10)


def test_boundary_weight_kernel_equals_numpy_twin(rng):
    import twins as ref
    for shape in ((9, 7, 8), (5, 1, 6)):
        mask = rng.random(shape) > 0.4
        np.testing.assert_allclose(diffusion.boundary_weight(mask), ref.boundary_weight(mask), rtol=1e-5, atol=1e-6)


def test_coarsen_kernel_equals_numpy_twin(rng):
    """diffusion.coarsen (kernels.sampling.block_sums) against its reshaping twin, on shapes that
    are and are not multiples of the factor, float32 and float64 cells, both modes."""
    import twins as ref
    for shape in ((9, 7, 8), (5, 1, 6), (8, 8, 4)):
        for dtype in (np.float32, np.float64):
            x = (rng.random(shape) * 10.0 ** rng.uniform(-3, 3, shape)).astype(dtype)
            for factor in (1, 2, 3):
                for how in ("sum", "mean"):
                    got = diffusion.coarsen(x, factor, how)
                    assert got.dtype == np.float64
                    np.testing.assert_allclose(got, ref.coarsen(x, factor, how), rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("shape", [(3, 5, 21), (2, 3, 8), (2, 2, 5)])
def test_reductions_sum_in_the_order_their_code_states(shape, rng):
    """kernels.diffusion.dot, cg_update's two sums and kernels.propagation.total_energy give
    bit for bit the sums of tests/twins.py's lanes_sum: the order of their additions is fixed by
    their code (eight lanes per row, rows, then slices), not chosen by the compiler. Under
    fastmath LLVM regrouped them, and the same kernel summed differently compiled in the
    process and loaded from Numba's cache (kernels/reduction.py). Rows of 21, 8 and 5 terms:
    full lanes and a remainder, full lanes only, a remainder only."""
    from popvol.kernels.propagation import total_energy
    from twins import lanes_sum
    a = rng.standard_normal(shape).astype(np.float32)
    b = rng.standard_normal(shape).astype(np.float32)
    assert K.dot(a, b) == lanes_sum(a, b)
    assert K.dot(a.astype(np.float64), b.astype(np.float64)) == lanes_sum(a.astype(np.float64), b.astype(np.float64))
    assert total_energy(a) == lanes_sum(a)
    x, r, p, Ap = (rng.standard_normal(shape).astype(np.float32) for _ in range(4))
    M = rng.uniform(0.5, 2.0, shape).astype(np.float32)
    z = np.empty_like(r)
    rz, rr = K.cg_update(x, r, p, Ap, M, 0.37, z)
    assert (rz, rr) == (lanes_sum(r, z), lanes_sum(r, r))
    # terms of magnitudes 1e-6 .. 1e6: here the order shows in the bits (one chain in index
    # order gives another sum), and the kernels still agree with the lanes
    wide = (rng.standard_normal((4, 6, 37)) * 10.0 ** rng.uniform(-6, 6, (4, 6, 37))).astype(np.float32)
    one_chain = 0.0
    for term in wide.ravel():
        one_chain += float(term)
    assert total_energy(wide) == lanes_sum(wide) != one_chain
    assert K.dot(wide, np.ones_like(wide)) == lanes_sum(wide)
