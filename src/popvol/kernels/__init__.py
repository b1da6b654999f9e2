"""The Numba back end (CPU): one module per stage's kernels (docs/ARCHITECTURE.md)."""

#: Numba options of a large helper called inside a parallel loop (the march, its lighting and the
#: fields' lookups it shares with the gather, the gather's per-cell lobes, one cell's send in the
#: walk's sweep, a spherical face's rates): compiled on its own and inlined
#: by LLVM (forceinline), not into the caller's Numba IR (inline="always"), which made compiling
#: the render kernel take about 105 s of a first run, against 21 s so, and the sweep 34 s against
#: 8 s; without reference counting (_nrt=False; such a helper allocates nothing): counted, its
#: array arguments cost atomic increments at every call, and the march ran 1.7-2x slower.
#: error_model="numpy" is what the parallel loop's body has. The output is bitwise that of the
#: inlined helper.
ON_ITS_OWN = dict(fastmath=True, error_model="numpy", forceinline=True, _nrt=False, cache=True)

# Lanes. Numba's parallel loop gives each thread one contiguous block of its range (also under
# numba.parallel_chunksize, with the OpenMP and workqueue layers: measured with Numba 0.68), which
# suits loops of even cost. Where the cost is uneven (rows of an image, the walk's bands, where
# the medium and the light are), a kernel runs ``prange(lanes)``, one lane per thread, and deals
# the work to the lanes: the render kernel rows round-robin, the sweeps the bands by the work
# each did in the sweep before (propagation.band_lanes). The caller passes the lanes
# (numba.get_num_threads(): called inside a kernel it would stop Numba's caching). Which lane
# does what never changes the result, only the time.

# Every kernel releases the GIL (nogil=True), so that a scene's light domains can be solved side
# by side on Python threads, each with its own share of Numba's threads (pipeline.side_by_side).
