"""Sums that do not depend on the number of threads.

A Numba ``prange`` reduction (``total += s`` in a parallel loop) groups its terms by thread, so
its float result changes in the last bits with the thread count, and a solver that compares a
sum with its tolerance may then take one more or one fewer step. The parallel kernels instead
store one partial sum per slice k (each slice summed by one thread in a fixed order) and add
the slices with :func:`ordered_sum`: frames are bitwise the same on a Dask worker with one
thread as on a machine with many.
"""
import numba as nb


@nb.njit(fastmath=True, cache=True)
def ordered_sum(part):
    """Sum of a 1-D float array in index order."""
    total = 0.0
    for k in range(part.shape[0]):
        total += part[k]
    return total


@nb.njit(fastmath=True, cache=True)
def add_parts(part, tally):
    """tally[c] += the ordered sum of row c of ``part`` (per-slice partial sums), for every c."""
    for c in range(part.shape[0]):
        tally[c] += ordered_sum(part[c])
