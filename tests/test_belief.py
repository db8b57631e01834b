"""Fusion oracles: batch Cholesky posterior, an information-form implementation, Monte Carlo."""
import numpy as np
import pytest
from scipy.linalg import cho_factor, cho_solve

from adaptive_cal.gaussian import belief as bl

RNG = np.random.default_rng(3)
K = 12


def _prior():
    a = RNG.normal(size=(K, K))
    return bl.Belief(RNG.normal(size=K), a @ a.T / K + 0.1 * np.eye(K))


def _information_form(prior, rows, y, r):
    """Independent implementation: C'^-1 = C^-1 + H^T R^-1 H, m' = C' (C^-1 m + H^T R^-1 y)."""
    f = cho_factor(prior.cov)
    info = cho_solve(f, np.eye(K)) + rows.T @ rows / r
    cov = cho_solve(cho_factor(info), np.eye(K))
    return cov @ (cho_solve(f, prior.mean) + rows.T @ y / r), cov


def test_sequential_fusion_equals_batch_and_information_form_in_any_order():
    prior, r = _prior(), 0.05**2
    rows, y = RNG.normal(size=(20, K)), RNG.normal(size=20)
    batch = bl.condition(prior, rows, y, r)
    mean_i, cov_i = _information_form(prior, rows, y, r)
    for order in (np.arange(20), RNG.permutation(20)):
        b = prior
        for i in order:
            b, _ = bl.fuse(b, rows[i], y[i], r)
        np.testing.assert_allclose(b.mean, batch.mean, atol=1e-9)
        np.testing.assert_allclose(b.cov, batch.cov, atol=1e-10)
    np.testing.assert_allclose(batch.mean, mean_i, atol=1e-8)
    np.testing.assert_allclose(batch.cov, cov_i, atol=1e-9)
    assert np.allclose(batch.cov, batch.cov.T)


def test_innovation_matches_filterpy_diagnostics():
    from filterpy.kalman import KalmanFilter

    prior, r = _prior(), 0.01
    h, y = RNG.normal(size=K), 1.7
    inn = bl.innovation(prior, h, y, r)
    kf = KalmanFilter(dim_x=K, dim_z=1)
    kf.x, kf.P = prior.mean.reshape(-1, 1).copy(), prior.cov.copy()
    kf.update(np.array([[y]]), R=np.array([[r]]), H=h.reshape(1, -1))
    assert inn.residual_mm == pytest.approx(float(kf.y[0, 0]))
    assert inn.variance_mm2 == pytest.approx(float(kf.S[0, 0]))
    assert inn.mahalanobis == pytest.approx(float(kf.mahalanobis))
    assert inn.log_likelihood == pytest.approx(float(kf.log_likelihood))


def test_covariance_does_not_depend_on_readings():
    prior, rows = _prior(), RNG.normal(size=(5, K))
    c1 = bl.condition(prior, rows, RNG.normal(size=5), 0.01).cov
    c2 = bl.covariance_after(prior.cov, rows, 0.01)
    np.testing.assert_allclose(c1, c2, atol=1e-12)


def test_sample_moments_monte_carlo():
    """Sample mean within 5 standard errors; sample covariance within 0.1 (n = 40,000)."""
    prior = _prior()
    draws = bl.sample(prior, np.random.default_rng(0), 40000)
    se = np.sqrt(np.diag(prior.cov) / len(draws))
    assert np.all(np.abs(draws.mean(0) - prior.mean) < 5 * se)
    assert np.abs(np.cov(draws.T) - prior.cov).max() < 0.1 * np.abs(prior.cov).max()


def test_mixture_moments_match_monte_carlo():
    b1, b2 = _prior(), _prior()
    mix = bl.mixture([b1, b2], [0.3, 0.7])
    rng = np.random.default_rng(1)
    n = 60000
    pick = rng.random(n) < 0.3
    d = np.where(pick[:, None], bl.sample(b1, rng, n), bl.sample(b2, rng, n))
    assert np.abs(d.mean(0) - mix.mean).max() < 0.05
    assert np.abs(np.cov(d.T) - mix.cov).max() < 0.08 * np.abs(mix.cov).max()


def test_predict_equals_dense_variance():
    prior, rows = _prior(), RNG.normal(size=(7, K))
    mean, var = bl.predict(prior, rows)
    np.testing.assert_allclose(mean, rows @ prior.mean)
    np.testing.assert_allclose(var, np.diag(rows @ prior.cov @ rows.T))


def test_fuse_step_equals_fuse_and_condition_in_numpy_and_under_jit_scan_vmap():
    """The one-reading step (the scan body of studies): numpy, eager JAX, jit(scan) and
    vmap over beliefs all equal filterpy's Joseph update (``fuse``) and the batch posterior."""
    import jax
    import jax.numpy as jnp

    prior, r = _prior(), 0.03**2
    rows, y = RNG.normal(size=(15, K)), RNG.normal(size=15)
    batch = bl.condition(prior, rows, y, r)
    joseph, step = prior, prior
    for i in range(15):
        joseph, _ = bl.fuse(joseph, rows[i], y[i], r)
        step = bl.fuse_step(step, rows[i], y[i], r)
        np.testing.assert_allclose(step.mean, joseph.mean, atol=1e-10)
        np.testing.assert_allclose(step.cov, joseph.cov, atol=1e-11)
    np.testing.assert_allclose(step.mean, batch.mean, atol=1e-9)
    np.testing.assert_allclose(step.cov, batch.cov, atol=1e-10)
    assert np.array_equal(step.cov, step.cov.T)

    def body(belief, inp):
        row, reading, weight = inp
        return bl.fuse_step(belief, row, reading, r, weight), None

    start = bl.Belief(jnp.asarray(prior.mean), jnp.asarray(prior.cov))
    ones = jnp.ones(15)
    eager = start
    for i in range(15):
        eager = bl.fuse_step(eager, jnp.asarray(rows[i]), y[i], r)
    scanned, _ = jax.jit(lambda b, i: jax.lax.scan(body, b, i))(start, (rows, y, ones))
    for got in (eager, scanned):
        np.testing.assert_allclose(np.asarray(got.mean), step.mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(got.cov), step.cov, rtol=1e-12, atol=1e-12)
    # weight 0 skips the reading: masked steps leave the belief as it was
    mask = (jnp.arange(15) < 6).astype(float)
    masked, _ = jax.lax.scan(body, start, (rows, y, mask))
    six = bl.condition(prior, rows[:6], y[:6], r)
    np.testing.assert_allclose(np.asarray(masked.mean), six.mean, atol=1e-9)
    np.testing.assert_allclose(np.asarray(masked.cov), six.cov, atol=1e-10)
    # vmap over plates (readings per plate) equals one plate at a time
    ys = RNG.normal(size=(3, 15))
    many = jax.vmap(lambda yy: jax.lax.scan(body, start, (rows, yy, ones))[0])(jnp.asarray(ys))
    for p in range(3):
        one = bl.condition(prior, rows, ys[p], r)
        np.testing.assert_allclose(np.asarray(many.mean[p]), one.mean, atol=1e-9)
        np.testing.assert_allclose(np.asarray(many.cov[p]), one.cov, atol=1e-10)


def test_predict_in_jax_equals_numpy():
    import jax.numpy as jnp

    prior, rows = _prior(), RNG.normal(size=(7, K))
    mean, var = bl.predict(prior, rows)
    jmean, jvar = bl.predict(bl.Belief(jnp.asarray(prior.mean), jnp.asarray(prior.cov)),
                             jnp.asarray(rows), jnp)
    np.testing.assert_allclose(np.asarray(jmean), mean, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(jvar), var, rtol=1e-12)


def test_information_cov_equals_covariance_after_and_rms_std():
    prior, rows, r = _prior(), RNG.normal(size=(9, K)), 0.02
    cov = bl.information_cov(bl.precision(prior.cov), rows.T @ rows / r)
    np.testing.assert_allclose(cov, bl.covariance_after(prior.cov, rows, r), atol=1e-10)
    np.testing.assert_allclose(bl.precision(prior.cov) @ prior.cov, np.eye(K), atol=1e-9)
    gram = np.diag(np.arange(1.0, K + 1))
    j = float(np.trace(gram @ cov))
    assert bl.integrated_variance(cov, gram) == pytest.approx(j, rel=1e-12)
    assert bl.rms_std(cov, gram, 4.0) == pytest.approx(np.sqrt(j / 4.0), rel=1e-12)
    assert bl.rms_std_from_integrated_variance(-1e-18, 4.0) == 0.0
