"""Henyey-Greenstein tools (src/popvol/hg.py) against independent oracles: adaptive quadrature
(scipy.integrate), textbook closed forms written here from scratch, and analytic facts
(normalisation, mean cosine g, Legendre moments g^l, HG_a * HG_g = HG_{ag}, the solid angles of
the six-neighbour cone partition of supplement Eq. 7). No expected value is taken from popvol.
"""
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import eval_legendre

from popvol import hg

C45 = np.cos(np.pi / 4)          # the front/side/back boundaries, theta = pi/4 and 3 pi/4


# -- oracles (written independently of popvol) --------------------------------------------------

def hg_density(mu, g):
    """HG per steradian, (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^1.5), written out here."""
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def hg_cdf_textbook(mu, g):
    """P(cos theta <= mu) for HG: (1 - g^2)/(2 g) (1/sqrt(1 + g^2 - 2 g mu) - 1/(1 + g))."""
    mu = np.asarray(mu, float)
    if g == 0:
        return (1.0 + mu) / 2.0
    return (1.0 - g * g) / (2.0 * g) * (1.0 / np.sqrt(1.0 + g * g - 2.0 * g * mu) - 1.0 / (1.0 + g))


def _breaks(lo, hi, g):
    """Break points that resolve the HG peak at mu = sign(g) (width ~ (1 - |g|)^2)."""
    if abs(g) < 0.3:
        return [lo, hi]
    peak = np.sign(g)
    pts = [peak - np.sign(g) * 10.0 ** -k for k in range(1, 11)]
    return sorted({lo, hi, *[p for p in pts if lo < p < hi]})


def quad_mu(func, lo, hi, g):
    """int_lo^hi func(mu) dmu, piecewise adaptive quadrature with break points at the HG peak."""
    if hi <= lo:
        return 0.0
    b = _breaks(lo, hi, g)
    total = 0.0
    for x0, x1 in zip(b[:-1], b[1:]):
        val, _ = integrate.quad(func, x0, x1, epsabs=1e-15, epsrel=1e-11, limit=200)
        total += val
    return total


def sphere_share(a, theta0, theta1, phi0, phi1):
    """Share of HG_a (axis z) in the spherical patch theta in [theta0, theta1], phi in [phi0, phi1],
    by 2-D quadrature over the sphere (dOmega = sin theta dtheta dphi)."""
    val, _ = integrate.dblquad(lambda th, ph: hg_density(np.cos(th), a) * np.sin(th),
                               phi0, phi1, theta0, theta1, epsabs=1e-13, epsrel=1e-10)
    return val


def sphere_moment(a, theta0, theta1, phi0, phi1):
    val, _ = integrate.dblquad(lambda th, ph: np.cos(th) * hg_density(np.cos(th), a) * np.sin(th),
                               phi0, phi1, theta0, theta1, epsabs=1e-13, epsrel=1e-10)
    return val


G_NORM = (-0.95, -0.5, 0.0, 0.3, 0.877, 0.99)


# -- f_hg -----------------------------------------------------------------------------------------

def test_f_hg_matches_the_formula():
    mu = np.linspace(-1, 1, 41)
    for g in (-0.9, -1e-4, 0.0, 1e-9, 0.5, 0.99):
        # hg.py evaluates 1 + g^2 - 2 g mu in a cancellation-free form: equal to rounding
        np.testing.assert_allclose(hg.f_hg(mu, g), hg_density(mu, g), rtol=1e-10)


@pytest.mark.parametrize("g", G_NORM)
def test_f_hg_unit_integral_over_sphere(g):
    total = 2 * np.pi * quad_mu(lambda m: hg.f_hg(m, g), -1.0, 1.0, g)
    assert total == pytest.approx(1.0, rel=1e-6)


@pytest.mark.parametrize("g", G_NORM)
def test_f_hg_mean_cosine_is_g(g):
    mean = 2 * np.pi * quad_mu(lambda m: m * hg.f_hg(m, g), -1.0, 1.0, g)
    assert mean == pytest.approx(g, abs=1e-8)


@pytest.mark.parametrize("g", (-0.7, 0.2, 0.6, 0.877))
def test_f_hg_legendre_moments_are_powers_of_g(g):
    """HG = sum_l (2l+1) g^l P_l(mu) / 4 pi, so 2 pi int P_l f dmu = g^l."""
    for l in (1, 2, 3, 4):
        m = 2 * np.pi * quad_mu(lambda x: eval_legendre(l, x) * hg.f_hg(x, g), -1.0, 1.0, g)
        assert m == pytest.approx(g**l, abs=1e-9), l


# -- F_hg -----------------------------------------------------------------------------------------

G_CDF = (-0.999, -0.9, -0.3, -1e-4, -1e-9, 0.0, 1e-9, 1e-4, 0.2, 0.877, 0.99, 0.999)
MU_CDF = (-1.0, -0.999, -0.9, -C45, -0.3, 0.0, 0.1, C45, 0.95, 0.999, 0.99999, 1.0)


@pytest.mark.parametrize("g", G_CDF)
def test_F_hg_is_the_integral_of_f_hg(g):
    for mu in MU_CDF:
        expected = quad_mu(lambda m: hg_density(m, g), -1.0, mu, g)
        got = hg.F_hg(mu, g)
        assert got == pytest.approx(expected, rel=1e-7, abs=1e-14), mu


# (the textbook form cancels catastrophically for tiny |g|; those are covered by quadrature)
@pytest.mark.parametrize("g", [g for g in G_CDF if abs(g) > 1e-3])
def test_F_hg_agrees_with_textbook_cdf(g):
    mu = np.linspace(-1, 1, 201)
    np.testing.assert_allclose(2 * np.pi * hg.F_hg(mu, g), hg_cdf_textbook(mu, g), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("g", G_CDF + (-1.0, 1.0))
def test_F_hg_monotone_and_bounded(g):
    mu = np.linspace(-1, 1, 4001)
    F = np.asarray(hg.F_hg(mu, g))
    assert np.all(np.isfinite(F))
    assert np.all(np.diff(F) >= -1e-15)
    tol = 1e-12
    assert F.min() >= 0.0 and F.max() <= 1 / (2 * np.pi) * (1 + tol)
    assert hg.F_hg(-1.0, g) == pytest.approx(0.0, abs=1e-15)
    assert 2 * np.pi * hg.F_hg(1.0, g) == pytest.approx(1.0, rel=tol)


NEAR_ONE = 1 - 1e-7


@pytest.mark.parametrize("g", [NEAR_ONE, -NEAR_ONE])
def test_near_collimated_lobes_keep_normalisation_and_peak(g):
    peak = np.sign(g)
    exact_peak = (1 + abs(g)) / (4 * np.pi * (1 - abs(g)) ** 2)     # f_hg at mu = sign(g)
    assert hg.f_hg(peak, g) == pytest.approx(exact_peak, rel=1e-8)
    assert 2 * np.pi * hg.F_hg(1.0, g) == pytest.approx(1.0, abs=1e-9)
    assert hg.F_hg(-1.0, g) == pytest.approx(0.0, abs=1e-9)
    assert hg.first_moment(1.0, g) == pytest.approx(g, abs=1e-9)
    assert hg.first_moment(-1.0, g) == pytest.approx(0.0, abs=1e-9)


def test_F_hg_isotropic_and_delta_limits():
    mu = np.linspace(-1, 1, 11)
    np.testing.assert_allclose(hg.F_hg(mu, 0.0), (1 + mu) / (4 * np.pi), rtol=1e-14, atol=1e-16)
    # g = 1: all mass at mu = 1
    np.testing.assert_array_equal(hg.F_hg(mu[:-1], 1.0), 0.0)
    assert 2 * np.pi * hg.F_hg(1.0, 1.0) == pytest.approx(1.0)
    # g = -1: all mass at mu = -1, so the CDF is 1 everywhere above -1
    np.testing.assert_allclose(2 * np.pi * hg.F_hg(mu[1:], -1.0), 1.0, rtol=1e-14)


# -- first_moment -------------------------------------------------------------------------------

G_MOM = (-0.99, -0.5, -0.0101, -0.0099, -1e-4, 0.0, 1e-7, 0.005, 0.0099, 0.0101, 0.3, 0.877, 0.999)
MU_MOM = (-1.0, -0.95, -C45, -0.2, 0.0, 0.4, C45, 0.9, 0.999, 1.0)


@pytest.mark.parametrize("g", G_MOM)
def test_first_moment_is_the_integral_of_mu_f(g):
    for mu in MU_MOM:
        expected = 2 * np.pi * quad_mu(lambda m: m * hg_density(m, g), -1.0, mu, g)
        got = hg.first_moment(mu, g)
        assert got == pytest.approx(expected, rel=1e-7, abs=1e-11), mu


@pytest.mark.parametrize("g", G_MOM)
def test_first_moment_full_range_is_g(g):
    tol = 1e-11
    assert hg.first_moment(1.0, g) == pytest.approx(g, abs=tol)
    assert hg.first_moment(-1.0, g) == pytest.approx(0.0, abs=tol)


def test_first_moment_is_continuous_across_the_series_switch():
    """|g| = 0.01 switches from the Legendre series to the closed form: no visible jump."""
    mu = np.linspace(-1, 1, 9)
    for g0 in (0.01, -0.01):
        lo = hg.first_moment(mu, g0 * (1 - 1e-9))
        hi = hg.first_moment(mu, g0 * (1 + 1e-9))
        np.testing.assert_allclose(lo, hi, atol=1e-10)


# -- split fractions (cone partition of supplement Eq. 7) ----------------------------------------
# front: theta in [0, pi/4] (all azimuths); each of the 4 side neighbours: theta in
# [pi/4, 3 pi/4] and one azimuth quarter; back: theta in [3 pi/4, pi].

@pytest.mark.parametrize("a", (-0.9, -0.3, 0.0, 0.5, 0.9))
def test_split_fractions_by_quadrature_over_the_sphere(a):
    q = np.pi / 4
    front = sphere_share(a, 0.0, q, 0.0, 2 * np.pi)
    side = sphere_share(a, q, 3 * q, -q, q)              # one azimuth quarter
    side2 = sphere_share(a, q, 3 * q, q, 3 * q)          # the next quarter: the same by symmetry
    back = sphere_share(a, 3 * q, np.pi, 0.0, 2 * np.pi)
    assert side == pytest.approx(side2, rel=1e-9)
    assert front + 4 * side + back == pytest.approx(1.0, rel=1e-8)
    f, s, b = hg.split_fractions(a)
    assert f == pytest.approx(front, rel=1e-8, abs=1e-12)
    assert s == pytest.approx(side, rel=1e-8, abs=1e-12)
    assert b == pytest.approx(back, rel=1e-8, abs=1e-12)


def test_split_fractions_sum_to_one_and_are_shares():
    a = np.linspace(-1, 1, 201)
    f, s, b = (np.asarray(x) for x in hg.split_fractions(a))
    np.testing.assert_allclose(f + 4 * s + b, 1.0, rtol=0, atol=1e-13)
    for x in (f, s, b):
        assert np.all(np.isfinite(x))
        assert np.all(x >= -1e-15) and np.all(x <= 1 + 1e-15)
    # more forward lobe -> more to the front, less to the back
    assert np.all(np.diff(f) >= -1e-15) and np.all(np.diff(b) <= 1e-15)


def test_split_fractions_mirror_symmetry():
    a = np.linspace(-1, 1, 201)
    f, s, b = hg.split_fractions(a)
    fm, sm, bm = hg.split_fractions(-a)
    np.testing.assert_allclose(f, bm, atol=1e-14)
    np.testing.assert_allclose(b, fm, atol=1e-14)
    np.testing.assert_allclose(s, sm, atol=1e-14)


def test_split_fractions_isotropic_are_solid_angle_shares():
    """a = 0: each share is its solid angle / 4 pi. Cones of half-angle pi/4 hold
    2 pi (1 - cos 45) each; the band holds 4 pi cos 45, split into 4 quarters."""
    f, s, b = hg.split_fractions(0.0)
    assert f == pytest.approx((1 - C45) / 2, rel=1e-13)
    assert b == pytest.approx((1 - C45) / 2, rel=1e-13)
    assert s == pytest.approx(C45 / 4, rel=1e-13)


def test_split_fractions_collimated_limits():
    f, s, b = hg.split_fractions(1.0)
    assert (f, s, b) == pytest.approx((1.0, 0.0, 0.0), abs=1e-14)
    f, s, b = hg.split_fractions(-1.0)
    assert (f, s, b) == pytest.approx((0.0, 0.0, 1.0), abs=1e-14)


# -- conditional mean cosines ---------------------------------------------------------------------

@pytest.mark.parametrize("a", (-0.9, -0.3, 0.0, 0.5, 0.9))
def test_conditional_mean_cosines_by_sphere_quadrature(a):
    q = np.pi / 4
    m_front = sphere_moment(a, 0, q, 0, 2 * np.pi) / sphere_share(a, 0, q, 0, 2 * np.pi)
    m_side = sphere_moment(a, q, 3 * q, -q, q) / sphere_share(a, q, 3 * q, -q, q)
    m_back = sphere_moment(a, 3 * q, np.pi, 0, 2 * np.pi) / sphere_share(a, 3 * q, np.pi, 0, 2 * np.pi)
    got = hg.conditional_mean_cosines(a)
    assert got == pytest.approx((m_front, m_side, m_back), rel=1e-7, abs=1e-10)


@pytest.mark.parametrize("a", (-0.999, -0.99, -0.6, -0.05, -0.005, 0.001, 0.2, 0.7, 0.95, 0.99, 0.999))
def test_conditional_mean_cosines_by_1d_quadrature(a):
    def mean(lo, hi):
        num = quad_mu(lambda m: m * hg_density(m, a), lo, hi, a)
        den = quad_mu(lambda m: hg_density(m, a), lo, hi, a)
        return num / den
    expected = (mean(C45, 1.0), mean(-C45, C45), mean(-1.0, -C45))
    got = hg.conditional_mean_cosines(a)
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-9)


def test_conditional_mean_cosines_isotropic_and_bounds():
    mf, ms, mb = hg.conditional_mean_cosines(0.0)
    assert mf == pytest.approx((1 + C45) / 2, rel=1e-12)
    assert ms == pytest.approx(0.0, abs=1e-13)
    assert mb == pytest.approx(-(1 + C45) / 2, rel=1e-12)
    a = np.linspace(-1, 1, 401)
    mf, ms, mb = (np.asarray(x) for x in hg.conditional_mean_cosines(a))
    for x in (mf, ms, mb):
        assert np.all(np.isfinite(x))
    # each mean lies inside its own slice
    assert np.all((mf >= C45 - 1e-9) & (mf <= 1 + 1e-12))
    assert np.all((ms >= -C45 - 1e-9) & (ms <= C45 + 1e-9))
    assert np.all((mb >= -1 - 1e-12) & (mb <= -C45 + 1e-9))
    assert hg.conditional_mean_cosines(1.0)[0] == 1.0
    assert hg.conditional_mean_cosines(-1.0)[2] == -1.0


def test_conditional_mean_cosines_mirror_symmetry():
    """HG_{-a}(mu) = HG_a(-mu): m_front(-a) = -m_back(a), m_side(-a) = -m_side(a)."""
    a = np.linspace(-0.99, 0.99, 199)
    mf, ms, mb = hg.conditional_mean_cosines(a)
    mf2, ms2, mb2 = hg.conditional_mean_cosines(-a)
    np.testing.assert_allclose(mf, -mb2, atol=1e-9)
    np.testing.assert_allclose(ms, -ms2, atol=1e-9)


def test_conditional_mean_cosines_mirror_symmetry_at_collimated_ends():
    mf_minus = hg.conditional_mean_cosines(-1.0)[0]
    mb_plus = hg.conditional_mean_cosines(1.0)[2]
    assert mf_minus == pytest.approx(-mb_plus, abs=1e-6)
    # and both equal the limit computed by quadrature at a = -(1 - 1e-6)
    a = -(1 - 1e-6)
    num = quad_mu(lambda m: m * hg_density(m, a), C45, 1.0, a)
    den = quad_mu(lambda m: hg_density(m, a), C45, 1.0, a)
    assert mf_minus == pytest.approx(num / den, abs=1e-6)


def test_split_conserves_first_moment():
    """front m_front + 4 side m_side + back m_back = a (the `moment` rule's invariant)."""
    a = np.linspace(-0.999, 0.999, 101)
    f, s, b = hg.split_fractions(a)
    mf, ms, mb = hg.conditional_mean_cosines(a)
    np.testing.assert_allclose(f * mf + 4 * s * ms + b * mb, a, atol=1e-10)


# -- HG_a * HG_g = HG_{a g} ----------------------------------------------------------------------

def convolved_density(mu, a, g):
    """Density (per sr) of the direction after a direction drawn from HG_a about z is scattered
    again by HG_g: int f_a(w' . z) f_g(w . w') dw', 2-D quadrature over the intermediate w'."""
    st = np.sqrt(1 - mu * mu)

    def integrand(th, ph):
        cos_ww = mu * np.cos(th) + st * np.sin(th) * np.cos(ph)
        return hg_density(np.cos(th), a) * hg_density(cos_ww, g) * np.sin(th)

    # symmetric in ph -> integrate [0, pi] and double
    val, _ = integrate.dblquad(integrand, 0.0, np.pi, 0.0, np.pi, epsabs=1e-12, epsrel=1e-9)
    return 2 * val


@pytest.mark.parametrize("a,g", [(0.5, 0.6), (-0.4, 0.7), (0.3, -0.5)])
def test_hg_self_convolution_density(a, g):
    for mu in (-1.0 + 1e-9, -0.6, 0.0, 0.5, 0.9, 1.0 - 1e-9):
        assert convolved_density(mu, a, g) == pytest.approx(hg.f_hg(mu, a * g), rel=1e-6), mu


def rotate_about(axis_mu, phi, mu2, phi2):
    """z-component of a direction with polar cosine mu2 (azimuth phi2) about an axis of polar
    cosine axis_mu (azimuth phi) -- i.e. the new direction's cosine to z."""
    s1 = np.sqrt(np.maximum(1 - axis_mu**2, 0))
    s2 = np.sqrt(np.maximum(1 - mu2**2, 0))
    return axis_mu * mu2 - s1 * s2 * np.cos(phi2)


def test_hg_self_convolution_monte_carlo():
    """Sample twice with sample_hg (fresh azimuth each time): the result is HG_{ag} -- its first
    three Legendre moments are (ag)^l (within 5 standard errors) and it passes a KS test."""
    rng = np.random.default_rng(1)
    n, a, g = 200_000, 0.7, 0.8
    mu1 = hg.sample_hg(a, rng.random(n))
    mu2 = hg.sample_hg(g, rng.random(n))
    z = np.clip(rotate_about(mu1, 0.0, mu2, 2 * np.pi * rng.random(n)), -1, 1)
    for l in (1, 2, 3):
        p = eval_legendre(l, z)
        assert abs(p.mean() - (a * g) ** l) < 5 * p.std() / np.sqrt(n), l
    res = stats.kstest(z, lambda x: hg_cdf_textbook(x, a * g))
    assert res.pvalue > 1e-3


# -- sampling -------------------------------------------------------------------------------------

@pytest.mark.parametrize("g", (-0.5, 0.0, 0.877))
def test_sample_hg_distribution(g):
    rng = np.random.default_rng(7)
    n = 200_000
    mu = np.asarray(hg.sample_hg(g, rng.random(n)))
    assert mu.shape == (n,)
    assert np.all((mu >= -1) & (mu <= 1))
    res = stats.kstest(mu, lambda x: hg_cdf_textbook(x, g))
    assert res.pvalue > 1e-3
    # also against popvol's own CDF (checked by quadrature above)
    res2 = stats.kstest(mu, lambda x: 2 * np.pi * np.asarray(hg.F_hg(x, g)))
    assert res2.pvalue > 1e-3
    # mean g, variance from E[mu^2] = (1 + 2 g^2) / 3 (second Legendre moment g^2)
    sigma = np.sqrt((1 + 2 * g * g) / 3 - g * g)
    assert abs(mu.mean() - g) < 5 * sigma / np.sqrt(n)


# sample_hg(0, 0) evaluates the unused g != 0 branch as 0/0 (np.where evaluates both branches)
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_sample_hg_endpoints_and_tiny_g():
    # u = 0 -> mu = -1, u -> 1 -> mu = 1 (inverse CDF), for any g
    for g in (-0.9, -1e-8, 0.0, 1e-8, 0.5, 0.99):
        assert hg.sample_hg(g, 0.0) == pytest.approx(-1.0, abs=1e-9)
        assert hg.sample_hg(g, 1.0 - 1e-15) == pytest.approx(1.0, abs=1e-6)
        # inverse of the CDF: CDF(sample(u)) = u
        u = np.linspace(0.01, 0.99, 25)
        np.testing.assert_allclose(hg_cdf_textbook(hg.sample_hg(g, u), g) if abs(g) > 1e-3
                                   else (1 + np.asarray(hg.sample_hg(g, u))) / 2, u, atol=1e-8)
