"""Trilinear lookup in voxel grids (Numba), shared by resampling and rendering.

Continuous index coordinates put voxel centres at integers. A grid covers the union of its
cells, [-1/2, n - 1/2] per axis: inside, values are trilinear between centres and clamped to
the edge value in the outer half cell (Mitsuba's gridvolume does the same); outside, zero.
Grids of size 1 along an axis (constants stored as (1, 1, 1)) are constant along it.
"""
import numba as nb
import numpy as np

NO_BLOCKS = np.zeros((0, 0, 0), np.uint8)   # block_sums: no mask, every block


@nb.njit(inline="always", fastmath=True, cache=True)
def corner_weights(x, n):
    """Lower index, upper index and weight of the upper one along an axis of n voxels."""
    if x < 0.0:
        x = 0.0
    hi = n - 1.0
    if x > hi:
        x = hi
    i0 = int(x)
    if i0 > n - 2:
        i0 = max(n - 2, 0)
    f = x - i0
    i1 = min(i0 + 1, n - 1)
    return i0, i1, f


@nb.njit(inline="always", fastmath=True, cache=True)
def inside(x, y, z, shape):
    """Whether continuous index (x, y, z) lies in the cells of a grid of ``shape``."""
    return (-0.5 <= x <= shape[0] - 0.5) and (-0.5 <= y <= shape[1] - 0.5) and (-0.5 <= z <= shape[2] - 0.5)


@nb.njit(inline="always", fastmath=True, cache=True)
def trilinear(grid, x, y, z):
    """Value of ``grid`` (3-D float array) at continuous index (x, y, z); 0 outside its cells."""
    s = grid.shape
    if not inside(x, y, z, s):
        return 0.0
    return trilinear_clamped(grid, x, y, z)


@nb.njit(inline="always", fastmath=True, cache=True)
def trilinear_clamped(grid, x, y, z):
    """Like :func:`trilinear` but clamps to the edge everywhere (for constants and fields)."""
    return interpolate(grid, cell_corners(x, y, z, grid.shape))


@nb.njit(inline="always", fastmath=True, cache=True)
def cell_corners(x, y, z, shape):
    """The trilinear stencil at continuous index (x, y, z) of a grid of ``shape``, clamped to
    the edge: (i0, i1, j0, j1, k0, k1, fx, fy, fz), the lower and upper index and the upper
    one's weight along each axis, for :func:`interpolate`. The indices are unsigned (uint64,
    never negative here), so that indexing with them skips Numba's wrap-around of negative
    indices: 14 % off mapping a domain's fields to the medium's grid (pipeline, fields)."""
    i0, i1, fx = corner_weights(x, shape[0])
    j0, j1, fy = corner_weights(y, shape[1])
    k0, k1, fz = corner_weights(z, shape[2])
    return (np.uint64(i0), np.uint64(i1), np.uint64(j0), np.uint64(j1), np.uint64(k0), np.uint64(k1),
            fx, fy, fz)


@nb.njit(inline="always", fastmath=True, cache=True)
def interpolate(grid, corners):
    """Trilinear value of ``grid`` (3-D) on the stencil ``corners`` of :func:`cell_corners`;
    one stencil serves every grid of the same shape."""
    i0, i1, j0, j1, k0, k1, fx, fy, fz = corners
    c00 = grid[i0, j0, k0] * (1 - fz) + grid[i0, j0, k1] * fz
    c01 = grid[i0, j1, k0] * (1 - fz) + grid[i0, j1, k1] * fz
    c10 = grid[i1, j0, k0] * (1 - fz) + grid[i1, j0, k1] * fz
    c11 = grid[i1, j1, k0] * (1 - fz) + grid[i1, j1, k1] * fz
    return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def resample(grid, inv_voxel, grid_origin, frame, dom_origin, h, shape, clamp, out):
    """Sample ``grid`` (world voxel grid) at the centres of a light domain's cells.

    grid_origin: world position of voxel (0,0,0)'s centre; inv_voxel: 1/voxel size (3,).
    frame rows d, u, v; dom_origin: world corner of the domain; out: float32 ``shape``.
    ``clamp``: clamp to the edge outside the grid instead of returning 0.
    """
    for k in nb.prange(shape[0]):
        for i in range(shape[1]):
            for j in range(shape[2]):
                a = (k + 0.5) * h
                b = (i + 0.5) * h
                c = (j + 0.5) * h
                wx = dom_origin[0] + a * frame[0, 0] + b * frame[1, 0] + c * frame[2, 0]
                wy = dom_origin[1] + a * frame[0, 1] + b * frame[1, 1] + c * frame[2, 1]
                wz = dom_origin[2] + a * frame[0, 2] + b * frame[1, 2] + c * frame[2, 2]
                x = (wx - grid_origin[0]) * inv_voxel[0]
                y = (wy - grid_origin[1]) * inv_voxel[1]
                z = (wz - grid_origin[2]) * inv_voxel[2]
                if clamp:
                    out[k, i, j] = trilinear_clamped(grid, x, y, z)
                else:
                    out[k, i, j] = trilinear(grid, x, y, z)


#: the most fields one domain_to_world call samples (a sun's walk's three and its diffusion
#: stage's four, on the walk's own cells: pipeline.solve)
MAX_WORLD_FIELDS = 7


def domain_to_world(fields, frame, dom_origin, h, world_origin, voxel, outs, needed):
    """Sample domain fields (a tuple of float32 (n_d, n_u, n_v) arrays, at most
    MAX_WORLD_FIELDS) at the centres of the world voxels where ``needed`` (bool (nx, ny, nz)) is
    set, into ``outs`` (a tuple of as many C-contiguous float32 (nx, ny, nz) arrays), trilinear
    and clamped to the edge; one set of weights serves all fields. Voxels not needed are not
    written: allocate ``outs`` with zeros. The tuples are padded to MAX_WORLD_FIELDS for the
    kernel (:func:`_domain_to_world`), so that it compiles once for any number of fields."""
    n = len(fields)
    if not 1 <= n <= MAX_WORLD_FIELDS or len(outs) != n:
        raise ValueError(f"domain_to_world: 1 to {MAX_WORLD_FIELDS} fields and as many outputs, not {n} and {len(outs)}")
    fields = tuple(np.ascontiguousarray(f, np.float32) for f in fields)
    for o in outs:
        if o.dtype != np.float32 or not o.flags.c_contiguous or not o.flags.writeable:
            raise ValueError("domain_to_world: outputs must be writeable C-contiguous float32 arrays")
    pad = MAX_WORLD_FIELDS - n
    _domain_to_world(fields + fields[:1] * pad, n, np.asarray(frame, np.float64), np.asarray(dom_origin, np.float64),
                     float(h), np.asarray(world_origin, np.float64), np.asarray(voxel, np.float64),
                     tuple(outs) + tuple(outs[:1]) * pad, needed)


@nb.njit(inline="always", fastmath=True, cache=True)
def voxel_corners(x, y, z, world_origin, voxel, frame, dom_origin, h, shape):
    """The trilinear stencil (:func:`cell_corners`) in a domain of ``shape`` cells (frame rows
    d, u, v, corner ``dom_origin``, cell size h) at the centre of world voxel (x, y, z)."""
    px = world_origin[0] + x * voxel[0] - dom_origin[0]
    py = world_origin[1] + y * voxel[1] - dom_origin[1]
    pz = world_origin[2] + z * voxel[2] - dom_origin[2]
    return cell_corners((px * frame[0, 0] + py * frame[0, 1] + pz * frame[0, 2]) / h - 0.5,
                        (px * frame[1, 0] + py * frame[1, 1] + pz * frame[1, 2]) / h - 0.5,
                        (px * frame[2, 0] + py * frame[2, 1] + pz * frame[2, 2]) / h - 0.5, shape)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def cells_read(needed, frame, dom_origin, h, world_origin, voxel, out):
    """Set ``out`` (bool (n_d, n_u, n_v), a domain's cells) at the cells whose fields
    :func:`domain_to_world` reads for the world voxels where ``needed`` (bool (nx, ny, nz)):
    the corners of their trilinear stencils. Threads write True into shared cells only, so
    the result is the same on any number of threads. NumPy twin: tests/twins.py (cells_read)."""
    nx, ny, nz = needed.shape
    s = out.shape
    for x in nb.prange(nx):
        for y in range(ny):
            for z in range(nz):
                if needed[x, y, z]:
                    i0, i1, j0, j1, k0, k1, fx, fy, fz = voxel_corners(x, y, z, world_origin, voxel, frame,
                                                                     dom_origin, h, s)
                    out[i0, j0, k0] = out[i0, j0, k1] = out[i0, j1, k0] = out[i0, j1, k1] = True
                    out[i1, j0, k0] = out[i1, j0, k1] = out[i1, j1, k0] = out[i1, j1, k1] = True


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _domain_to_world(fields, n_fields, frame, dom_origin, h, world_origin, voxel, outs, needed):
    """:func:`domain_to_world` of the first ``n_fields`` of ``fields`` into as many ``outs``
    (both tuples of MAX_WORLD_FIELDS arrays)."""
    nx, ny, nz = needed.shape
    s = fields[0].shape
    for x in nb.prange(nx):
        for y in range(ny):
            for z in range(nz):
                if not needed[x, y, z]:
                    continue
                corners = voxel_corners(x, y, z, world_origin, voxel, frame, dom_origin, h, s)
                # static tuple indices (a loop to n_fields would index the tuples at run time, 15 %
                # slower); the tests are the same for every voxel, so they cost next to nothing
                outs[0][x, y, z] = interpolate(fields[0], corners)
                if n_fields > 1:
                    outs[1][x, y, z] = interpolate(fields[1], corners)
                if n_fields > 2:
                    outs[2][x, y, z] = interpolate(fields[2], corners)
                if n_fields > 3:
                    outs[3][x, y, z] = interpolate(fields[3], corners)
                if n_fields > 4:
                    outs[4][x, y, z] = interpolate(fields[4], corners)
                if n_fields > 5:
                    outs[5][x, y, z] = interpolate(fields[5], corners)
                if n_fields > 6:
                    outs[6][x, y, z] = interpolate(fields[6], corners)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def block_sums(x, factor, held, out, mask):
    """out (m, bx, by, bz): the sum of x (m, nx, ny, nz) over blocks of factor^3 voxels, b =
    ceil(n / factor) per axis, divided by the voxels the block holds if ``held`` (the mean; a
    block at a far edge averages the voxels it holds), else not (the sum, or the mean of the
    grid padded with zeros once divided by factor^3). Each block is summed by one thread in a
    fixed order, in float64: per row of voxels along z, each block's run x[lf], x[lf + 1], ...
    into its partial sum (0 + x[lf] + x[lf + 1] + ...), the rows' partial sums then in row
    order. The partial sums of a row are made one offset r at a time across all its blocks
    (the loop over blocks the compiler vectorises). ``mask`` uint8 (bx, by, bz): only the rows
    of voxels that cross a block marked in it are read, and the blocks not marked are 0 (the
    others' values do not depend on it); shape (0, 0, 0) (NO_BLOCKS): every block. NumPy
    twins: tests/twins.py (block_mean, coarsen)."""
    m, nx, ny, nz = x.shape
    bx, by, bz = out.shape[1], out.shape[2], out.shape[3]
    whole = nz // factor                # blocks along z that hold factor voxels
    masked = mask.shape[0] > 0
    for t in nb.prange(m * bx):         # one slab of blocks each
        k = t // bx
        i = t % bx
        a0 = i * factor
        a1 = min(a0 + factor, nx)
        acc = np.zeros((by, bz))
        s = np.empty(bz)
        wanted = np.ones(by, np.bool_)  # the rows of blocks (i, j, :) with a block marked
        if masked:
            for j in range(by):
                wanted[j] = False
                for l in range(bz):
                    if mask[i, j, l]:
                        wanted[j] = True
                        break
        for a in range(a0, a1):
            for b in range(ny):
                j = b // factor
                if not wanted[j]:
                    continue
                row = x[k, a, b]
                s[:] = 0.0
                for r in range(factor):
                    for l in range(whole):
                        s[l] += row[l * factor + r]
                    for l in range(whole, bz):      # the last block, if it holds fewer
                        if l * factor + r < nz:
                            s[l] += row[l * factor + r]
                for l in range(bz):
                    acc[j, l] += s[l]
        for j in range(by):
            nb_ = min(factor, ny - j * factor)
            for l in range(bz):
                count = (a1 - a0) * nb_ * min(factor, nz - l * factor) if held else 1
                out[k, i, j, l] = acc[j, l] / count if not masked or mask[i, j, l] else 0.0


@nb.njit(inline="always", fastmath=True, cache=True)
def block_stencil(i, j, k, factor, shape):
    """The trilinear stencil (:func:`cell_corners`) of voxel (i, j, k)'s centre on a grid of
    ``shape`` holding the values at the centres of blocks of factor^3 voxels (block b's centre
    at voxel index factor b + (factor - 1) / 2), clamped to the edge."""
    half = 0.5 * (factor - 1)
    return cell_corners((i - half) / factor, (j - half) / factor, (k - half) / factor, shape)


@nb.njit(inline="always", fastmath=True, cache=True)
def interpolate_channel(grid, corners, ch):
    """:func:`interpolate` of channel ch of ``grid`` (nx, ny, nz, C)."""
    i0, i1, j0, j1, k0, k1, fx, fy, fz = corners
    c00 = grid[i0, j0, k0, ch] * (1 - fz) + grid[i0, j0, k1, ch] * fz
    c01 = grid[i0, j1, k0, ch] * (1 - fz) + grid[i0, j1, k1, ch] * fz
    c10 = grid[i1, j0, k0, ch] * (1 - fz) + grid[i1, j0, k1, ch] * fz
    c11 = grid[i1, j1, k0, ch] * (1 - fz) + grid[i1, j1, k1, ch] * fz
    return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def upsample_blocks(coarse, factor, needed, out):
    """out float32 (nx, ny, nz, C) at the voxels where ``needed``: the trilinear value of
    ``coarse`` (bx, by, bz, C), the values at the centres of blocks of factor^3 voxels
    (:func:`block_stencil`), clamped to the edge; other voxels are not written. NumPy twin:
    tests/twins.py (upsample)."""
    nx, ny, nz = needed.shape
    for i in nb.prange(nx):
        for j in range(ny):
            for k in range(nz):
                if not needed[i, j, k]:
                    continue
                corners = block_stencil(i, j, k, factor, coarse.shape)
                for ch in range(coarse.shape[3]):
                    out[i, j, k, ch] = interpolate_channel(coarse, corners, ch)


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def add_upsampled_blocks(coarse, factor, needed, phi, flux):
    """Add :func:`upsample_blocks` of ``coarse`` float32 (bx, by, bz, 4) at the voxels where
    ``needed`` (bool (nx, ny, nz)) to phi float32 (nx, ny, nz) (channel 0) and flux float32 (3,
    nx, ny, nz) (channels 1-3), each value rounded to float32 before it is added: the walk's
    tail on blocks added to the walk's fields (walk.add_tail) without a buffer of the fine
    grid's size. NumPy twin: tests/twins.py (upsample)."""
    nx, ny, nz = needed.shape
    for i in nb.prange(nx):
        for j in range(ny):
            for k in range(nz):
                if not needed[i, j, k]:
                    continue
                corners = block_stencil(i, j, k, factor, coarse.shape)
                phi[i, j, k] += np.float32(interpolate_channel(coarse, corners, 0))
                for a in range(3):
                    flux[a, i, j, k] += np.float32(interpolate_channel(coarse, corners, 1 + a))


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def densest_near_blocks(density, block, out):
    """out float32 (ceil(nx / block), ...): the largest density within one voxel of each block
    of block^3 voxels, i.e. over voxels [block b - 1, block (b + 1) + 1] along each axis, within
    the grid (renderer.densest_in_blocks). Voxel j lies in blocks max(0, (j - 2) // block) ..
    (j + 1) // block of its axis. NumPy twin: tests/twins.py (densest_in_blocks)."""
    nx, ny, nz = density.shape
    bx, by, bz = out.shape
    for b in nb.prange(bx):             # one slab of blocks each: no two threads write one block
        acc = np.zeros((by, bz), np.float32)
        for i in range(max(block * b - 1, 0), min(block * (b + 1) + 2, nx)):
            for j in range(ny):
                j_lo = max(0, (j - 2) // block)
                j_hi = min(by - 1, (j + 1) // block)
                for k in range(nz):
                    v = density[i, j, k]
                    if v <= 0.0:
                        continue
                    for q in range(max(0, (k - 2) // block), min(bz - 1, (k + 1) // block) + 1):
                        for p in range(j_lo, j_hi + 1):
                            if v > acc[p, q]:
                                acc[p, q] = v
        for p in range(by):
            for q in range(bz):
                out[b, p, q] = acc[p, q]


@nb.njit(parallel=True, fastmath=True, cache=True, nogil=True)
def blend_rows(table, rows, weights, out):
    """``out[c] = sum_q weights[c, q] table[rows[c, q]]`` for every c: a weighted mix of rows of
    ``table`` (float32 (n, w)), the rows int64 (m, k) and their weights float32 (m, k) per c,
    into ``out`` float32 (m, w); a weight of 0 skips its row. (walk.direction_split: each
    lobe's split, bilinear between a cube map's texels and linear between two anisotropies.)
    NumPy twin: tests/twins.py (blend_rows)."""
    m, k = rows.shape
    w = table.shape[1]
    for c in nb.prange(m):
        for x in range(w):
            out[c, x] = 0.0
        for q in range(k):
            wq = weights[c, q]
            if wq == 0.0:
                continue
            r = rows[c, q]
            for x in range(w):
                out[c, x] += wq * table[r, x]
