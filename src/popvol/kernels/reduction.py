"""Sums that do not depend on the number of threads.

A Numba ``prange`` reduction (``total += s`` in a parallel loop) groups its terms by thread, so
its float result changes in the last bits with the thread count, and a solver that compares a
sum with its tolerance may then take one more or one fewer step. The parallel kernels instead
store one partial sum per slice k (each slice summed by one thread in a fixed order) and add
the slices with :func:`ordered_sum`: frames are bitwise the same on a Dask worker with one
thread as on a machine with many.

They are compiled without ``fastmath``, which lets LLVM regroup a sum's terms to vectorise it,
and not the same way in code compiled in the process and code loaded from Numba's cache
(``kernels.diffusion.dot`` on two equal float32 arrays: 0.012734128888354344 against
0.01273412888835434), so a first run's frames would differ in the last bits from later ones. A
row's terms go instead to LANES fixed partial sums (:func:`row_dot`, :func:`row_sum`), added in
a fixed order: the order is in the code, not left to the compiler. The kernels that sum set
``fastmath=False`` outright: one that sets nothing inherits its caller's (Numba's
``inherit_if_not_set``), and a sum called from a fastmath kernel would be compiled, and
cached, with it.
"""
import numba as nb
import numpy as np


@nb.njit(fastmath=False, cache=True, nogil=True)
def ordered_sum(part):
    """Sum of a 1-D float array in index order."""
    total = 0.0
    for k in range(part.shape[0]):
        total += part[k]
    return total


@nb.njit(fastmath=False, cache=True, nogil=True)
def add_parts(part, tally):
    """tally[c] += the ordered sum of row c of ``part`` (per-slice partial sums), for every c."""
    for c in range(part.shape[0]):
        tally[c] += ordered_sum(part[c])


@nb.njit(fastmath=False, cache=True, nogil=True)
def add_row_parts(part, tally, row_work):
    """A sweep's per-row tallies ``part`` float64 (5, n_d * n_u), row k * n_u + i: the four
    tallies added to ``tally`` (:func:`add_parts`), and the packets each row sent (part[4]) summed
    over k into ``row_work`` float64 (n_u,) (overwritten), for the next sweep's cut. Returns the
    packets sent."""
    add_parts(part[:4], tally)
    n1 = row_work.shape[0]
    sent = 0
    row_work[:] = 0.0
    for c in range(part.shape[1]):
        sent += np.int64(part[4, c])
        row_work[c % n1] += part[4, c]
    return sent


#: partial sums per row in :func:`row_dot` and :func:`row_sum` (independent chains that the
#: processor overlaps: about twice as slow as a vectorised fastmath sum, three times as fast as
#: one chain)
LANES = 8


@nb.njit(inline="always", cache=True)
def _lanes_total(s0, s1, s2, s3, s4, s5, s6, s7):
    return ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))


@nb.njit(inline="always", cache=True)
def row_dot(a, b, k, i):
    """sum over j of a[k, i, j] b[k, i, j] for 3-D arrays (products in the arrays' precision,
    sums in float64): term j goes to lane j mod LANES, the lanes are added in a fixed order.
    Inline it only into kernels compiled without fastmath (module docstring)."""
    n2 = a.shape[2]
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
    for jb in range(n2 // LANES):
        j = LANES * jb
        s0 += a[k, i, j] * b[k, i, j]
        s1 += a[k, i, j + 1] * b[k, i, j + 1]
        s2 += a[k, i, j + 2] * b[k, i, j + 2]
        s3 += a[k, i, j + 3] * b[k, i, j + 3]
        s4 += a[k, i, j + 4] * b[k, i, j + 4]
        s5 += a[k, i, j + 5] * b[k, i, j + 5]
        s6 += a[k, i, j + 6] * b[k, i, j + 6]
        s7 += a[k, i, j + 7] * b[k, i, j + 7]
    for j in range(LANES * (n2 // LANES), n2):
        s0 += a[k, i, j] * b[k, i, j]
    return _lanes_total(s0, s1, s2, s3, s4, s5, s6, s7)


@nb.njit(inline="always", cache=True)
def row_sum(a, k, i):
    """sum over j of a[k, i, j] in float64, in the lanes of :func:`row_dot`."""
    n2 = a.shape[2]
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
    for jb in range(n2 // LANES):
        j = LANES * jb
        s0 += a[k, i, j]
        s1 += a[k, i, j + 1]
        s2 += a[k, i, j + 2]
        s3 += a[k, i, j + 3]
        s4 += a[k, i, j + 4]
        s5 += a[k, i, j + 5]
        s6 += a[k, i, j + 6]
        s7 += a[k, i, j + 7]
    for j in range(LANES * (n2 // LANES), n2):
        s0 += a[k, i, j]
    return _lanes_total(s0, s1, s2, s3, s4, s5, s6, s7)
