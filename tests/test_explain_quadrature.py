"""explain's evidence integrates the noise variance out with a fixed rule about the mode
(``evidence.quadrature``): checked against scipy's adaptive quadrature of the same integrand,
for one-column and several-column models, from 2 rows to 100,000 (the oracle; the rule's
speed: benchmarks/bench_explain_speed.py)."""
import numpy as np
import pytest
from scipy import integrate

from adaptive_cal.analysis.explain import evidence as E


def _reference(lam, c2, yy, m):
    """log of integral p(z | v) dsigma / sigma = 1/2 integral p(z | e^w) dw by QUADPACK, about
    the rule's own mode and sd (the integrand is evaluated by the module's ``_spectral``)."""
    lz, w = E.log_evidence_spectral(lam, c2, yy, m)
    _, d2 = E._derivs(lam, c2, yy, m, np.asarray(w))
    sd = 1.0 / np.sqrt(max(-float(d2), 1e-2))
    f = lambda u: float(E._spectral(lam, c2, yy, m, np.array([u]))[0])
    peak = f(float(w))
    val, _ = integrate.quad(lambda u: np.exp(f(u) - peak), float(w) - 60 * sd, float(w) + 60 * sd,
                            points=[float(w)], limit=400, epsabs=0.0, epsrel=1e-12)
    return float(lz), peak + np.log(val) + np.log(0.5)


# the largest error measured over 30 random models per size, with about 10 x margin; at a
# handful of rows the rule's cut at +-9 posterior sds dominates (the right tail of v's
# posterior is heavy there): 6e-4 nats at m = 2, as with the 73-point rule this one replaced
SIZES = [(2, 5e-3), (5, 5e-5), (10, 5e-7), (40, 1e-9), (400, 1e-9), (999, 1e-9), (1000, 1e-9),
         (4000, 1e-9), (100_000, 1e-8)]


@pytest.mark.parametrize("m,tol,k", [(m, tol, k) for k in (1, 3) for m, tol in SIZES if m > k])
def test_rule_is_the_adaptive_integral(m, tol, k):
    rng = np.random.default_rng(m + 7 * k)
    worst = 0.0
    for _ in range(12):
        yy = float(rng.uniform(1.0, 100.0))
        # prior spectra from nothing (a column the projection removed) to 1e4 x the noise
        lam = rng.choice([0.0, 1e-6, 1e-2, 1.0, 100.0, 1e4], k) * yy / m * rng.uniform(0.1, 10, k)
        c2 = np.minimum(rng.uniform(0.0, 1.0, k) ** 3 * yy / k, yy / k)
        got, want = _reference(lam, c2, yy, m)
        worst = max(worst, abs(got - want))
    assert worst < tol


def test_rule_switches_to_gauss_hermite_at_many_rows():
    t, lw = E.quadrature(E.GAUSS_HERMITE_ROWS - 1)
    assert t.size == 25 and np.allclose(np.diff(t), 0.75)
    t, lw = E.quadrature(E.GAUSS_HERMITE_ROWS)
    # 9 nodes, exact for a Gaussian: sum of the weights is sqrt(2 pi) for exp(-t^2 / 2)
    assert t.size == 9
    np.testing.assert_allclose(np.exp(lw - 0.5 * t ** 2).sum(), np.sqrt(2 * np.pi), rtol=1e-14)
    np.testing.assert_allclose(np.exp(lw) @ np.exp(-0.5 * t ** 2), np.sqrt(2 * np.pi), rtol=1e-12)


def test_log_integral_is_logsumexp_and_keeps_minus_infinity():
    from scipy.special import logsumexp

    rng = np.random.default_rng(5)
    g = rng.normal(size=(40, 13, 25)) * 50.0
    g[2, 5, 7] = 700.0  # one term dominating by e^700: no overflow
    lw = rng.normal(size=25)
    np.testing.assert_allclose(E._log_integral(g, lw), logsumexp(g + lw, axis=-1), rtol=1e-13)
    assert E._log_integral(np.full((2, 25), -np.inf), lw).tolist() == [-np.inf, -np.inf]
