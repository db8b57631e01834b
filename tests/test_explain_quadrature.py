"""explain's evidence integrates the noise variance out with a fixed rule about the mode
(``evidence.quadrature``): checked against scipy's adaptive quadrature of the same integrand,
for one-column and several-column models, from 2 rows to 100,000 (the oracle; the rule's
speed: benchmarks/bench_explain_speed.py)."""
import numpy as np
import pytest
from scipy import integrate

from adaptive_cal.analysis.explain import evidence as E
from adaptive_cal.analysis.explain import quadrature as quadrature_rules


def _reference(lam, c2, yy, m):
    """log of integral p(z | v) dsigma / sigma = 1/2 integral p(z | e^w) dw by QUADPACK, about
    the rule's own mode and sd (the integrand is evaluated by the module's ``_spectral``)."""
    lz, w = E.log_evidence_spectral(lam, c2, yy, m)
    _, d2 = E._derivs(lam, c2, yy, m, np.asarray(w))
    sd = 1.0 / np.sqrt(max(-float(d2), 1e-2))
    f = lambda u: float(E._spectral(lam, c2, yy, m, np.array([u]))[0])
    peak = f(float(w))
    val, _ = integrate.quad(lambda u: np.exp(f(u) - peak), float(w) - 80 * sd, float(w) + 80 * sd,
                            points=[float(w)], limit=1000, epsabs=0.0, epsrel=1e-12)
    return float(lz), peak + np.log(val) + np.log(0.5)


# the largest error measured over random models, with about 10 x margin; at a handful of
# residual degrees of freedom the rule's cut at +-9 posterior sds dominates (the right tail of
# v's posterior is heavy there): 6e-4 nats at m = 2, as with every rule tried. At 100 one
# model has a second, lower mode of v (e^-9 of the peak, 3 sds below it: its large prior
# spectrum takes the data's share at a smaller noise), outside every rule's window: 1.1e-6
# nats with 25 points, 1.6e-6 with 73
SIZES = [(2, 5e-3), (5, 5e-5), (10, 5e-4), (20, 5e-8), (40, 5e-8), (60, 5e-8), (99, 5e-8),
         (100, 1e-5), (400, 1e-9), (1500, 1e-9), (4000, 1e-9), (100_000, 1e-8)]


@pytest.mark.parametrize("dof,tol", SIZES)
def test_rule_is_the_adaptive_integral(dof, tol):
    """Random spectra of k = 1-8 columns at m - k = ``dof``: prior spectra from nothing (a
    column the projection removed) to 1e4 x the noise, the data's share explained from 0 to
    99.9 % (a lopsided integrand where the effect holds nearly all of it)."""
    rng = np.random.default_rng(dof)
    worst = 0.0
    for _ in range(16):
        k = int(rng.integers(1, 9))
        m, yy = dof + k, float(rng.uniform(1.0, 100.0))
        rest = 10 ** rng.uniform(-3.0, 0.0)
        c2 = rng.dirichlet(np.ones(k)) * (1.0 - rest) * yy
        lam = rng.choice([0.0, 1e-2, 1.0, 100.0, 1e4], k) * rest * yy / m * rng.uniform(0.1, 10, k)
        got, want = _reference(lam, c2, yy, m)
        worst = max(worst, abs(got - want))
    assert worst < tol


@pytest.mark.parametrize("lam,c2,m,tol", [
    # lopsided: few residual degrees of freedom, or an effect holding 96 % of the data with a
    # prior spectrum near the noise (an outside audit of the 25- and 9-point rules, 2026-11-30)
    ([0.103534, 43.035101, 76.162212, 2069.791322, 272.204019],
     [0.467068, 0.208684, 0.036421, 0.226707, 0.047009], 6, 1e-4),
    ([541.196287, 0.062716, 0.033178, 0.036257], [0.09866, 0.020987, 0.472391, 0.388016], 10, 1e-8),
    ([1.8789219541763023e-4], [0.9645186610766425], 1500, 1e-7),
    ([7.046e-5], [0.9645186610766425], 4000, 1e-7),
    # a near-perfect fit: the mode of log v lies 23 below log(|y|^2 / m), beyond the coarse
    # grid of old and its 12 Newton steps (it was 735 nats off with 25 points, 0.16 with 73)
    ([1e-3], [1.0 - 1e-10], 1000, 1e-6),
    ([1e-3], [1.0 - 1e-9], 4000, 1e-6),
])
def test_rule_on_hard_integrands(lam, c2, m, tol):
    got, want = _reference(np.array(lam), np.array(c2), 1.0, m)
    assert abs(got - want) < tol


@pytest.mark.parametrize("dof", [1000, 1500, 4000, 20_000, 100_000])
def test_gauss_hermite_where_the_effect_explains_little(dof):
    """From 1,000 residual degrees of freedom, models whose effect explains under a tenth of
    the rest are integrated with Gauss-Hermite's 9 points: as exact as the trapezoid there."""
    rng = np.random.default_rng(dof)
    worst, used = 0.0, 0
    for _ in range(24):
        k = int(rng.integers(1, 4))
        m, yy = dof + k, float(rng.uniform(1.0, 100.0))
        share = 10 ** rng.uniform(-6.0, np.log10(0.095))
        rest = yy / (1.0 + share)
        c2 = rng.dirichlet(np.ones(k)) * share * rest
        lam = 10 ** rng.uniform(-4.0, 6.0, k) * rest / m * rng.choice([0.0, 1.0], k, p=[0.1, 0.9])
        used += int(E.near_gaussian(m - k, np.array(rest), np.array(c2.sum())))
        got, want = _reference(lam, c2, yy, m)
        worst = max(worst, abs(got - want))
    assert used == 24 and worst < 1e-9
    assert not E.near_gaussian(dof - 1, np.array(1.0), np.array(0.0)) or dof - 1 >= 1000
    assert not E.near_gaussian(dof, np.array(1.0), np.array(0.2))  # lopsided: the trapezoid


def test_rule_by_residual_degrees_of_freedom():
    assert E.quadrature(19)[0].size == 73 and E.quadrature(20)[0].size == 49
    assert E.quadrature(99)[0].size == 49 and E.quadrature(100)[0].size == 25
    for n in (25, 49, 73):  # the trapezoid over +-9 sds: the weights sum to its width
        t, lw = quadrature_rules._RULES[n]
        assert t[0] == -9.0 and t[-1] == 9.0 and np.exp(lw).sum() * (n - 1) / n == pytest.approx(18.0)


def test_coarse_grid_reaches_a_near_perfect_fits_mode():
    g = E.coarse_grid(1.0, 1000, 0.5)
    np.testing.assert_array_equal(g, np.log(1.0 / 1000) + np.linspace(-14.0, 4.0, 61))
    g = E.coarse_grid(1.0, 1000, 1e-10)  # mode near log(1e-10 / 1000)
    assert g[0] < np.log(1e-10 / 1000) < g[-1] and np.allclose(np.diff(g), 0.3)
    lz, w = E.log_evidence_spectral(np.array([1e-3]), np.array([1.0 - 1e-10]), 1.0, 1000)
    d1, _ = E._derivs(np.array([1e-3]), np.array([1.0 - 1e-10]), 1.0, 1000, np.asarray(w))
    assert abs(float(d1)) < 1e-6  # Newton reached the mode


def test_log_integral_is_logsumexp_and_keeps_minus_infinity():
    from scipy.special import logsumexp

    rng = np.random.default_rng(5)
    g = rng.normal(size=(40, 13, 25)) * 50.0
    g[2, 5, 7] = 700.0  # one term dominating by e^700: no overflow
    lw = rng.normal(size=25)
    np.testing.assert_allclose(E._log_integral(g, lw), logsumexp(g + lw, axis=-1), rtol=1e-13)
    assert E._log_integral(np.full((2, 25), -np.inf), lw).tolist() == [-np.inf, -np.inf]
