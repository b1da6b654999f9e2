"""Henyey-Greenstein phase function tools (supplement Sec. 1.1; docs/METHOD.md,
"Henyey-Greenstein tools").

All functions take scalars or arrays (broadcast) and return float64. mu = cos(theta) is the
cosine from the lobe's axis; g (or a, for a cell's radiance lobe) is the mean cosine.
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre as npleg

from .errors import PopvolError
from .io.files import write_atomically

COS_QUARTER_PI = np.sqrt(0.5)   # the front/side/back boundaries of supplement Eq. 7
_SMALL_G = 0.01                 # below this |g| the first moment uses its Legendre series
_NEAR_ONE = 1e-6                # |a| within this of 1: conditional means take their limit


def _denominator(mu, g):
    """1 + g^2 - 2 g mu without cancellation near mu = sign(g), |g| -> 1:
    (1 - g)^2 + 2 g (1 - mu) for g >= 0, (1 + g)^2 - 2 g (1 + mu) for g < 0 (both >= 0)."""
    return np.where(g >= 0, (1.0 - g) ** 2 + 2.0 * g * (1.0 - mu), (1.0 + g) ** 2 - 2.0 * g * (1.0 + mu))


def f_hg(mu, g):
    """HG phase function per steradian, supplement Eq. 1:
    f = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2)), for |g| < 1."""
    mu, g = np.asarray(mu, np.float64), np.asarray(g, np.float64)
    d = _denominator(mu, g)
    return (1.0 - g * g) / (4.0 * np.pi * d * np.sqrt(d))


def F_hg(mu, g):
    """Per-unit-azimuth CDF int_{-1}^{mu} f_hg dmu', supplement Eq. 2, so 2 pi F_hg(1, g) = 1.

    Eq. 2 has a removable 1/g singularity; with s = sqrt(1 + g^2 - 2 g mu) and
    (1 + g)^2 - s^2 = 2 g (1 + mu) it becomes
        2 pi F = (1 - g) (1 + mu) / (s (1 + g + s)),
    exact, stable at g -> 0 (F -> (1 + mu) / 4 pi), for negative g and at |g| = 1 (delta lobes).
    """
    mu, g = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(g, np.float64))
    s = np.sqrt(np.maximum(_denominator(mu, g), 0.0))
    den = s * (1.0 + g + s)
    with np.errstate(divide="ignore", invalid="ignore"):
        two_pi_F = np.where(den > 0, (1.0 - g) * (1.0 + mu) / np.where(den > 0, den, 1.0), 0.0)
    # the delta lobe g = 1 has all its mass at mu = 1
    two_pi_F = np.where((den == 0) & (mu >= 1.0), 1.0, two_pi_F)
    out = two_pi_F / (2.0 * np.pi)
    return out if out.ndim else float(out)


# Legendre series of the first moment for small |g|: f = sum (2l+1) g^l P_l(mu) / (4 pi), so
# 2 pi int_{-1}^{mu} t f dt = 1/2 sum_l (2l+1) g^l Q_l(mu), Q_l(mu) = int_{-1}^{mu} t P_l(t) dt.
_L_MAX = 10
_Q = [npleg.legint(npleg.legmulx(np.eye(_L_MAX + 1)[l]), lbnd=-1) for l in range(_L_MAX + 1)]


def first_moment(mu, g):
    """2 pi int_{-1}^{mu} mu' f_hg(mu', g) dmu' (so first_moment(1, g) = g).

    Closed form: with s as in :func:`F_hg`, an antiderivative of 2 pi mu f is
    (1 - g^2)(1 + g^2 - g mu) / (2 g^2 s); its 1/g^2 cancels between the bounds, so for
    |g| < 0.01 the Legendre series (to g^10) is used instead.
    """
    mu, g = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(g, np.float64))
    out = np.empty(mu.shape)
    small = np.abs(g) < _SMALL_G
    if small.any():
        m, gg = mu[small], g[small]
        out[small] = 0.5 * sum((2 * l + 1) * gg**l * npleg.legval(m, _Q[l]) for l in range(_L_MAX + 1))
    big = ~small
    if big.any():
        m = mu[big]
        gg = np.clip(g[big], -1 + 1e-12, 1 - 1e-12)
        s = np.sqrt(np.maximum(_denominator(m, gg), 1e-300))
        val = (1 - gg * gg) / (2 * gg * gg) * ((1 + gg * gg - gg * m) / s - (1 + gg + gg * gg) / (1 + gg))
        out[big] = val
    return out if out.ndim else float(out)


def upper_tail(mu, g):
    """2 pi int_mu^1 f_hg dmu' = 1 - 2 pi F_hg(mu, g), without the cancellation of that
    difference when the tail is tiny (g -> -1): with s as in :func:`F_hg`,
    s - (1 - g) = 2 g (1 - mu) / (s + 1 - g) gives (1 + g)(1 - mu) / (s (s + 1 - g))."""
    mu, g = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(g, np.float64))
    s = np.sqrt(np.maximum(_denominator(mu, g), 0.0))
    den = s * (s + 1.0 - g)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, (1.0 + g) * (1.0 - mu) / np.where(den > 0, den, 1.0), 0.0)
    out = np.where((den == 0) & (mu <= -1.0), 1.0, out)     # the delta lobe g = -1
    return out if out.ndim else float(out)


def _upper_first_moment(mu, g):
    """2 pi int_mu^1 mu' f_hg dmu' for |g| >= 0.01 as the difference of the antiderivative of
    :func:`first_moment` between mu and 1: its bracket is O(1), so this stays accurate when the
    tail is tiny (g -> -1), where g - first_moment(mu, g) cancels."""
    s = np.sqrt(np.maximum(_denominator(mu, g), 1e-300))
    return (1 - g * g) / (2 * g * g) * ((1 + g * g - g) / (1 - g) - (1 + g * g - g * mu) / s)


def split_fractions(a):
    """Shares of a cell lobe HG_a sent to its 6 face neighbours (supplement Eq. 4, 7):
    (front, side, back) with front: theta in [0, pi/4]; side: theta in [pi/4, 3 pi/4] over one
    azimuth quarter (the share of EACH of the 4 side neighbours); back: theta in [3 pi/4, pi].
    front + 4 side + back = 1 for every a in [-1, 1] (supplement Eq. 8)."""
    a = np.asarray(a, np.float64)
    c = COS_QUARTER_PI
    front = np.asarray(upper_tail(c, a))
    back = 2 * np.pi * F_hg(-c, a)
    side = (1.0 - front - back) / 4.0
    return front, side, back


def conditional_mean_cosines(a):
    """Mean of mu over each slice of HG_a: (m_front, m_side, m_back), i.e.
    int mu f dmu / int f dmu over mu in [c, 1], [-c, c], [-1, -c], c = cos(pi/4).

    Used by the `moment` rule: each outgoing part carries the mean cosine of its own slice,
    which conserves the lobe's first angular moment (docs/METHOD.md, "Walk"). Where a slice
    holds no energy (|a| -> 1) the limit is returned, so the result is always finite.
    """
    a_in = np.asarray(a, np.float64)
    a = np.clip(a_in, -1 + _NEAR_ONE, 1 - _NEAR_ONE)
    c = COS_QUARTER_PI
    front, side, back = split_fractions(a)
    m_c, m_mc = first_moment(c, a), first_moment(-c, a)
    # first_moment(1, a) = a; for a -> -1 the tail is computed directly (no cancellation)
    m_front = np.where(a < -_SMALL_G, _upper_first_moment(c, np.minimum(a, -_SMALL_G)), a - m_c) / front
    m_side = (m_c - m_mc) / (4 * side)
    m_back = m_mc / back
    # a collimated lobe (a = +-1) keeps exactly +-1: its populated slice is a delta
    m_front = np.where(a_in >= 1.0, 1.0, m_front)
    m_back = np.where(a_in <= -1.0, -1.0, m_back)
    return m_front, m_side, m_back


def side_wedge_mean_cosine(a, nodes: int = 64):
    """Mean cosine of a side slice of HG_a about the slice's OWN axis e_n (the face normal it
    is sent through): int (w . e_n) f dw / int f dw over theta in [pi/4, 3 pi/4] and one
    azimuth quarter |phi| <= pi/4 about e_n, which is sqrt(2) int sqrt(1 - mu^2) f dmu / (pi/2
    int f dmu) over mu in [-c, c] (Gauss-Legendre with ``nodes`` nodes). The six-ordinate
    walk's side parts carry it (docs/METHOD.md, "Six ordinates"). Isotropic: (1 + pi/2) / pi =
    0.8183; at |a| = 1, where the slice is empty, its limit 0.7887 (HG's tail tends to a
    shape proportional to (1 -+ mu)^(-3/2))."""
    a = np.asarray(a, np.float64)
    c = COS_QUARTER_PI
    x, w = np.polynomial.legendre.leggauss(nodes)
    mu, w = c * x, c * w
    inner = np.clip(a, -1 + _NEAR_ONE, 1 - _NEAR_ONE)[..., None]
    f = f_hg(mu, inner)
    energy = (np.pi / 2) * (f * w).sum(-1)
    moment = np.sqrt(2.0) * (f * np.sqrt(1 - mu * mu) * w).sum(-1)
    return moment / energy


def sample_hg(g, u):
    """mu distributed as HG_g for u uniform in [0, 1) (inverse of F_hg)."""
    g, u = np.broadcast_arrays(np.asarray(g, np.float64), np.asarray(u, np.float64))
    small = np.abs(g) < 1e-6
    gs = np.where(small, 0.5, g)       # any |g| > 0 (the small-g branch is discarded)
    t = (1 - gs * gs) / (1 - gs + 2 * gs * u)
    mu = np.where(small, 2 * u - 1, (1 + gs * gs - t * t) / (2 * gs))
    mu = np.clip(mu, -1.0, 1.0)
    return mu if mu.ndim else float(mu)


def plot_supplement_figure(path) -> None:
    """Reproduce the supplement's Fig. 1: f_hg (log scale) and 2 pi F_hg for g = 0, 0.5, 0.9."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise PopvolError("matplotlib is needed for this figure: pip install 'popvol[plots]'") from None
    theta = np.linspace(0, np.pi, 721)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.5), dpi=100)
    for g in (0.0, 0.5, 0.9):
        ax1.semilogy(theta, f_hg(np.cos(theta), g), label=f"g = {g:g}")
        ax2.plot(theta, 2 * np.pi * F_hg(np.cos(theta), g), label=f"g = {g:g}")
    ax1.set(title=r"$f_{hg}(\cos\theta, g)$ (Eq. 1)", xlabel=r"$\theta$", xlim=(0, np.pi))
    ax2.set(title=r"$2\pi\,F_{hg}(\cos\theta, g)$ (Eq. 2)", xlabel=r"$\theta$", xlim=(0, np.pi), ylim=(0, 1.02))
    for ax in (ax1, ax2):
        ax.set_xticks([0, np.pi / 4, np.pi / 2, 3 * np.pi / 4, np.pi], ["0", "π/4", "π/2", "3π/4", "π"])
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    try:
        write_atomically(path, fig.savefig)      # the temporary file keeps the suffix: the format
    finally:
        plt.close(fig)
