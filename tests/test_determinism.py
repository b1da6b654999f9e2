"""Results do not depend on the number of threads: the parallel sums (kernels/reduction.py)
and a whole solve give the same bits with one thread as with two. Dask workers run one
Numba thread each (popvol.distributed), and frames must be bitwise those of a serial run."""
import numba
import numpy as np
import pytest

import popvol
from popvol.kernels import diffusion as KD
from popvol.kernels import propagation as KP

pytestmark = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 Numba threads")


def with_threads(n, f):
    old = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        return f()
    finally:
        numba.set_num_threads(old)


def random_grids(n=3, shape=(37, 23, 19)):
    rng = np.random.default_rng(5)
    return [(rng.random(shape, dtype=np.float32) * 10.0 ** rng.uniform(-3, 3, shape)).astype(np.float32)
            for _ in range(n)]


def test_parallel_sums_are_the_same_with_one_or_two_threads():
    a, b, m = random_grids()
    for f in (lambda: KD.dot(a, b), lambda: KP.total_energy(a)):
        assert with_threads(1, f) == with_threads(2, f)

    def update():
        x, r, p = (g.copy() for g in random_grids())
        return KD.cg_update(x, r, p, a, m + 1.0, 0.3, np.empty_like(a)), x, r
    (s1, x1, r1), (s2, x2, r2) = with_threads(1, update), with_threads(2, update)
    assert s1 == s2 and np.array_equal(x1, x2) and np.array_equal(r1, r2)
    # and the sums are right: against NumPy's float64 sum (the kernel multiplies in float32)
    assert KD.dot(a, b) == pytest.approx(float(np.sum(a.astype(np.float64) * b)), rel=1e-6)
    assert KP.total_energy(a) == pytest.approx(float(np.sum(a, dtype=np.float64)), rel=1e-12)


def sun_and_sky(sky_lights: int, point: bool = False):
    """A small procedural cloud under a sun and a sky of ``sky_lights`` directions (and, with
    ``point``, a point light inside it: a spherical domain of its own)."""
    lights = [{"type": "directional", "direction": [-0.9, -0.4, -0.35], "irradiance": 5.0},
              {"type": "sky", "lights": sky_lights}]
    if point:
        lights.append({"type": "point", "position": [0.0, 0.7, 0.0], "intensity": 2.0})
    return popvol.scene_from_dict({
        "medium": {"type": "procedural", "resolution": 10, "scale": 30.0, "time": 1.0},
        "lights": lights,
        "camera": {"origin": [0.0, 0.1, 2.4], "target": [0.0, 0.72, 0.0], "width": 32, "height": 18},
        "method": {"resolution": 16}})


def test_a_solve_is_the_same_with_one_or_two_threads():
    scene = sun_and_sky(2)
    one, two = with_threads(1, lambda: popvol.solve(scene)), with_threads(2, lambda: popvol.solve(scene))
    for name in ("phi", "phia", "direct", "phid", "flux"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert [d.result.iterations for d in one.domains] == [d.result.iterations for d in two.domains]


@pytest.mark.parametrize("point", [False, True])
def test_domains_solved_side_by_side_are_the_same_as_one_at_a_time(monkeypatch, point):
    """pipeline.side_by_side: the sun's and the sky's domains (and a point light's spherical
    one) solved two at a time, each on one Numba thread of its own Python thread, give the bits
    of one at a time on two threads."""
    import threading
    import popvol.pipeline as P
    scene = sun_and_sky(3, point)
    ran = []
    solve_light = P.solve_light

    def recorded(*args, **kwargs):
        ran.append((threading.get_ident(), numba.get_num_threads()))
        return solve_light(*args, **kwargs)
    monkeypatch.setattr(P, "solve_light", recorded)
    solutions = {}
    for workers in (1, 2):
        monkeypatch.setattr(P, "side_by_side", lambda cells, threads=None, w=workers: w)
        ran.clear()
        solutions[workers] = with_threads(2, lambda: popvol.solve(scene))
        threads = {t for t, _ in ran}
        assert len(ran) == len(scene.lights) and len(threads) == workers
        assert {n for _, n in ran} == {2 // workers}
    one, two = solutions[1], solutions[2]
    for name in ("phi", "phia", "direct", "phid", "flux"):
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
    assert np.array_equal(one.points.fields, two.points.fields)
    assert np.array_equal(popvol.render(scene, one), popvol.render(scene, two))
    assert [(d.light_index, d.result.iterations) for d in one.domains] == \
        [(d.light_index, d.result.iterations) for d in two.domains]


def test_side_by_side_only_where_it_finishes_sooner():
    """Side by side where the largest-first dealing beats one at a time on every thread, at
    PARALLEL_EFFICIENCY: the bench's sun + 8 sky domains yes, a sun with one small domain no."""
    from popvol.pipeline import side_by_side
    sky = [576378, 57564, 59532, 57400, 52900, 56800, 49400, 52300, 49900]
    assert side_by_side(sky, 2) == 2
    assert side_by_side(sky[:2], 2) == 1           # the small one would wait for nothing
    assert side_by_side([1000] * 4, 2) == 2 and side_by_side([1000] * 8, 8) == 8
    assert side_by_side([1000] * 3, 2) == 2         # 2000 on one thread against 3000 on two
    assert side_by_side([1000] * 3, 8) == 1         # three workers would leave two threads idle
    assert side_by_side([1000] * 8, 4) == 4         # four workers of one thread each
    assert side_by_side(sky, 1) == 1 and side_by_side([1000], 2) == 1
    # not where the two largest domains would not fit in memory together (64 bytes a cell)
    assert side_by_side([10**6] * 4, 2, memory=2 * 64 * 10**6 / 0.8) == 2
    assert side_by_side([10**6] * 4, 2, memory=1.9 * 64 * 10**6 / 0.8) == 1


def test_a_failing_domain_stops_the_others_side_by_side():
    """run_jobs: a job's error is raised, and jobs not yet started are dropped, not run."""
    import threading
    import time
    from popvol.pipeline import run_jobs
    started = []
    lock = threading.Lock()

    def job(k):
        with lock:
            started.append(k)
        if k == 0:
            raise popvol.PopvolError("job 0 failed")
        time.sleep(0.05)
        return k
    with pytest.raises(popvol.PopvolError, match="job 0 failed"):
        run_jobs(job, [100, 90, 80, 70, 60, 50, 40, 30], 2)
    assert 0 in started and len(started) < 8
    assert run_jobs(lambda k: k * k, [1, 5, 3], 2) == [0, 1, 4]      # results in the jobs' order
