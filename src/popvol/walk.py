"""The walk: light carried cell to cell through a light's domain (docs/METHOD.md, "Walk").

A domain's cells hold pending packets (power W and W times the lobe's anisotropy a). A cell
sends each packet's front, side and back parts (supplement Eq. 2, 4, 7) to its six neighbours,
attenuated by the half-step transmittance of sender and receiver and with the anisotropy
decayed (supplement Eq. 12 or its Poisson form), and adds the visit to the fluence phi and phi
a. Gauss-Seidel sweeps along the principal ordinate (kernels/propagation.py for a rectilinear
domain, kernels/spherical.py for a point light's) or a Jacobi wavefront repeat this until the
power still in flight is below the tolerance; the experimental binned wavefront
(kernels/binned.py) keeps each cell's light in fixed anisotropy bins instead of one merged lobe.
The ordinates' walks (by sweeps: kernels/ordinates18.py, eighteen directions, the default for a
sun's and an environment's light, and kernels/ordinates.py, six) keep one lobe per lattice
direction instead, so that light sent sideways keeps going sideways, and walk every order. With the one-lobe walks' diffusion stage, packets
whose lobe has spread leave the walk (docs/METHOD.md, "Hand-over").
"""
from __future__ import annotations

import functools
import threading
import time

import numba
import numpy as np

from . import hg
from .diffusion import coarse_optics
from .domains import check_memory, grow
from .kernels import binned as KB
from .kernels import cells as KC
from .kernels import ordinates as KO
from .kernels import ordinates18 as KO18
from .kernels import propagation as K
from .kernels import sampling as KS
from .results import Budget, WalkResult

SPLIT_TABLE_SIZE = 4097
SOUTHWELL_FRACTION = 2.0      # cells send above twice the mean pending energy (sweep_until_converged)
ANISOTROPY_BINS = 17          # the binned wavefront's bins per cell (anisotropy_bins): spacing 1/8


@functools.lru_cache(maxsize=4)
def split_table(n: int = SPLIT_TABLE_SIZE) -> np.ndarray:
    """float64 (n, 8): front/side/back shares and their conditional mean cosines for a lobe
    HG_a, sampled at a = linspace(-1, 1, n) (supplement Eq. 2, 4, 7); columns 6, 7 are padding
    so that one row is 64 bytes (the kernels read two neighbouring rows per lookup)."""
    a = np.linspace(-1.0, 1.0, n)
    table = np.zeros((n, 8))
    table[:, 0], table[:, 1], table[:, 2] = hg.split_fractions(a)
    table[:, 3], table[:, 4], table[:, 5] = hg.conditional_mean_cosines(a)
    return table


@functools.lru_cache(maxsize=4)
def split_table32(n: int = SPLIT_TABLE_SIZE) -> np.ndarray:
    """:func:`split_table` in float32, what the kernels read (see kernels.propagation.split)."""
    return split_table(n).astype(np.float32)


@functools.lru_cache(maxsize=4)
def ordinate_table(n: int = SPLIT_TABLE_SIZE) -> np.ndarray:
    """float64 (n, 7): for a lobe HG_a at a = linspace(-1, 1, n), the columns of
    kernels.ordinates (PF .. MJ): front, side (each) and back shares, their conditional mean
    cosines about the lobe's axis (supplement Eq. 2, 4, 7) and the side slice's mean cosine
    about its own axis (:func:`popvol.hg.side_wedge_mean_cosine`)."""
    table = np.zeros((n, 7))
    table[:, :6] = split_table(n)[:, :6]
    table[:, 6] = hg.side_wedge_mean_cosine(np.linspace(-1.0, 1.0, n))
    return table


def _lattice18() -> np.ndarray:
    """int64 (18, 3): the eighteen ordinates' offsets in cells, (d, u, v): the six faces +-d, +-u,
    +-v, then the twelve edges (+-1, +-1, 0), (+-1, 0, +-1), (0, +-1, +-1)."""
    faces = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    edges = []
    for p, q in ((0, 1), (0, 2), (1, 2)):
        for sp in (1, -1):
            for sq in (1, -1):
                v = [0, 0, 0]
                v[p], v[q] = sp, sq
                edges.append(tuple(v))
    return np.array(faces + edges, np.int64)


#: the eighteen-ordinate walk's directions as offsets in cells (kernels/ordinates18.py)
ORDINATES18 = _lattice18()
#: the six-ordinate walk's directions (kernels/ordinates.py), in its order +d, -d, +u, -u, +v, -v:
#: the lattice's six faces
ORDINATES6 = ORDINATES18[:6]
#: the groups of rows the eighteen-ordinate sweep runs as a pipeline (one thread each at most),
#: fixed so that the fields do not depend on the number of threads: it uses two threads at most
GROUPS18 = 2
#: parts held to a sweep's end by the eighteen-ordinate walks of this process (kernels/ordinates18.py)
HELD18 = [0]
#: memory ordinate18_table takes while it is built (12.7 MB by tracemalloc: the lobe weights of
#: 255 anisotropies x 2048 bands of cosine, float64, and their temporaries)
ORDINATE18_TABLE_BYTES = 16_000_000


def _signed_permutations() -> list[np.ndarray]:
    """The 48 symmetries of the cube: 3x3 signed permutation matrices."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in np.ndindex(2, 2, 2):
            R = np.zeros((3, 3), np.int64)
            for row, col in enumerate(perm):
                R[row, col] = 1 - 2 * signs[row]
            out.append(R)
    return out


_TABLE18_LOCK = threading.Lock()


def ordinate18_table(n_a: int = 257, n_mu: int = 2048, n_azimuth: int = 512) -> np.ndarray:
    """:func:`_ordinate18_table`, built once per process (light domains solved side by side
    on Python threads wait for the first)."""
    with _TABLE18_LOCK:
        return _ordinate18_table(n_a, n_mu, n_azimuth)


@functools.lru_cache(maxsize=2)
def _ordinate18_table(n_a: int = 257, n_mu: int = 2048, n_azimuth: int = 512) -> np.ndarray:
    """float32 (18, n_a, 2, 18): for a lobe HG_a about ordinate o's direction e_o (a =
    linspace(-1, 1, n_a)), [o, a, 0, n] the share of it in ordinate n's part of the sphere (the
    directions nearer to e_n than to any other of the 18, :data:`ORDINATES18`), and [o, a, 1,
    n] that share times its mean cosine about e_n (kernels/ordinates18.py). The shares of a lobe sum to 1.

    By quadrature over n_mu bands of cosine about the lobe's axis (each weighted by the lobe's
    exact integral over it) times n_azimuth azimuths (kernels.ordinates18.nearest_ordinate_bands),
    for one face and one edge; the other ordinates follow by the cube's symmetries.
    a = +-1 (a delta along +-e_o) is all in ordinate o (or its opposite), with mean cosine 1."""
    axes = ORDINATES18 / np.linalg.norm(ORDINATES18, axis=1)[:, None]
    edges = np.linspace(-1.0, 1.0, n_mu + 1)
    mu = 0.5 * (edges[1:] + edges[:-1])
    phi = (np.arange(n_azimuth) + 0.5) / n_azimuth * 2.0 * np.pi
    a = np.linspace(-1.0, 1.0, n_a)
    # each band of cosines weighted by HG_a's integral over it, exact however peaked the lobe:
    # int (1 - a^2) (1 + a^2 - 2 a mu)^-3/2 dmu = (1 - a^2) / a (1 + a^2 - 2 a mu)^-1/2
    inner = a[1:-1, None]
    flat = np.abs(inner) < 1e-6
    g = np.where(flat, 0.5, inner)
    primitive = (1.0 - g ** 2) / g / np.sqrt(1.0 + g ** 2 - 2.0 * g * edges[None, :])
    lobe = np.where(flat, np.diff(edges)[None, :], np.diff(primitive, axis=1))
    table = np.zeros((18, n_a, 2, 18))
    for c in (0, 6):                     # a face and an edge
        e = axes[c]
        p = np.cross(e, [0.0, 0.0, 1.0] if abs(e[2]) < 0.9 else [1.0, 0.0, 0.0])
        p /= np.linalg.norm(p)
        q = np.cross(e, p)
        ring = np.cos(phi)[:, None] * p + np.sin(phi)[:, None] * q          # (n_azimuth, 3)
        frac, cos = np.zeros((n_mu, 18)), np.zeros((n_mu, 18))
        KO18.nearest_ordinate_bands(mu, ring, e, axes, frac, cos)
        share = np.einsum("am,mn->an", lobe, frac)
        moment = np.einsum("am,mn->an", lobe, cos)
        total = share.sum(axis=1, keepdims=True)
        table[c, 1:-1, 0] = share / total
        table[c, 1:-1, 1] = moment / total
        opposite = int(np.flatnonzero((ORDINATES18 == -ORDINATES18[c]).all(axis=1))[0])
        table[c, -1, :, c] = (1.0, 1.0)
        table[c, 0, :, opposite] = (1.0, 1.0)
    index_of = {tuple(v): n for n, v in enumerate(ORDINATES18)}
    rotations = _signed_permutations()
    for o in range(18):
        c = 0 if o < 6 else 6
        R = next(R for R in rotations if (R @ ORDINATES18[c] == ORDINATES18[o]).all())
        image = [index_of[tuple(R @ ORDINATES18[n])] for n in range(18)]
        table[o][..., image] = table[c]
    return table.astype(np.float32)


#: texels per side of each face of :func:`direction_split`'s cube map (about 5.6 degrees each)
SPLIT_TEXELS = 16
#: quadrature directions over the sphere of :func:`direction_split`'s tables
SPLIT_QUADRATURE = 8192
#: anisotropies at which :func:`direction_split` is tabulated: -1 .. 1 in steps of this
SPLIT_G_STEP = 0.05


def fibonacci_directions(n: int) -> np.ndarray:
    """float64 (n, 3): unit directions of a Fibonacci lattice, each the centre of an equal
    solid angle 4 pi / n (the quadratures of :func:`_direction_split` and of lights.point)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    ring = np.sqrt(1.0 - z * z)
    turn = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([ring * np.cos(turn), ring * np.sin(turn), z], axis=-1)


def _cube_axes(face: int) -> tuple[int, float, int, int]:
    """A cube map's face (2 axis + (the component is negative)): (axis, its sign, the two other
    axes in increasing order)."""
    axis = face // 2
    others = [a for a in range(3) if a != axis]
    return axis, -1.0 if face % 2 else 1.0, others[0], others[1]


@functools.lru_cache(maxsize=64)
def _direction_split(n_ordinates: int, g: float) -> np.ndarray:
    """float32 (6, T, T, 2, n_ordinates), T = SPLIT_TEXELS: for a lobe HG_g about the direction
    of each texel of a cube map (face f (:func:`_cube_axes`), texel (s, t) of the two other
    components over the largest's absolute value, in [-1, 1]), [..., 0, n] its share in
    ordinate n's part of the sphere (the directions nearer to e_n than to any other of the first
    ``n_ordinates`` of :data:`ORDINATES18`) and [..., 1, n] that share times the part's mean
    cosine about e_n, as the walks' own split (:func:`ordinate18_table`) gives a lobe about an
    ordinate. By quadrature over SPLIT_QUADRATURE directions of a Fibonacci lattice (equal
    areas); the shares of a lobe sum to 1."""
    axes = ORDINATES18[:n_ordinates] / np.linalg.norm(ORDINATES18[:n_ordinates], axis=1)[:, None]
    omega = fibonacci_directions(SPLIT_QUADRATURE)
    dots = omega @ axes.T
    part = np.argmax(dots, axis=1)
    member = np.zeros((SPLIT_QUADRATURE, n_ordinates))
    member[np.arange(SPLIT_QUADRATURE), part] = 1.0
    cosine = member * dots[np.arange(SPLIT_QUADRATURE), part][:, None]
    s = (np.arange(SPLIT_TEXELS) + 0.5) / SPLIT_TEXELS * 2.0 - 1.0
    table = np.zeros((6, SPLIT_TEXELS, SPLIT_TEXELS, 2, n_ordinates))
    g = float(np.clip(g, -0.999, 0.999))
    for face in range(6):
        axis, sign, a1, a2 = _cube_axes(face)
        d = np.zeros((SPLIT_TEXELS, SPLIT_TEXELS, 3))
        d[..., axis] = sign
        d[..., a1], d[..., a2] = np.meshgrid(s, s, indexing="ij")
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        f = hg.f_hg(d.reshape(-1, 3) @ omega.T, g)                  # (T T, Q)
        total = f.sum(axis=1, keepdims=True)
        table[face, :, :, 0] = (f @ member / total).reshape(SPLIT_TEXELS, SPLIT_TEXELS, n_ordinates)
        table[face, :, :, 1] = (f @ cosine / total).reshape(SPLIT_TEXELS, SPLIT_TEXELS, n_ordinates)
    return table.astype(np.float32)


def direction_split(directions: np.ndarray, g: np.ndarray, n_ordinates: int) -> tuple[np.ndarray, np.ndarray]:
    """Lobes HG_g about any ``directions`` (float64 (m, 3), unit, in the domain's frame) split
    among the ordinates of the ordinates' walks as they split a lobe about an ordinate (each
    part goes into the ordinate whose part of the sphere it falls in, with its mean cosine about
    that ordinate's direction): (share, share times mean cosine), float32 (m, n_ordinates).
    Looked up in :func:`_direction_split`'s cube map, bilinear between the texels of a
    direction's face, and linear in g (float (m,), clipped to [-1, 1]) between the
    anisotropies tabulated SPLIT_G_STEP apart."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    m = len(d)
    if m == 0:
        return np.zeros((0, n_ordinates), np.float32), np.zeros((0, n_ordinates), np.float32)
    absd = np.abs(d)
    axis = np.argmax(absd, axis=1)
    rows = np.arange(m)
    face = 2 * axis + (d[rows, axis] < 0)
    big = np.maximum(absd[rows, axis], 1e-300)
    a1 = np.where(axis == 0, 1, 0)
    a2 = np.where(axis == 2, 1, 2)
    def texels(c):
        """The two texels about each coordinate c (over the largest's absolute value) and the
        weight of the upper one (clamped at the face's edges)."""
        x = np.clip((c / big + 1.0) * 0.5 * SPLIT_TEXELS - 0.5, 0.0, SPLIT_TEXELS - 1.0)
        i0 = np.minimum(x.astype(np.int64), SPLIT_TEXELS - 2)
        return i0, x - i0
    s0, fs = texels(d[rows, a1])
    t0, ft = texels(d[rows, a2])
    texel = (face * SPLIT_TEXELS + s0) * SPLIT_TEXELS + t0           # the corner (s0, t0) of each
    corners = [(texel + i * SPLIT_TEXELS + j, (fs if i else 1.0 - fs) * (ft if j else 1.0 - ft))
               for i in (0, 1) for j in (0, 1)]
    x = (np.clip(np.broadcast_to(np.asarray(g, np.float64), (m,)), -1.0, 1.0) + 1.0) / SPLIT_G_STEP
    x = np.where(np.abs(x - np.round(x)) < 1e-6, np.round(x), x)     # on a tabulated anisotropy: one table
    n_g = int(round(2.0 / SPLIT_G_STEP))
    lo = np.minimum(x.astype(np.int64), n_g - 1)
    w = x - lo
    bins = np.unique(np.concatenate([lo, (lo + 1)[w > 0]]))
    texels_per_table = 6 * SPLIT_TEXELS * SPLIT_TEXELS
    table = np.concatenate([_direction_split(n_ordinates, round(-1.0 + b * SPLIT_G_STEP, 6)).reshape(
        texels_per_table, 2 * n_ordinates) for b in bins])
    rows = np.empty((m, 8), np.int64)
    weights = np.empty((m, 8), np.float32)
    for q, (upper, wg) in enumerate(((0, 1.0 - w), (1, w))):
        at_bin = np.searchsorted(bins, np.minimum(lo + upper, bins[-1])) * texels_per_table
        for c, (index, wc) in enumerate(corners):
            rows[:, 4 * q + c] = at_bin + index
            weights[:, 4 * q + c] = wg * wc
    out = np.empty((m, 2 * n_ordinates), np.float32)
    KS.blend_rows(table, rows, weights, out)
    return out[:, :n_ordinates], out[:, n_ordinates:]


def anisotropy_bins(n: int = ANISOTROPY_BINS) -> np.ndarray:
    """float64 (n,): the binned wavefront's anisotropies, evenly spaced over [-1, 1] (n odd, so
    that a = 0 is a bin; a = 1 always is, for collimated light)."""
    return np.linspace(-1.0, 1.0, n)


@functools.lru_cache(maxsize=4)
def bin_shares(n: int = ANISOTROPY_BINS, rule: str = "moment") -> np.ndarray:
    """float64 (n, 6): for the lobe HG_a of each of :func:`anisotropy_bins`, the front share, the
    share of EACH side neighbour and the back share (supplement Eq. 2, 4, 7, exact), then the
    three parts' outgoing anisotropy before decay: their conditional mean cosines (rule
    "moment") or a itself (rule "paper")."""
    a = anisotropy_bins(n)
    out = np.zeros((n, 6))
    out[:, 0], out[:, 1], out[:, 2] = hg.split_fractions(a)
    out[:, 3:] = np.stack(hg.conditional_mean_cosines(a), 1) if rule == "moment" else a[:, None]
    return out


def medium_factors(sigma_t: np.ndarray, sigma_s: np.ndarray, g: np.ndarray, h: float, decay: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Half-step transmittance Th and anisotropy decay Dh per cell, float32 (the broadcast
    shape of the arguments, at most 3-D; h is the step length, a number).

    Th = exp(-sigma_a h / 2)  (only absorption removes energy; scattering widens the lobe).
    Dh = g^(sigma_s h / 2)    (decay "paper", supplement Eq. 12; needs g >= 0), or
         exp(-sigma_s h (1 - g) / 2)  (decay "poisson": E[g^n] for n ~ Poisson(sigma_s h)).
    (kernels/cells.py)
    """
    shape, (st, ss, gg) = _cells(sigma_t, sigma_s, g)
    Th, Dh = np.empty(st.shape, np.float32), np.empty(st.shape, np.float32)
    KC.medium_factors(st, ss, gg, float(h), decay == "paper", Th, Dh)
    return Th.reshape(shape), Dh.reshape(shape)


def handover_factor(sigma_t, sigma_s, g, s: float) -> np.ndarray:
    """float32: per cell, f = 1 - exp(-sigma_tr s) (sigma_tr = sigma_a + sigma_s (1 - g), s the
    cell's step length, a number): the share of a lobe's first moment the medium removes
    over one cell. A packet hands over when |a| < method.handover_scale * f, so the criterion
    follows the transport mean free path, not the cell count (docs/METHOD.md, "Hand-over").
    0 outside the diffusion region (sigma_s = 0 or sigma_t = 0). (kernels/cells.py)"""
    shape, (st, ss, gg) = _cells(sigma_t, sigma_s, g)
    out = np.empty(st.shape, np.float32)
    KC.handover_factor(st, ss, gg, float(s), out)
    return out.reshape(shape)


def direct_fluence(sigma_t: np.ndarray, h: float) -> np.ndarray:
    """float32 (n_d, n_u, n_v): fluence of the unscattered light at the cell centres of a
    domain whose first axis runs from the light, per unit irradiance: exp(-tau), tau = sigma_t
    integrated from the face k = 0 to the centre (Beer-Lambert, sigma_t piecewise constant;
    kernels/cells.py)."""
    sigma_t = np.ascontiguousarray(sigma_t, np.float32)
    out = np.empty(sigma_t.shape, np.float32)
    KC.direct_fluence(sigma_t, float(h), out)
    return out


def _cells(*arrays):
    """(the broadcast shape of ``arrays``, each as a contiguous float32 3-D array of it, a
    lower-dimensional shape padded with leading 1s) for the kernels of kernels/cells.py."""
    shape = np.broadcast_shapes(*(np.shape(a) for a in arrays))
    if len(shape) > 3:
        raise ValueError(f"per-cell arrays of at most 3 dimensions, not {shape}")
    cube = (1,) * (3 - len(shape)) + shape
    return shape, tuple(np.ascontiguousarray(np.broadcast_to(np.asarray(a, np.float32), shape)).reshape(cube)
                        for a in arrays)


def replace_direct(result: WalkResult, direct: np.ndarray) -> None:
    """Swap the unscattered light the walk's fields hold for ``direct`` (float32, the domain's
    shape), keeping the scattered rest: phi - direct + direct' and the same for phi a (the
    unscattered lobe has a = 1). Used where the walk solved a capped medium
    (medium.transport_medium) and the unscattered light crosses the true one. In place for phi
    a, so a six-ordinate walk's flux (whose first row it is) follows."""
    change = direct - result.direct
    result.phi = result.phi + change
    result.phia += change
    result.direct = direct


def default_max_iterations(shape, solver: str) -> int:
    if solver in ("jacobi", "binned"):
        return 40 * int(sum(shape))
    return 400


def handover_arrays(handover, shape):
    """(scale, per-cell factor, Q) as the kernels take them, from ``handover`` = (scale,
    float32 per-cell :func:`handover_factor`) or None (no hand-over: scale -1, and the factor and
    Q are dummies); Q is float32 (2,) + shape, zeroed: handed-over power and first moment."""
    if handover is None:
        return -1.0, np.zeros((1, 1, 1), np.float32), np.zeros((2, 1, 1, 1), np.float32)
    scale, factor = handover
    return float(scale), np.ascontiguousarray(factor, np.float32), np.zeros((2,) + tuple(shape), np.float32)


def hand_over_pending(W, Wa, Th, Dh, diffusive, Q) -> float:
    """When the sweeps stop, the packets still pending in the diffusion region (``diffusive`` >
    0) go to the diffusion stage instead of being left in flight: each gets its cell's half
    step (as when it is next sent: power W Th, moment Wa Th Dh) and is added to Q[0], Q[1].
    Their lobes have spread (what is left late in a walk has |a| ~ 0.1), so diffusion is where
    they would mostly have gone; with tolerance 3e-3 this moves the images of the gallery's
    scenes by relMSE <= 2e-4 from a walk run to 1e-3. W and Wa are zeroed there (in place);
    returns the power the half steps absorbed [W] (kernels/cells.py)."""
    return float(KC.hand_over_pending(W, Wa, Th, Dh, diffusive, Q))


def sweep_until_converged(one_sweep, in_flight: float, target: float, cap: int, n_cells: int,
                          injected: float, progress=None, least: int = 0, floor: float = 0.0
                          ) -> tuple[float, int, int]:
    """Run thresholded Gauss-Seidel sweeps until the power in flight is <= target or ``cap``
    sweeps have run, and at least ``least`` sweeps unless the power in flight is <= ``floor``
    first; ``one_sweep(it, w_min)`` sweeps once and returns (power still in flight,
    number of cells that sent). Returns (in flight, sweeps, cells that sent over all sweeps).

    Southwell-style: only cells holding more than twice the mean pending energy (in flight
    over ``n_cells``) send; the others wait for more to arrive, which skips most of the faint
    light in empty space. Near the tolerance (in flight under 10 times ``floor``, or ``target``
    where ``floor`` is 0) the fraction drops to 1/2 (the fullest cell always qualifies: max >=
    mean), and should no cell qualify, the next sweep sends them all.
    """
    fraction = SOUTHWELL_FRACTION
    near = floor if floor > 0.0 else target
    it = 0
    sent_total = 0
    while (in_flight > target or (it < least and in_flight > floor)) and it < cap:
        if in_flight < 10.0 * near:
            fraction = min(fraction, 0.5)
        in_flight, sent = one_sweep(it, fraction * in_flight / n_cells)
        fraction = fraction if sent > 0 else 0.0
        sent_total += int(sent)
        it += 1
        if progress is not None:
            progress(it, in_flight / injected)
    return in_flight, it, sent_total


def walk_binned(Th, Dh, injection, a0, rule, periodic, inv_area, phi, phia, tally, eps, diffusive, Q,
                target, cap, progress=None) -> tuple[int, float, float]:
    """The binned wavefront (kernels/binned.py) of :func:`walk_box`: returns (iterations, power in
    flight, power the injection's half step absorbed). Accumulates into phi, phia, tally, Q. With
    the hand-over, what is still pending when it stops goes to Q (it is at cell centres)."""
    shape = Th.shape
    ab = anisotropy_bins()
    shares = bin_shares(len(ab), rule)
    check_memory(2 * len(ab) * int(np.prod(shape)) * 4, "method.resolution (with experimental.solver = 'binned')",
                 f"the {len(ab)} anisotropy bins of a {'x'.join(map(str, shape))} domain (twice)")
    W = np.zeros((len(ab),) + shape, np.float32)
    W_next = np.zeros_like(W)
    # the injected light crosses half a cell to the first centres (a0 decayed by Dh[0])
    KB.inject(W, ab, (injection * Th[0]).astype(np.float64), np.float64(a0) * Dh[0].astype(np.float64),
              float(eps), diffusive, Q)
    absorbed = float(np.sum(injection * (1.0 - Th[0]), dtype=np.float64))
    injected = float(np.sum(injection, dtype=np.float64))
    in_flight = float(np.sum(W, dtype=np.float64))
    it = 0
    while in_flight > target and it < cap:
        KB.binned_send(W, ab, shares, Th, periodic, inv_area, phi, phia, tally)
        in_flight = KB.binned_gather(W, ab, shares, Th, Dh, periodic, float(eps), diffusive, Q, W_next, tally)
        W, W_next = W_next, W
        it += 1
        if progress is not None and it % 16 == 0:
            progress(it, in_flight / max(injected, 1e-300))
    if eps > 0:
        region = diffusive > 0
        Q[0] += np.where(region, W.sum(axis=0, dtype=np.float64), 0.0).astype(np.float32)
        Q[1] += np.where(region, np.tensordot(ab, W.astype(np.float64), axes=1), 0.0).astype(np.float32)
        W[:, region] = 0.0
        in_flight = float(np.sum(W, dtype=np.float64))
    return it, in_flight, absorbed


def scatter_factor(sigma_s, h: float) -> np.ndarray:
    """float32 (sigma_s's shape): per cell, the half-step no-scatter transmittance Sh = exp(-sigma_s
    h / 2), so that exp(-sigma_s s) over a transfer is Sh of sender times Sh of receiver; the
    six-ordinate walk's share of a packet that crosses a transfer unscattered (docs/METHOD.md,
    "Six ordinates")."""
    return np.exp(np.asarray(sigma_s, np.float32) * np.float32(-0.5 * h))


def row_groups(row_work: np.ndarray, visits: float, forward_u: bool, lanes: int) -> np.ndarray:
    """int64 (groups + 1,): where to cut the rows of a six- or eighteen-ordinate sweep into
    groups (kernels.ordinates.ordinates_sweep, one per thread; kernels.ordinates18, GROUPS18),
    as row positions in the sweep's order along u: the cuts share out each row's work,
    ``row_work`` (float (n_u,), packets sent per row i in the sweep before) plus ``visits`` /
    propagation.VISIT_COST per row (its cells' visits), evenly. At most ``lanes`` groups, none
    empty. For the six-ordinate sweep where the rows are cut never changes the result, only the
    time; the eighteen-ordinate sweep's fields depend on the cut, which depends on the fields
    and GROUPS18, not on the thread count."""
    n1 = row_work.shape[0]
    work = row_work + visits / K.VISIT_COST
    if not forward_u:
        work = work[::-1]
    cum = np.cumsum(work)
    groups = max(min(int(lanes), n1), 1)
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, groups) / groups, side="right")
    return np.unique(np.concatenate(([0], np.clip(cuts, 1, n1 - 1), [n1]))).astype(np.int64)


def skipped_cells(Th, Dh, Sh, read) -> np.ndarray:
    """bool (the domain's shape): the cells the six-ordinate walk crosses without visiting them
    (docs/METHOD.md, "Skipping empty space"): empty (Th = Dh = Sh = 1: a packet crosses it
    unchanged), their fields not ``read`` (bool, the domain's shape), and none of their 26
    neighbours holding medium, so that a run of them ends at an empty cell: the cells neither
    read nor :func:`never_skipped`."""
    return ~read & ~never_skipped(Th, Dh, Sh)


def never_skipped(Th, Dh, Sh) -> np.ndarray:
    """bool (the domain's shape): the cells the ordinates' walks visit whatever is read: those
    a packet does not cross unchanged (a factor below 1: medium, however thin) and their 26
    neighbours (:func:`skipped_cells`). A source of packets (:func:`place`) may use only these."""
    return grow(~((Th == 1) & (Dh == 1) & (Sh == 1)))


def inject(W, Wa, Th, Dh, injection, a0, cell, pending, tally) -> tuple[float, float]:
    """The light injected at the face k = 0 of an ordinates walk (:func:`walk_ordinates`,
    :func:`walk_ordinates18`) into ordinate +d (column 0 of W, Wa, one row per cell not skipped:
    ``cell``): it crosses half a cell to the first centres (a0 decayed by Dh there), in slice 0,
    or, where a column starts with skipped cells, in the cell after them; a column skipped
    throughout transmits it (``tally``). Marks the rows it enters ``pending``. Returns (power
    the half step into slice 0 absorbed, power injected)."""
    kept = cell >= 0
    first = np.argmax(kept, axis=0)                    # the first cell of each column along d kept
    ahead = kept.any(axis=0)
    I, J = np.nonzero(ahead)
    k1 = first[ahead]
    c = cell[k1, I, J]
    W[c, 0] = injection[ahead] * Th[k1, I, J]
    Wa[c, 0] = W[c, 0] * np.float32(a0) * Dh[k1, I, J]
    pending[k1, I] = 1
    tally[K.TRANSMITTED] += float(np.sum(injection[~ahead], dtype=np.float64))
    absorbed = float(np.sum(injection * (1.0 - Th[0]), dtype=np.float64))
    return absorbed, float(np.sum(injection, dtype=np.float64))


def place(W, Wa, cell, pending, source) -> tuple[float, float]:
    """Packets pending at cell centres at the start of an ordinates walk, in place of
    :func:`inject`'s: ``source`` = (index, int (3, k), the cells (none skipped); power, float32
    (k, n_ordinates), per ordinate; moment, the same times each lobe's anisotropy), written
    into the first n_ordinates columns of W, Wa. Marks their rows ``pending``. Returns (0, the
    power placed)."""
    index, power, moment = source
    c = cell[tuple(index)]
    if (c < 0).any():
        raise ValueError("a source packet in a skipped cell")
    n = power.shape[1]
    W[c, :n] = power
    Wa[c, :n] = moment
    pending[index[0], index[1]] = 1
    return 0.0, float(np.sum(power, dtype=np.float64))


def sweep_order(it: int) -> tuple[bool, bool, bool]:
    """Whether sweep ``it`` of an ordinates walk runs forward along d, u and v: every sweep
    reverses all three, so with upwind sweeps every ordinate is sent every second sweep
    (docs/METHOD.md, "Six ordinates")."""
    forward = it % 2 == 0
    return forward, forward, forward


def ordinates_ahead(offsets: np.ndarray, forward: tuple[bool, bool, bool]) -> np.ndarray:
    """bool (n,): which of the ordinates ``offsets`` (int (n, 3), in cells along d, u, v) point
    ahead in the order of a sweep that runs forward along each axis where ``forward`` says so
    (toward a cell later in the order k, then i, then j): the ordinates an upwind sweep sends."""
    along = np.asarray(offsets) * np.where(forward, 1, -1)
    first = along[np.arange(len(along)), np.argmax(along != 0, axis=1)]     # first nonzero step
    return first > 0


def walk_ordinates(Th, Dh, Sh, injection, a0, inv_area, phi, flux, tally, target, cap, progress=None,
                   skip=None, source=None) -> tuple[int, float, float, int]:
    """The six-ordinate walk (kernels/ordinates.py) of :func:`walk_box` (``Sh``: float32, the
    domain's shape, :func:`scatter_factor`), every order of scattering, by thresholded
    Gauss-Seidel sweeps (:func:`sweep_until_converged`, every packet slot of every cell counted
    in the mean pending power): the injected light enters ordinate +d; the sweeps alternate +d
    / -d, and along u and v with it, every sweep (:func:`sweep_order`), and each sends only
    the ordinates that point ahead in its order (upwind; the others wait for a sweep their
    way). Returns (sweeps, power in flight, power the injection's half step absorbed, packets sent).
    Accumulates into phi, flux (float32 (3,) + shape, the first moment in the domain's frame)
    and tally, except in the ``skip`` cells (:func:`skipped_cells`; None: none), which light
    crosses a run at a time (kernels.cells.skip_runs, int16 (6,) + shape) and which hold no
    packet. The pending state W, Wa is float32 (m, 12), one row per cell not skipped (its
    index in ``cell``, int32, the domain's shape, -1 where skipped): the six ordinates, then
    per ordinate o the light that scattered in the cell's half of its way in along e_o
    (kernels/ordinates.py). ``source``: packets pending at the start in place of the injected
    light (:func:`place`)."""
    shape = Th.shape
    if max(shape) > KC.MAX_RUN:
        raise ValueError(f"the six-ordinate walk takes domains of at most {KC.MAX_RUN} cells a side, not {shape}")
    n = int(np.prod(shape))
    kept = np.ones(shape, np.bool_) if skip is None else ~np.asarray(skip, np.bool_)
    m = int(np.count_nonzero(kept))
    check_memory(2 * 12 * 4 * m + (4 + 6 * 2) * n,
                 "method.resolution (with experimental.solver = 'ordinates', the default)",
                 f"the 6 ordinates of a {'x'.join(map(str, shape))} domain (power and moment, twice)")
    cell = np.full(shape, -1, np.int32)
    cell[kept] = np.arange(m, dtype=np.int32)
    runs = np.zeros((6,) + shape, np.int16)
    if skip is not None:
        KC.skip_runs(~kept, runs)
    table = ordinate_table()
    W = np.zeros((m, 12), np.float32)
    Wa = np.zeros_like(W)
    pending = np.zeros(shape[:2], np.uint8)
    absorbed, injected = (inject(W, Wa, Th, Dh, injection, a0, cell, pending, tally) if source is None
                          else place(W, Wa, cell, pending, source))

    row_work = np.zeros(shape[1])
    lanes = numba.get_num_threads()

    def one_sweep(it, w_min):
        # the rows cut into one group per thread by the work each row did in the sweep before
        fd, fu, fv = sweep_order(it)
        edges = row_groups(row_work, shape[0] * shape[2], fu, lanes)
        sent = KO.ordinates_sweep(W, Wa, Th, Dh, Sh, table, inv_area, phi, flux, np.float32(w_min), fd,
                                  fu, fv, tally, edges, row_work, cell, runs, pending,
                                  ordinates_ahead(ORDINATES6, (fd, fu, fv)))
        return K.total_energy(W.reshape(m, 1, 12)), sent
    in_flight, it, sent = sweep_until_converged(one_sweep, float(np.sum(W, dtype=np.float64)), target, cap,
                                                6 * n, injected, progress)
    return it, in_flight, absorbed, sent


def edge_factors(x: np.ndarray, e: np.float32) -> np.ndarray:
    """float32, x's shape: x ** e (kernels/cells.py, :func:`~popvol.kernels.cells.edge_factors`)."""
    x = np.ascontiguousarray(x, np.float32)
    out = np.empty_like(x)
    KC.edge_factors(x, np.float32(e), out)
    return out


def walk_ordinates18(Th, Dh, Sh, injection, a0, inv_area, phi, flux, tally, target, cap, progress=None,
                     skip=None, source=None, tail=0.0, tail_factor=0) -> tuple[int, float, float, int, tuple | None]:
    """The eighteen-ordinate walk (kernels/ordinates18.py) of :func:`walk_box`: as
    :func:`walk_ordinates` with a direction per face and per edge of the lattice, visiting
    every cell of a pending row that is not skipped. The injected light enters ordinate +d of
    slice 0; the sweeps reverse their order along d, u and v every sweep (:func:`sweep_order`),
    each sending only the ordinates that point ahead in its order (upwind). The
    rows are cut into GROUPS18 groups that sweep as a pipeline (:func:`row_groups`, by the
    packets each row sent in the sweep before), whatever the number of threads. Returns
    (sweeps, power in flight, power the injection's half step absorbed, packets sent);
    accumulates into phi, flux (float32 (3,) + shape, the domain's frame) and tally, except in
    the ``skip`` cells (:func:`skipped_cells`; None: none), which hold no packet and which light
    crosses along its ordinate without a visit. The pending state W, Wa is float32 (m, 18), one
    row per cell not skipped (its index in ``cell``, int32, the domain's shape, -1 where
    skipped). ``source``: packets pending at the start in place of the injected light
    (:func:`place`). With ``tail_factor`` > 0 only the packets above twice the mean pending
    power per ordinate of the cells not skipped are sent (the fainter wait), it stops once at
    most ``tail`` of the injected power is in flight after two sweeps or more (one each way
    along d), and the packets then pending, if more than ``target``, are taken out of the walk
    and returned on blocks of tail_factor^3 cells (:func:`block_packets`; else None), the power
    in flight then 0."""
    shape = Th.shape
    n = int(np.prod(shape))
    kept = np.ones(shape, np.bool_) if skip is None else ~np.asarray(skip, np.bool_)
    m = int(np.count_nonzero(kept))
    # parts that can be held to a sweep's end: one per kept cell and (d, u) edge whose neighbour
    # along it is skipped (kernels/ordinates18.py)
    held = 1
    if skip is not None and skip.any():
        for off in ORDINATES18[6:10]:                  # the (d, u) edges
            ahead = np.zeros(shape, np.bool_)
            src = tuple(slice(max(-x, 0), shape[a] - max(x, 0)) for a, x in enumerate(off))
            dst = tuple(slice(max(x, 0), shape[a] - max(-x, 0)) for a, x in enumerate(off))
            ahead[src] = skip[dst]
            held += int(np.count_nonzero(ahead & kept))
    check_memory(3 * 18 * 4 * m + 4 * 3 * n + 4 * n + GROUPS18 * held * 40 + ORDINATE18_TABLE_BYTES,
                 "experimental.ordinates (18) with method.resolution",
                 f"the 18 ordinates of a {'x'.join(map(str, shape))} domain (power, moment and landing cells)")
    cell = np.full(shape, -1, np.int32)
    cell[kept] = np.arange(m, dtype=np.int32)
    table = ordinate18_table()
    root2 = np.float32(np.sqrt(2.0))
    Th2, Dh2, Sh2 = (edge_factors(x, root2) for x in (Th, Dh, Sh))
    W = np.zeros((m, 18), np.float32)
    Wa = np.zeros_like(W)
    landing = np.full((m, 18), KO18.UNKNOWN, np.int32)
    pending = np.zeros(shape[:2], np.uint8)
    absorbed, injected = (inject(W, Wa, Th, Dh, injection, a0, cell, pending, tally) if source is None
                          else place(W, Wa, cell, pending, source))
    flat = W.reshape(m, 1, 18)
    row_work = np.zeros(shape[1])
    held_at = np.zeros((GROUPS18, held, 3), np.int64)
    held_parts = np.zeros((GROUPS18, held, 2))

    def one_sweep(it, w_min):
        fd, fu, fv = sweep_order(it)
        edges = row_groups(row_work, shape[0] * shape[2], fu, GROUPS18)
        sent, held = KO18.ordinates18_sweep(W, Wa, Th, Dh, Sh, Th2, Dh2, Sh2, ORDINATES18, table, inv_area, phi,
                                            flux, np.float32(w_min), fd, fu, fv, tally,
                                            cell, landing, pending, edges, row_work, held_at, held_parts,
                                            ordinates_ahead(ORDINATES18, (fd, fu, fv)))
        HELD18[0] += held
        return K.total_energy(flat), sent
    # with a tail: at least one sweep each way along d before it, and the packets under twice
    # the mean of the cells the walk holds (not of the whole domain, mostly empty) left for it
    stop, least, slots = (max(target, tail * injected), 2, 18 * m) if tail_factor else (target, 0, 18 * n)
    in_flight, it, sent = sweep_until_converged(one_sweep, K.total_energy(flat), stop, cap, slots, injected,
                                                progress, least=least, floor=target)
    if tail_factor and in_flight > target:
        return it, 0.0, absorbed, sent, block_packets(W, Wa, cell, pending, tail_factor)
    return it, in_flight, absorbed, sent, None


def block_packets(W, Wa, cell, pending, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The packets an ordinates walk holds (W, Wa float32 (m, n_ordinates), one row per cell not
    skipped: ``cell``; only its rows (k, i) marked ``pending`` hold any) moved to the blocks of
    factor^3 cells that hold them, summed per ordinate (kernels.ordinates18.held_blocks, then
    pending_blocks, which sums into one row per such block), as
    :func:`place` takes them on the blocks' grid: (index int64 (3, k), the blocks holding any;
    power float32 (k, n_ordinates); moment, the same times each lobe's anisotropy)."""
    held = np.zeros(tuple(-(-s // factor) for s in cell.shape), np.uint8)
    KO18.held_blocks(W, cell, pending, factor, held)
    index = np.array(np.nonzero(held))
    slot = np.full(held.shape, -1, np.int32)
    slot[tuple(index)] = np.arange(index.shape[1], dtype=np.int32)
    P = np.zeros((index.shape[1], W.shape[1]), np.float32)
    M = np.zeros_like(P)
    KO18.pending_blocks(W, Wa, cell, pending, factor, slot, P, M)
    return index, P, M


def walk_tail(optics, h: float, a0: float, source, read, factor: int, target: float, decay: str,
              cap: int) -> WalkResult:
    """The eighteen-ordinate walk's last light on coarser cells (docs/METHOD.md, "The walk's
    tail on wider cells"): the packets a walk on cells of size h with ``optics`` (sigma_t,
    sigma_s, g, float32, its shape) held when it stopped, moved to blocks of factor^3 of its
    cells (``source``, :func:`block_packets`), walked on the blocks with their optics
    (diffusion.coarse_optics) until at most ``target`` [W] is in flight. ``read``: the cells
    whose fields are read (bool, the walk's shape; None: all); a block is read where it or one
    of its 26 neighbours holds such a cell (the blocks :func:`add_tail`'s trilinear stencils
    reach), or where it holds a packet. Returns the blocks' WalkResult (phi and flux on
    the blocks, cells of size factor h; :func:`add_tail` adds them to the walk's)."""
    sigma_t, sigma_s, g = (x.astype(np.float32) for x in coarse_optics(*optics, factor))
    H = h * factor
    if read is None:
        read_blocks = np.ones(sigma_t.shape, np.bool_)
    else:
        holds = np.zeros(sigma_t.shape, np.bool_)
        k, i, j = np.nonzero(read)
        holds[k // factor, i // factor, j // factor] = True
        read_blocks = grow(holds)                # the blocks their trilinear stencils reach
        read_blocks[tuple(source[0])] = True
    power = float(np.sum(source[1], dtype=np.float64))
    Th, Dh = medium_factors(sigma_t, sigma_s, g, H, decay)
    return walk_box(Th, Dh, None, a0, H, "moment", "ordinates", min(target / max(power, 1e-300), 1.0), cap,
                    scatter=scatter_factor(sigma_s, H), read=read_blocks, ordinates=18, source=source)


def add_tail(walk: WalkResult, tail: WalkResult, factor: int, read) -> None:
    """Add the fields of ``tail`` (:func:`walk_tail`, on blocks of factor^3 cells) to the walk's
    phi and flux (so to phia, its flux[0]; its cells', where ``read``; None: every cell),
    trilinear between the blocks' centres (kernels.sampling.add_upsampled_blocks)."""
    coarse = np.ascontiguousarray(np.stack([tail.phi, *tail.flux], axis=-1), np.float32)
    needed = np.ones(walk.phi.shape, np.bool_) if read is None else read
    KS.add_upsampled_blocks(coarse, factor, needed, walk.phi, walk.flux)


def walk_the_tail(walk: WalkResult, optics, h: float, a0: float, read, factor: int, tolerance: float,
                  decay: str, cap: int) -> None:
    """Walk the packets ``walk`` (an eighteen-ordinate walk on cells of size h with ``optics``,
    stopped by :func:`walk_box`'s ``tail``) still held, on blocks of factor^3 of its cells,
    until at most ``tolerance`` of the light it was injected is in flight (:func:`walk_tail`),
    and add their fields to its own (:func:`add_tail`) and their budget to its budget; its
    ``tail`` is then that walk, its ``pending`` None, and its seconds include the tail's."""
    t0 = time.perf_counter()
    b = walk.budget
    tail = walk_tail(optics, h, a0, walk.pending, read, factor, tolerance * b.injected, decay, cap)
    add_tail(walk, tail, factor, read)
    for name in ("reflected", "transmitted", "side", "absorbed", "in_flight"):
        setattr(b, name, getattr(b, name) + getattr(tail.budget, name))
    walk.residual = b.in_flight / max(b.injected, 1e-300)
    walk.converged = tail.converged
    walk.seconds += time.perf_counter() - t0
    walk.tail, walk.pending = tail, None


def walk_box(Th: np.ndarray, Dh: np.ndarray, injection: np.ndarray, a0: float, h: float,
             rule: str = "moment", solver: str = "sweep", tolerance: float = 1e-3,
             max_iterations: int = 0, periodic: bool = False, progress=None,
             handover: tuple[float, np.ndarray] | None = None, scatter: np.ndarray | None = None,
             read: np.ndarray | None = None, ordinates: int = 6, source=None, tail: tuple[float, int] = (0.0, 0)
             ) -> WalkResult:
    """Walk light injected into slice k = 0 of a rectilinear domain until (almost) all of it
    has left.

    Args:
        Th, Dh: float32 (n_d, n_u, n_v) half-step factors from :func:`medium_factors`.
        injection: (n_u, n_v) power [W] entering each cell of slice 0 (E h^2 for a sun).
            The light travels half a cell to the first centre, so it is attenuated by Th[0].
        a0: anisotropy of the injected lobe (1 = collimated). With the sweep solver, a packet
            at least this anisotropic crosses empty cells unsplit (docs/METHOD.md, "Streaming
            through empty cells").
        h: cell size; fluence accumulates W / h^2 per visit.
        rule: "moment" or "paper"; solver: "sweep", "jacobi", "binned" (the Jacobi wavefront
            with each cell's light in fixed anisotropy bins, linear in the light:
            :func:`walk_binned`) or "ordinates" (sweeps with one lobe per lattice direction:
            :func:`walk_ordinates`; rule "moment" only, no hand-over; the result's ``flux``
            holds the fluence's first moment vector).
        tolerance: stop when in-flight energy < tolerance * injected; max_iterations: cap
            (0 = automatic). With ``handover`` and the sweep or binned solver, what is then
            still pending in the diffusion region is handed over (:func:`hand_over_pending`).
        periodic: wrap the lateral faces (an infinite slab; used by the slab tests).
        progress: optional callable(iteration, residual).
        handover: (method.handover_scale, float32 (n_d, n_u, n_v) :func:`handover_factor`): a
            packet whose |a| is below their product leaves the walk; its power and moment are
            returned in ``handed``. None: light walks until it leaves (the six-ordinate walk
            takes no hand-over).
        scatter: float32 (n_d, n_u, n_v) :func:`scatter_factor`, which the six-ordinate walk
            needs (the share of a packet that crosses a transfer unscattered); the other
            solvers ignore it.
        read: bool (n_d, n_u, n_v): the cells whose fields are read. The six-ordinate walk
            crosses the empty cells outside it without visiting them (:func:`skipped_cells`),
            so their phi and flux stay 0; None: every cell is visited. The other solvers
            ignore it.
        ordinates: 6 or 18, the directions of the "ordinates" solver: the six faces of the
            lattice (:func:`walk_ordinates`) or its faces and edges (:func:`walk_ordinates18`).
        source: the "ordinates" solver only: packets pending at cell centres at the start
            (:func:`place`; a point light's first scattering), in place of the injected light;
            ``injection`` is then ignored and may be None, and ``injected`` is their power.
        tail: (share, factor), the eighteen-ordinate walk only: with share > 0 it stops once
            at most that share of the injected light is in flight after two sweeps or more,
            and what it then holds is returned in the result's ``pending`` on blocks of
            factor^3 cells, for :func:`walk_the_tail` (None if at most ``tolerance`` was left).
    """
    Th = np.ascontiguousarray(Th, np.float32)
    Dh = np.ascontiguousarray(Dh, np.float32)
    shape = Th.shape
    moment = rule == "moment"
    table = split_table32()
    inv_area = np.float32(1.0 / (h * h))
    cap = max_iterations or default_max_iterations(shape, solver)
    if handover is not None and periodic:
        raise ValueError("the hand-over has no periodic diffusion stage")
    eps, diffusive, Q = handover_arrays(handover, shape)

    W = np.zeros(shape, np.float32)
    phi = np.zeros(shape, np.float32)
    phia = np.zeros(shape, np.float32)
    if source is not None and solver != "ordinates":
        raise ValueError("only the ordinates' walks start from a source of packets")
    budget = Budget(injected=float(np.sum(injection if source is None else source[1], dtype=np.float64)))
    tally = np.zeros(4)
    target = tolerance * budget.injected
    t0 = time.perf_counter()
    it = 0
    sent = 0                            # cells that sent, over the sweeps (the sweep solver's)
    if solver == "jacobi":
        # the wave holds packets at cell centres: the injected light has crossed half a cell
        W[0] = injection * Th[0]
        Wa = W * np.float32(a0)
        Wa[0] *= Dh[0]
        budget.absorbed = float(np.sum(injection * (1.0 - Th[0]), dtype=np.float64))
        in_flight = float(np.sum(W, dtype=np.float64))
        parts = np.empty((6,) + shape, np.float32)
        while in_flight > target and it < cap:
            K.jacobi_send(W, Wa, Th, Dh, table, moment, periodic, inv_area, phi, phia, parts, tally,
                          eps, diffusive, Q)
            in_flight = K.jacobi_gather(parts, Th, Dh, periodic, W, Wa, tally)
            it += 1
            if progress is not None and it % 16 == 0:
                progress(it, in_flight / budget.injected)
    elif solver == "ordinates":
        if handover is not None or periodic or not moment:
            raise ValueError("the six-ordinate walk has no hand-over, periodic faces or 'paper' rule")
        if scatter is None:
            raise ValueError("the six-ordinate walk needs scatter (walk.scatter_factor)")
        flux = np.zeros((3,) + shape, np.float32)
        Sh = np.ascontiguousarray(scatter, np.float32)
        skip = skipped_cells(Th, Dh, Sh, read) if read is not None else None
        if ordinates == 18:
            at, factor = tail if tail[0] > 0.0 else (0.0, 0)
            it, in_flight, budget.absorbed, sent, pending = walk_ordinates18(
                Th, Dh, Sh, injection, a0, inv_area, phi, flux, tally, target, cap, progress, skip, source, at,
                factor)
        else:
            it, in_flight, budget.absorbed, sent = walk_ordinates(Th, Dh, Sh, injection, a0, inv_area, phi, flux,
                                                                  tally, target, cap, progress, skip, source)
        phia = flux[0]
    elif solver == "binned":
        it, in_flight, budget.absorbed = walk_binned(Th, Dh, injection, a0, rule, periodic, inv_area, phi, phia,
                                                     tally, eps, diffusive, Q, target, cap, progress)
    else:
        # pending packets have arrived at the face of their cell; the cell applies its half step
        W[0] = injection
        Wa = W * np.float32(a0)
        in_flight = budget.injected
        bands = K.band_edges(shape[1])
        # the injected light's lobe streams through empty cells unsplit (docs/METHOD.md,
        # "Streaming through empty cells")
        a_stream = np.float32(min(a0, 1.0))
        halo = np.zeros((len(bands) - 1, 2, 2, shape[0], shape[2]), np.float32)
        tally_b = np.zeros((len(bands) - 1, 5))
        visited = np.diff(bands) * shape[0] * shape[2]

        def one_sweep(it, w_min):
            # alternate +d / -d every sweep and the lateral order every second sweep; the bands
            # dealt to the threads by the work each did in the sweep before
            band_lane = K.band_lanes(tally_b[:, 4], visited, numba.get_num_threads())
            left = K.sweep(W, Wa, Th, Dh, table, moment, periodic, it % 2 == 0, it % 4 >= 2, w_min,
                           inv_area, phi, phia, bands, band_lane, halo, tally_b, tally, eps, diffusive, Q,
                           a_stream)
            return left, tally_b[:, 4].sum()
        in_flight, it, sent = sweep_until_converged(one_sweep, in_flight, target, cap, Th.size,
                                                    budget.injected, progress)
        if handover is not None:
            tally[K.ABSORBED] += hand_over_pending(W, Wa, Th, Dh, diffusive, Q)
            in_flight = K.total_energy(W)
    seconds = time.perf_counter() - t0
    budget.reflected, budget.transmitted, budget.side = (float(x) for x in tally[:3])
    budget.absorbed += float(tally[K.ABSORBED])
    budget.in_flight = in_flight
    residual = in_flight / max(budget.injected, 1e-300)
    result = WalkResult(phi, phia, budget, it, it * int(np.prod(shape)), residual, in_flight <= target,
                        seconds, solver, handed=Q if handover is not None else None,
                        flux=flux if solver == "ordinates" else None, cells_sent=sent)
    if solver == "ordinates" and ordinates == 18:
        result.pending = pending
    return result
