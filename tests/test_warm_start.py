"""Warm start between animation frames (pipeline.solve's ``warm``): the diffusion stage's
conjugate gradients start from the previous frame's fluence; the walk always starts cold. A
diffusion stage is what point lights have, and suns with the one-lobe sweeps (``solver =
"sweep"``), which these scenes use; a sun walked with six ordinates (the default) has none, so
there is nothing to warm-start (test_a_six_ordinate_sun_starts_cold).

The bound asserted for a warm frame against the cold one: relMSE of the images <= TOL^2 (an RMS
relative pixel difference of TOL, the method's default tolerance 3e-3: the walk itself stops
with that share of the light in flight) and the largest difference of the diffusion fluence <=
TOL of its largest value. Why it holds whatever the start: both solves stop on the true residual
||b - A x|| <= rtol ||b|| (rtol = 0.1 tolerance = 3e-4), so ||A (x_warm - x_cold)|| <= 2 rtol
||b||, which test_both_stop_on_the_true_residual checks directly; the walk's fields are the same
bit for bit. (Measured: 1e-5 to 1e-4 on the fluence, about 1e-10 on the images.)
"""
import numba
import numpy as np
import pytest

import popvol
from popvol import diffusion
from popvol.metrics import relmse

N = 20
TOL = popvol.Method().tolerance          # the default method.tolerance
SUN = {"type": "directional", "direction": [-0.9, -0.4, -0.35], "irradiance": [5.0, 4.85, 4.5]}
POINT = {"type": "point", "position": [0.3, 1.6, 0.4], "intensity": [2.0, 2.0, 2.0]}


def scene(t=1.0, seed=7, lights=(SUN, POINT), resolution=N, isotropic="diffusion", solver="sweep"):
    return popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": N, "seed": seed, "time": t, "scale": 40.0,
                   "albedo": 0.99, "g": 0.85},
        "lights": list(lights),
        "camera": {"origin": [0.0, 0.1, 2.4], "target": [0.0, 0.72, 0.0], "fov": 40.0, "width": 48, "height": 32},
        "method": {"resolution": resolution}, "experimental": {"isotropic": isotropic, "solver": solver}})


def domains(sol):
    return sol.stats()["domains"]


def cg(sol):
    return sum(d["diffusion_iterations"] for d in domains(sol))


def max_rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def assert_same_frame(s, warm, cold):
    """The warm frame is the cold one within the tolerance (module docstring)."""
    for name in ("phi", "phia", "direct"):                 # the walk: cold in both
        np.testing.assert_array_equal(getattr(warm, name), getattr(cold, name))
    assert max_rel(warm.phid, cold.phid) <= TOL
    assert relmse(popvol.render(s, warm), popvol.render(s, cold)) <= TOL ** 2


def test_without_warm_the_solve_is_unchanged():
    s = scene()
    threads = numba.get_num_threads()
    numba.set_num_threads(1)          # parallel float sums in a fixed order: compare bit for bit
    try:
        a, b = popvol.solve(s), popvol.solve(s, warm=None)
    finally:
        numba.set_num_threads(threads)
    for name in ("phi", "phia", "direct", "phid", "flux"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert all(d["warm"] is False and d["warm_note"] == "" for d in domains(b))
    assert all(d["diffusion_iterations"] > 0 for d in domains(b))


def test_warm_from_the_same_scene_is_converged_already():
    s = scene()
    cold = popvol.solve(s)
    warm = popvol.solve(s, warm=cold)
    for d in domains(warm):
        assert d["warm"] and d["warm_note"] == "warm"
        assert d["diffusion_iterations"] <= 1 and d["diffusion_residual"] <= 0.1 * TOL
    assert_same_frame(s, warm, cold)


def test_warm_from_the_previous_frame_needs_fewer_iterations():
    prev = popvol.solve(scene(1.0))
    s = scene(1.0 + 1 / 24)
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    assert all(d["warm"] for d in domains(warm))
    assert cg(warm) < cg(cold)
    assert all(d["diffusion_residual"] <= 0.1 * TOL for d in domains(warm))
    assert_same_frame(s, warm, cold)


def test_a_cut_does_not_smear():
    prev = popvol.solve(scene(5.0, seed=3))
    s = scene(1.0, seed=7)
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    assert all(d["warm"] for d in domains(warm))
    assert_same_frame(s, warm, cold)
    # the previous frame really was another picture
    assert relmse(popvol.render(scene(5.0, seed=3), prev), popvol.render(s, cold)) > 100 * TOL ** 2


def test_a_turned_sun_is_resampled_and_a_moved_point_light_reuses_its_grid():
    prev = popvol.solve(scene())
    turned = dict(SUN, direction=[-0.88, -0.42, -0.38])
    moved = dict(POINT, position=[0.32, 1.6, 0.4])
    s = scene(lights=(turned, moved))
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    sun, point = domains(warm)
    assert sun["warm"] and "resampled" in sun["warm_note"]
    assert point["warm"] and point["warm_note"] == "warm"     # its diffusion grid is the medium's
    assert_same_frame(s, warm, cold)


def test_a_previous_solution_on_another_grid_is_resampled():
    """Another resolution (or a medium whose crop changed) gives the sun's domain another
    shape: the guess is resampled onto it, and the frame is still the cold one."""
    s = scene()
    prev = popvol.solve(scene(resolution=N - 4))
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    sun = domains(warm)[0]
    assert sun["warm"] and "resampled" in sun["warm_note"]
    assert_same_frame(s, warm, cold)


@pytest.mark.parametrize("case", ["lights", "kind", "walk"])
def test_a_mismatched_previous_solution_falls_back_to_cold(case):
    s = scene()
    prev_scene, note = {"lights": (scene(lights=(SUN,)), "light(s)"),
                        "kind": (scene(lights=(POINT, SUN)), "light"),
                        "walk": (scene(isotropic="walk"), "no diffusion solve")}[case]
    prev = popvol.solve(prev_scene)
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    for d in domains(warm):
        assert d["warm"] is False and d["warm_note"].startswith("cold") and note in d["warm_note"]
    np.testing.assert_allclose(warm.phid, cold.phid, rtol=0, atol=1e-6 * float(cold.phid.max()))


def test_a_six_ordinate_sun_starts_cold():
    """With the default solver the sun walks every order (no conjugate gradients): it starts cold,
    saying why, and the point light beside it is warm-started; the frame is the cold one."""
    prev = popvol.solve(scene(1.0, solver="ordinates"))
    s = scene(1.0 + 1 / 24, solver="ordinates")
    cold, warm = popvol.solve(s), popvol.solve(s, warm=prev)
    sun, point = domains(warm)
    assert sun["warm"] is False and "no diffusion solve" in sun["warm_note"]
    assert point["warm"] and point["diffusion_iterations"] < domains(cold)[1]["diffusion_iterations"]
    assert_same_frame(s, warm, cold)


def test_both_stop_on_the_true_residual():
    """Cold and warm (from another cloud's solve, a cut) both end with ||b - A x|| <= rtol ||b||
    recomputed in float64, so ||A (x_warm - x_cold)|| <= 2 rtol ||b||."""
    rtol = 1e-4
    rng = np.random.default_rng(1)
    n = 16
    x = np.indices((n, n, n)).astype(np.float64) / n
    st = 20.0 * np.clip(1.0 - 4 * ((x - 0.5) ** 2).sum(axis=0), 0.0, None) * (0.5 + rng.random((n, n, n)))
    ss, g, h = 0.99 * st, np.full(st.shape, 0.8), 1.0 / n
    D, sah3, mask = diffusion.coefficients(st, ss, g, h)
    b = diffusion.source(np.where(mask, rng.random(st.shape), 0.0), np.zeros(st.shape), D, mask, h)
    b[~mask] = 0.0
    bw = diffusion.boundary_weight(mask)
    other = np.where(mask, 10.0 * rng.random(st.shape), 0.0).astype(np.float32)

    def residual(xs, rhs=b):
        """||rhs - A xs|| / ||b||, in float64."""
        space = diffusion.RowSpace(D, sah3, mask, h, bw)
        Ax = space.vector(np.float64)
        space.apply(space.pack(xs, np.float64), Ax)
        return np.linalg.norm(rhs - space.unpack(Ax)) / np.linalg.norm(b)

    xc, itc, rc = diffusion.pcg(D, sah3, mask, h, b, rtol, 10_000, bw)
    xw, itw, rw = diffusion.pcg(D, sah3, mask, h, b, rtol, 10_000, bw, other)
    assert residual(xc) <= 1.05 * rtol
    assert residual(xw) <= rtol * (1 + 1e-3) and rw <= rtol      # warm: the true residual, by construction
    assert residual(xw.astype(np.float64) - xc, 0.0) <= 2.1 * rtol
    _, it0, _ = diffusion.pcg(D, sah3, mask, h, b, rtol, 10_000, bw, xc)
    assert it0 <= 1


def test_resample_grid_is_exact_for_linear_fields_and_fill_gaps_uses_neighbours():
    frame = np.eye(3)
    src = np.fromfunction(lambda i, j, k: 1.0 + i + 2 * j - k, (8, 8, 8)).astype(np.float32)
    # a grid shifted by a quarter cell: inside the source's centres a linear field is exact
    out = diffusion.resample_grid(src, frame, np.zeros(3), 1.0, frame, np.full(3, 0.25), 1.0, (8, 8, 8))
    q = np.indices((7, 7, 7)).astype(np.float64) + 0.25
    np.testing.assert_allclose(out[:7, :7, :7], 1.0 + q[0] + 2 * q[1] - q[2], rtol=1e-6)
    x = np.full((3, 3, 3), 2.0, np.float32)
    x[1, 1, 1] = 0.0
    mask = np.ones((3, 3, 3), bool)
    mask[0, 0, 0] = False
    filled = diffusion.fill_gaps(x, mask)
    assert filled[1, 1, 1] == 2.0 and filled[0, 0, 0] == 0.0


def test_resample_grid_between_rotated_grids_is_exact_for_linear_fields():
    """A linear field of world position, sampled at the centres of a grid turned 30 degrees and
    of another cell size, is read back exactly at the centres that fall inside the source's."""
    t = np.radians(30.0)
    src_frame = np.array([[np.cos(t), np.sin(t), 0.0], [-np.sin(t), np.cos(t), 0.0], [0.0, 0.0, 1.0]])
    src_origin, src_h = np.array([-1.0, -2.0, 0.5]), 0.5
    a, c = np.array([0.3, -0.7, 1.1]), 2.0
    q = np.indices((20, 20, 20)).reshape(3, -1).T
    src_world = src_origin + (q + 0.5) * src_h @ src_frame
    src = (src_world @ a + c).reshape(20, 20, 20).astype(np.float32)
    frame, origin, h, shape = np.eye(3), np.array([1.0, 1.0, 1.0]), 0.3, (12, 12, 12)
    out = diffusion.resample_grid(src, src_frame, src_origin, src_h, frame, origin, h, shape)
    p = np.indices(shape).reshape(3, -1).T
    world = origin + (p + 0.5) * h
    x = (world - src_origin) @ src_frame.T / src_h - 0.5
    inside = np.all((x >= 0) & (x <= 19), axis=1)
    assert inside.sum() > 1000
    np.testing.assert_allclose(out.reshape(-1)[inside], (world @ a + c)[inside], rtol=1e-5, atol=1e-5)


def test_frame_to_world_is_the_rotation_of_each_vector():
    """domains.frame_to_world (elementwise, no BLAS) equals rotating each vector by the frame."""
    from popvol.domains import frame_to_world
    rng = np.random.default_rng(3)
    frame, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    F = rng.normal(size=(3, 4, 5, 6)).astype(np.float32)
    expect = np.einsum("ac,a...->c...", frame, F.astype(np.float64))
    got = frame_to_world(frame, F)
    assert got.dtype == np.float32 and got.shape == F.shape
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-6)
