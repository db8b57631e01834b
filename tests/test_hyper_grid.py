"""The hyper-parameter posterior on a grid (planning.hyper_grid): weights are the exact
posterior density (oracle: prior.log_marginal, the evidence computed on its own, plus the
log-normal hyper-prior), the MAP comes first, and with many readings the grid gives way to the
Laplace points."""
import numpy as np

import adaptive_cal
from adaptive_cal.gaussian import belief as bl

adaptive_cal.use_float64()


def _plan():
    from adaptive_cal.cell.build import survey_plan
    from helpers import sim_cell

    return survey_plan(sim_cell(probe={"noise_range_mm": [0.003, 0.008]}), grow=False)


def _readings(plan, n, seed):
    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1) = plan.bounds_mm
    xy = np.stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)], 1)
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    a = bl.sample(plan.model.belief(plan.model.hyper0._replace(form_std_mm=0.02)), rng, 1)[0]
    return rows, rows @ a + 0.005 * rng.standard_normal(n)


def _log_post(model, h, rows, y):
    from adaptive_cal.gaussian.prior import log_marginal

    x = np.log(np.asarray(h, float))
    mu, sd = np.log(np.asarray(model.hyper0, float)), np.asarray(model.hyper_log_std, float)
    return log_marginal(model, h, rows, y) - 0.5 * np.sum(((x - mu) / sd) ** 2)


def test_grid_weights_are_the_exact_posterior_and_the_map_comes_first():
    from adaptive_cal.gaussian.prior import fit_hyper
    from adaptive_cal.planning.hyper_grid import grid_points

    plan = _plan()
    rows, y = _readings(plan, 14, 1)
    best = fit_hyper(plan.model, rows, y)
    pts = grid_points(plan.model, rows, y, None, None, best)
    assert pts is not None and len(pts) > 7  # broad at 14 readings: more than the 7 points
    assert np.allclose(pts[0][0], best)
    assert abs(sum(w for _, w in pts) - 1) < 1e-12
    ref = [_log_post(plan.model, h, rows, y) for h, _ in pts]
    for (h, w), lp in zip(pts[1:], ref[1:]):
        assert np.log(w / pts[0][1]) == __import__("pytest").approx(lp - ref[0], abs=1e-6)


def test_many_readings_keep_the_laplace_points():
    from adaptive_cal.gaussian.prior import fit_hyper
    from adaptive_cal.planning.hyper_grid import grid_points

    plan = _plan()
    rows, y = _readings(plan, 300, 2)
    assert grid_points(plan.model, rows, y, None, None, fit_hyper(plan.model, rows, y)) is None


def test_refit_mixes_the_grid_at_few_readings():
    """The survey's belief is the grid mixture (moment-matched, its mean the weighted mean of the
    nodes' posteriors) and its hyper is still the MAP."""
    from dataclasses import replace

    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.hyper_grid import grid_points

    plan = _plan()
    rows, y = _readings(plan, 14, 1)
    state = sv.refit(plan, replace(sv.start(plan), rows=rows, heights_mm=y))
    pts = grid_points(plan.model, rows, y, None, None, state.hyper)
    assert len(state.hyper_points) == len(pts) and np.allclose(state.hyper_points[0][0],
                                                               state.hyper)
    mean = sum(w * bl.condition(plan.model.belief(h), rows, y, h.noise_std_mm**2).mean
               for h, w in pts)
    assert np.allclose(state.belief.mean, mean, atol=1e-9)
