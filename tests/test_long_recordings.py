"""Long recordings (flatness and report of 10^4-10^5 rows): the hyper-parameter evidence, the
batch posterior and the self-checks switch to the coefficients' dimension K (Woodbury) above
COEFFICIENT_FORM_ROWS readings, where the n x n forms asked for tens of GB. Oracle: the n x n
forms themselves, on the same data (the switch lowered so both run at a small n)."""
import jax.numpy as jnp
import numpy as np

import adaptive_cal
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian import checks, prior


def _data(n=600, k=30, seed=4):
    rng = np.random.default_rng(seed)
    b = rng.standard_normal((k, k))
    cov = 1e-2 * b @ b.T
    cov[:, 0] *= 10.0  # scaled unlike the rest, as tilt against form is
    cov[0, :] *= 10.0
    cov += 1e-10 * np.eye(k)
    rows = rng.standard_normal((n, k))
    truth = np.linalg.cholesky(cov) @ rng.standard_normal(k)
    y = rows @ truth + 0.01 * rng.standard_normal(n)
    return rows, y, cov, 1e-4 * np.linspace(0.5, 2.0, n)


def test_evidence_in_the_coefficients_form_equals_the_readings_form():
    rows, y, cov, r = _data()
    mask = np.ones(len(y))
    mask[500:] = 0.0  # padded rows, as under jit
    y, rows = y * mask, rows * mask[:, None]
    a = prior.log_evidence(rows, y, cov, r, mask)
    b = prior.log_evidence_coefficients(rows, y, cov, r, mask)
    assert abs(a - b) < 1e-8 * abs(a)
    adaptive_cal.use_float64()
    c = float(prior.log_evidence_coefficients(jnp.asarray(rows), jnp.asarray(y), jnp.asarray(cov),
                                              jnp.asarray(r), jnp.asarray(mask), jnp))
    assert abs(a - c) < 1e-8 * abs(a)


def test_batch_posterior_in_the_coefficients_form(monkeypatch):
    rows, y, cov, r = _data()
    start = bl.Belief(np.zeros(cov.shape[0]), cov)
    dense = bl.condition(start, rows, y, r)
    monkeypatch.setattr(bl, "COEFFICIENT_FORM_ROWS", 100)
    wide = bl.condition(start, rows, y, r)
    assert np.abs(wide.mean - dense.mean).max() < 1e-7 * np.abs(dense.mean).max()
    assert np.abs(wide.cov - dense.cov).max() < 1e-7 * np.abs(dense.cov).max()


def test_checks_in_the_coefficients_form(monkeypatch):
    rows, y, cov, r = _data()
    m0 = np.zeros(cov.shape[0])
    loo, ms = checks.leave_one_out(rows, y, m0, cov, r), checks.innovations_mean_square(
        rows, y, m0, cov, r)
    z = checks.standardized_innovations(rows, y, m0, cov, r)
    assert abs(ms - np.mean(z**2)) < 1e-12 * ms  # below the switch: the innovations themselves
    monkeypatch.setattr(bl, "COEFFICIENT_FORM_ROWS", 100)  # the one switch (belief.coefficient_form)
    wide, ms_w = checks.leave_one_out(rows, y, m0, cov, r), checks.innovations_mean_square(
        rows, y, m0, cov, r)
    assert np.abs(wide.residual_mm - loo.residual_mm).max() < 1e-6 * np.abs(loo.residual_mm).max()
    assert np.abs(wide.variance_mm2 / loo.variance_mm2 - 1).max() < 1e-6
    assert abs(ms_w / ms - 1) < 1e-8


def test_flatness_of_twenty_thousand_rows_runs(tmp_path):
    # the n x n hyper-parameter evidence asked for 34 GB here (a JAX out-of-memory error)
    from adaptive_cal.analysis.flatness_intervals import recording_flatness

    rng = np.random.default_rng(0)
    n = 20000
    x, y = rng.uniform(-200, 200, n), rng.uniform(-150, 150, n)
    z = 0.012 * x + 0.002 * y + 5.1 + 1e-7 * x * x + 0.002 * rng.standard_normal(n)
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    lines += [f"{i},{3 * i},{x[i]:.3f},{y[i]:.3f},0,{z[i]:.6f}" for i in range(n)]
    path = tmp_path / "long.csv"
    path.write_text("\n".join(lines) + "\n")
    adaptive_cal.use_float64()
    out, _, _ = recording_flatness(path, np.random.default_rng(0), 40)
    assert abs(out["noise_std_mm"] - 0.002) < 2e-4
    lo, hi = out["flatness_mm"]["least_squares"]["ci95"]
    assert lo < hi
