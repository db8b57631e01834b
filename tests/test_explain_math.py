"""Oracle tests of the numerical core of explain: evidence, LOO, regressors, aliasing."""
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from adaptive_cal import effects
from adaptive_cal.analysis.explain.evidence import (Projector, _spectral, log_evidence,
                                           log_evidence_columns_mixture, log_evidence_mixture,
                                           log_evidence_spectral, loo_residuals, spectrum)
from adaptive_cal.analysis.explain.identify import canonical_correlations

GEOM = effects.Geometry((-225.0, 225.0), (-185.0, 185.0), (0.0, -650.0))


def _features(rng, n=30):
    x = rng.uniform(-200, 200, n)
    y = rng.uniform(-160, 160, n)
    return effects.Features(x, y, np.arange(n) * 4.0, np.sign(rng.standard_normal(n)),
                            5.0 + rng.uniform(-2, 2, n))


def test_evidence_given_noise_matches_brute_force_integral():
    """Closed form vs 2-D quadrature over (flat offset c, effect theta ~ N(0, tau^2))."""
    rng = np.random.default_rng(0)
    n, v, tau = 12, 0.3 ** 2, 0.8
    x = rng.standard_normal(n)
    y = 1.5 + 0.7 * x + 0.3 * rng.standard_normal(n)
    N = np.ones((n, 1))
    proj = Projector.of(N)
    lam, c2 = spectrum(proj(x[:, None]), proj(y), np.array([tau ** 2]))
    closed = _spectral(lam, c2, float(proj(y) @ proj(y)), n - 1, np.array([np.log(v)]))[0]

    def integrand(theta, c):
        r = y - c - theta * x
        return np.exp(-0.5 * r @ r / v - 0.5 * n * np.log(2 * np.pi * v)
                      + stats.norm.logpdf(theta, 0, tau))

    brute, _ = integrate.dblquad(integrand, -2.0, 5.0, -4.0, 6.0, epsabs=1e-14, epsrel=1e-10)
    # flat prior on c leaves the factor |N^T N|^(-1/2) = n^(-1/2), common to every model
    assert closed - 0.5 * np.log(n) == pytest.approx(np.log(brute), abs=1e-6)


def test_noise_integral_matches_quadrature():
    lam, c2, yy, m = np.array([3.0, 0.5]), np.array([2.0, 0.1]), 5.0, 20
    lz, _ = log_evidence_spectral(lam, c2, yy, m)
    f = lambda w: np.exp(_spectral(lam, c2, yy, m, np.array([w]))[0] - lz)
    val, _ = integrate.quad(f, -15, 10, limit=400, points=[np.log(yy / m)])
    assert 0.5 * val == pytest.approx(1.0, rel=1e-6)  # dsigma / sigma = dw / 2


def test_noise_integral_many_rows():
    """The grid follows the narrow posterior of the noise for 10,000 rows."""
    lam, c2, yy, m = np.array([40.0]), np.array([0.05]), 10000 * 0.004 ** 2, 9997
    lz, w = log_evidence_spectral(lam, c2, yy, m)
    f = lambda w_: np.exp(_spectral(lam, c2, yy, m, np.array([w_]))[0] - lz)
    val, _ = integrate.quad(f, w - 1, w + 1, points=[w], limit=200)
    assert 0.5 * val == pytest.approx(1.0, rel=1e-6)


def test_mixture_is_average_over_prior_scales():
    rng = np.random.default_rng(2)
    X = rng.standard_normal((25, 3))
    y = X @ [0.2, 0.0, -0.1] + 0.05 * rng.standard_normal(25)
    taus = np.geomspace(0.01, 1.0, 5)
    each = [log_evidence(X, y, np.full(3, t ** 2), 25)[0] for t in taus]
    lz, best, _ = log_evidence_mixture(X, y, taus, 25)
    assert lz == pytest.approx(logsumexp(each) - np.log(5), abs=1e-9)
    assert best == int(np.argmax(each))
    cols, _ = log_evidence_columns_mixture(X, y, taus, 25)
    for j in range(3):
        assert cols[j] == pytest.approx(log_evidence_mixture(X[:, [j]], y, taus, 25)[0], abs=1e-9)


def test_loo_shortcut_matches_explicit_refits():
    rng = np.random.default_rng(3)
    n = 20
    D = np.column_stack([np.ones(n), rng.standard_normal((n, 3))])
    y = D @ [1.0, 0.5, -0.3, 0.2] + 0.1 * rng.standard_normal(n)
    pen = np.array([0.0, 0.0, 2.0, 5.0])
    fast = loo_residuals(D, y, pen)
    for i in range(n):
        keep = np.arange(n) != i
        coef = np.linalg.solve(D[keep].T @ D[keep] + np.diag(pen), D[keep].T @ y[keep])
        assert fast[i] == pytest.approx(y[i] - D[i] @ coef, rel=1e-7, abs=1e-12)


@pytest.mark.parametrize("name,params", [
    ("tilt", {"a": 0.01, "b": -0.002, "c": 0.3}),
    ("thermal_drift", {"rate_mm_per_s": 2e-4, "amplitude_mm": 0.0}),
    ("thermal_drift", {"rate_mm_per_s": 2e-4, "amplitude_mm": 0.012, "tau_s": 50.0}),
    ("reversal", {"span_mm": 0.006}),
    ("arm_sag", {"sag_mm_at_1m": 0.05, "p": 2.3}),
    ("probe_gain", {"gain": 0.003}),
    ("local_defect", {"x_mm": 10.0, "y_mm": -20.0, "height_mm": 0.02, "radius_mm": 60.0}),
])
def test_regressor_is_the_forward_model(name, params):
    f = _features(np.random.default_rng(4))
    R = effects.get(name).regressor(f, GEOM, params)
    theta = [params[k] for k in effects.get(name).linear]
    np.testing.assert_allclose(R @ theta, effects.reading_change(name, params, f, GEOM), atol=1e-13)
    J = effects.get(name).jacobian(f, params, GEOM)
    for j, k in enumerate(effects.get(name).param_names):
        if k in effects.get(name).linear:
            np.testing.assert_allclose(J[:, j], R[:, effects.get(name).linear.index(k)],
                                       atol=1e-6)


def test_form_coefficients_round_trip():
    f = _features(np.random.default_rng(5))
    coef = np.array([0.01, 0.3, 0.17, -0.05])
    R = effects.form.regressor(f, GEOM)
    p = effects.form_params(coef, GEOM)
    np.testing.assert_allclose(R @ coef, effects.reading_change("form", p, f, GEOM), atol=1e-12)
    g = effects.form_pv_gradient(coef, GEOM)
    h = 1e-7
    num = (effects.form_params(coef + h * np.eye(4)[1], GEOM)["pv_mm"] - p["pv_mm"]) / h
    assert g[1] == pytest.approx(num, rel=1e-4)


def test_defect_grid_regressor_matches_single():
    f = _features(np.random.default_rng(6))
    G = effects.defect_regressor_grid(f, [0.0, 50.0], [10.0, -30.0], 40.0)
    for j, (cx, cy) in enumerate([(0.0, 10.0), (50.0, -30.0)]):
        one = effects.reading_change("local_defect", {"x_mm": cx, "y_mm": cy, "height_mm": 1.0,
                                                      "radius_mm": 40.0}, f, GEOM)
        np.testing.assert_allclose(G[:, j], one, atol=1e-14)


def test_canonical_correlations():
    rng = np.random.default_rng(7)
    F = rng.standard_normal((30, 3))
    inside = F @ [1.0, -2.0, 0.5]
    assert canonical_correlations(inside[:, None], F)[0] == pytest.approx(1.0)
    e = rng.standard_normal(30)
    e -= F @ np.linalg.lstsq(F, e, rcond=None)[0]
    assert canonical_correlations(e[:, None], F)[0] == pytest.approx(0.0, abs=1e-10)
    mix = inside / np.linalg.norm(inside) + e / np.linalg.norm(e)
    assert canonical_correlations(mix[:, None], F)[0] == pytest.approx(np.sqrt(0.5))


def test_full_covariance_prior_matches_dense_gaussian_and_sigma_integral():
    """Matrix prior (the design-scaled shape): closed form vs the dense marginal density
    N(z; 0, v I + Z S Z^T) integrated over sigma with p(sigma) = 1/sigma by quadrature."""
    from adaptive_cal.analysis.explain.candidates import prior_shape
    rng = np.random.default_rng(7)
    n = 14
    N = np.column_stack([np.ones(n), rng.standard_normal(n)])
    proj = Projector.of(N)
    Q = np.linalg.svd(np.eye(n) - proj.basis @ proj.basis.T)[0][:, :n - proj.rank]
    X = rng.standard_normal((n, 3)) @ np.diag([1.0, 0.2, 3.0])
    y = N @ [1.0, 0.3] + X @ [0.2, -0.5, 0.05] + 0.3 * rng.standard_normal(n)
    S = 0.4 ** 2 * prior_shape(proj(X))
    m = n - proj.rank
    lz, _ = log_evidence(proj(X), proj(y), S, m)
    z, Z = Q.T @ y, Q.T @ X

    def dens(w):
        C = np.exp(w) * np.eye(m) + Z @ S @ Z.T
        return np.exp(stats.multivariate_normal.logpdf(z, np.zeros(m), C) - lz)

    val, _ = integrate.quad(dens, -12, 6, limit=400)
    assert 0.5 * val == pytest.approx(1.0, rel=1e-6)
    # the design-scaled shape spreads the i.i.d. prior's signal energy evenly over directions
    S0 = prior_shape(proj(X), ridge=0.0)
    G = proj(X).T @ proj(X)
    assert np.trace(G @ S0) == pytest.approx(np.trace(G), rel=1e-9)
    assert np.allclose(np.linalg.eigvalsh(G @ S0), np.trace(G) / 3, rtol=1e-8)
