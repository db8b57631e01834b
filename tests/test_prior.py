"""Prior and hyper-parameter oracles: dense multivariate normal, finite differences, recovery."""
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from adaptive_cal.gaussian import prior as pr
from adaptive_cal.gaussian.spline import Surface


def _model():
    surf = Surface.create(np.linspace(-200, 200, 6), np.linspace(-150, 150, 5))
    return pr.PriorModel(surf, np.tan(np.radians(1.0)), 0.5, (0.0, 0.0),
                         pr.Hyper(0.05, 150.0, 0.005))


def test_tilt_part_is_a_plane_with_the_stated_variances():
    m = _model()
    c = m.tilt_cov()
    x, y = np.array([150.0]), np.array([-100.0])
    h = m.surface.basis(x, y)[0]
    expected = (150**2 + 100**2) * m.slope_std**2 + m.offset_std_mm**2
    assert h @ c @ h == pytest.approx(expected, rel=1e-10)


def test_log_marginal_equals_dense_mvn_and_jax_objective():
    m = _model()
    rng = np.random.default_rng(0)
    xy = rng.uniform([-190, -140], [190, 140], (23, 2))
    rows = m.surface.basis(xy[:, 0], xy[:, 1])
    y = rng.normal(size=23) * 0.1
    hyp = pr.Hyper(0.08, 120.0, 0.007)
    cov = rows @ m.belief(hyp).cov @ rows.T + hyp.noise_std_mm**2 * np.eye(23)
    dense = multivariate_normal(np.zeros(23), cov).logpdf(y)
    assert pr.log_marginal(m, hyp, rows, y) == pytest.approx(dense, rel=1e-9)
    # the jit objective (padded to 32 rows) = -(log marginal + log hyper-prior)
    args = pr._padded(rows, y) + pr._model_args(m)
    theta = np.log(hyp.theta)
    v, g = pr._value_and_grad("se")(theta, *args)
    logprior = -0.5 * np.sum(((theta - np.log(m.hyper0.theta)) / np.array(m.hyper_log_std)) ** 2)
    assert float(v) == pytest.approx(-(dense + logprior), rel=1e-9)
    # gradient against central differences. The truncation error is ~eps^2 f''' / 6 and the
    # round-off ~ u |f| / eps with u = 2.2e-16 and |f| ~ 1e3 (plus the solver's own round-off,
    # which is larger): eps = 1e-6 leaves ~1e-5 relative error, eps = 1e-4 balances the two
    # near 1e-8.
    eps = 1e-4
    fd = [(float(pr._value_and_grad("se")(theta + eps * e, *args)[0])
           - float(pr._value_and_grad("se")(theta - eps * e, *args)[0])) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-5, atol=1e-6)


def test_log_evidence_is_one_function_for_numpy_jit_and_padded_rows():
    """The log marginal that ``log_marginal`` and the jit objective share: numpy, jax.numpy under
    jit, and with padded rows masked out, all equal scipy's dense normal."""
    import jax
    import jax.numpy as jnp

    m = _model()
    rng = np.random.default_rng(1)
    xy = rng.uniform([-190, -140], [190, 140], (9, 2))
    rows = m.surface.basis(xy[:, 0], xy[:, 1])
    y = rng.normal(size=9) * 0.1
    cov, r = m.belief(m.hyper0).cov, 0.006**2
    dense = multivariate_normal(np.zeros(9), rows @ cov @ rows.T + r * np.eye(9)).logpdf(y)
    assert pr.log_evidence(rows, y, cov, r) == pytest.approx(dense, rel=1e-10)
    padded, py, mask = pr._padded(rows, y)
    jitted = jax.jit(lambda *a: pr.log_evidence(*a, xp=jnp))(padded, py, jnp.asarray(cov), r, mask)
    assert float(jitted) == pytest.approx(dense, rel=1e-10)


def test_fit_recovers_noise_and_amplitude_from_prior_draws():
    """Readings drawn from the prior with known theta: the MAP noise is within 25 % and the form
    amplitude within a factor 2.5 (n = 200 readings)."""
    m = _model()
    truth = pr.Hyper(0.1, 150.0, 0.006)
    rng = np.random.default_rng(5)
    xy = rng.uniform([-200, -150], [200, 150], (200, 2))
    rows = m.surface.basis(xy[:, 0], xy[:, 1])
    coef = rng.multivariate_normal(np.zeros(m.surface.size), m.belief(truth).cov)
    y = rows @ coef + truth.noise_std_mm * rng.standard_normal(200)
    fit = pr.fit_hyper(m, rows, y)
    assert fit.noise_std_mm == pytest.approx(truth.noise_std_mm, rel=0.25)
    assert truth.form_std_mm / 2.5 < fit.form_std_mm < truth.form_std_mm * 2.5
    points = pr.hyper_posterior(m, rows, y)
    assert len(points) == 7
    assert sum(w for _, w in points) == pytest.approx(1.0)
    assert points[0][0] == fit


def test_a_noise_range_keeps_the_learned_noise_from_collapsing_on_few_readings():
    """14 readings of prior draws (noise 8-18 um, 30 coefficients): with the weak default prior
    (first guess 5 um, log-std 1) the MAP noise falls below half the truth in 7 of 40 draws
    (measured); with the datasheet range [5, 20] um (log-normal, 95 % inside) in none. The
    range prior must not bias the noise either: median ratio within 20 % of 1."""
    surf = _model().surface
    weak = _model()
    ranged = pr.PriorModel(surf, weak.slope_std, 0.5, (0.0, 0.0), pr.Hyper(0.05, 150.0, 0.01),
                           (1.0, 0.7, np.log(0.02 / 0.005) / (2 * 1.959964)))
    ratios = {"weak": [], "range": []}
    for s in range(40):
        rng = np.random.default_rng(100 + s)
        truth = pr.Hyper(rng.uniform(0.01, 0.08), 150.0, rng.uniform(0.008, 0.018))
        xy = rng.uniform([-200, -150], [200, 150], (14, 2))
        rows = surf.basis(xy[:, 0], xy[:, 1])
        coef = rng.multivariate_normal(np.zeros(surf.size), weak.belief(truth).cov)
        y = rows @ coef + truth.noise_std_mm * rng.standard_normal(14)
        for key, m in (("weak", weak), ("range", ranged)):
            ratios[key].append(pr.fit_hyper(m, rows, y).noise_std_mm / truth.noise_std_mm)
    weak_r, range_r = np.array(ratios["weak"]), np.array(ratios["range"])
    assert np.sum(weak_r < 0.5) >= 4  # the failure the range prevents is there without it
    assert np.sum(range_r < 0.5) <= 1
    assert 0.8 <= np.median(range_r) <= 1.2


def test_probe_noise_range_sets_the_noise_prior_and_lifts_the_touch_floor():
    from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell
    from adaptive_cal.cell.build import prior_model, stop_rule
    from adaptive_cal.planning.stopping import Status

    from conftest import ROOT

    data = load_yaml(ROOT / "configs" / "sim-cell.yaml")
    weak = parse_cell(data)
    assert prior_model(weak).hyper_log_std[2] == 1.0
    data["probe"] = {k: v for k, v in data["probe"].items() if k != "noise_std_mm"}
    data["probe"]["noise_range_mm"] = [0.005, 0.02]
    cell = parse_cell(data)
    model = prior_model(cell)
    assert model.hyper0.noise_std_mm == pytest.approx(0.01)
    # 95 % of the log-normal inside [5, 20] um
    z = np.log(0.02 / 0.01) / model.hyper_log_std[2]
    assert z == pytest.approx(1.959964)
    k = model.surface.size
    early = Status(touches=5, mean_std_mm=1e-4, max_std_mm=1e-4)
    assert stop_rule(cell, k)(early) == "mean_std_bound"
    assert stop_rule(weak, k)(early) is None  # without the range: the floor of k touches
    fixed = parse_cell({**load_yaml(ROOT / "configs" / "sim-cell.yaml"),
                        "model": {**data["model"], "learn_hyper": False}})
    assert stop_rule(fixed, k)(early) == "mean_std_bound"  # nothing learned: no floor either
    for probe, words in (({"noise_range_mm": [0.0, 0.02]}, "above 0"),
                         ({"noise_range_mm": [0.02, 0.01]}, "low < high"),
                         ({"noise_range_mm": [0.005, 0.01], "noise_std_mm": 0.03}, "outside")):
        bad = {**data, "probe": {**data["probe"], **probe}}
        with pytest.raises(ConfigError, match="noise_range_mm") as err:
            parse_cell(bad)
        assert words in str(err.value)
