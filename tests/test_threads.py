"""OpenBLAS's threads stay idle while popvol solves and renders.

A BLAS call on a large array (``np.tensordot``, ``@``) runs on OpenBLAS's own threads, which
then spin for milliseconds and take the second core from the Numba kernel that follows (the
six-ordinate walk's first sweep took 25-80 ms instead of 15-17 ms behind one; docs/ARCHITECTURE.md,
"Where a change belongs"). The threads that ``import numpy`` starts are OpenBLAS's; their CPU
time, read from /proc, must not grow over solves and renders of the procedural cumulus field at
128 cells (before 3c3b798 it grew by 0.17 s over three).
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "src" / "popvol" / "bench_scenes" / "field_sun.toml"
BLAS_LIMITS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "GOTO_NUM_THREADS")

PROBE = r"""
import os, sys
before = set(os.listdir('/proc/self/task'))
import numpy as np
blas = set(os.listdir('/proc/self/task')) - before

def ticks():
    total = 0
    for t in blas:
        with open(f'/proc/self/task/{t}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        total += int(fields[11]) + int(fields[12])      # utime + stime, clock ticks
    return total

import popvol
scene = popvol.load_scene(sys.argv[1])
popvol.render(scene, popvol.solve(scene))               # warm-up: kernels from Numba's cache
t0 = ticks()
for _ in range(3):
    popvol.render(scene, popvol.solve(scene))
print(len(blas), ticks() - t0, os.sysconf('SC_CLK_TCK'))
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux's /proc")
def test_blas_threads_stay_idle_during_solve_and_render():
    # without the thread limits that importing dask.distributed (test_distributed) leaves in
    # this process's environment (OMP_NUM_THREADS = OPENBLAS_NUM_THREADS = 1): BLAS's own default
    env = {k: v for k, v in os.environ.items() if k not in BLAS_LIMITS}
    out = subprocess.run([sys.executable, "-c", PROBE, str(SCENE)], capture_output=True, text=True, timeout=600,
                         env={**env, "PYTHONPATH": str(ROOT / "src")})
    assert out.returncode == 0, out.stderr[-2000:]
    threads, ticks, per_second = map(int, out.stdout.split()[-3:])
    if threads == 0:
        pytest.skip("NumPy's BLAS starts no threads here")
    assert ticks / per_second <= 0.02, f"OpenBLAS's threads ran {ticks / per_second:.2f} s during 3 solves + renders"
