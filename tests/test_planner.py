"""Planner oracles: brute-force trace(Q C) drop, numpy vs jit, stroke probability, minimax,
travel order, stopping rules."""
import numpy as np
import pytest
from scipy.stats import norm

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning import route, scoring, stopping
from adaptive_cal.gaussian.spline import Surface

SURF = Surface.create(np.linspace(-200, 200, 6), np.linspace(-150, 150, 5))
RNG = np.random.default_rng(11)


def _cov():
    a = RNG.normal(size=(SURF.size, SURF.size))
    return a @ a.T / SURF.size * 1e-3


def test_closed_form_drop_equals_brute_force_trace_difference():
    cov, gram, r = _cov(), SURF.gram(), 1e-5
    xy = RNG.uniform([-200, -150], [200, 150], (40, 2))
    rows = SURF.basis(xy[:, 0], xy[:, 1])
    drop, var = scoring.variance_drop(rows, cov, gram, r)
    j0 = np.trace(gram @ cov)
    brute = [j0 - np.trace(gram @ bl.covariance_after(cov, rows[i:i + 1], r)) for i in range(40)]
    np.testing.assert_allclose(drop, brute, rtol=1e-8)
    np.testing.assert_allclose(drop, scoring.variance_drop_numpy(rows, cov, gram, r), rtol=1e-10)
    np.testing.assert_allclose(var, np.einsum("nk,kl,nl->n", rows, cov, rows), rtol=1e-10)


def test_stroke_constraint_is_one_in_a_million():
    half = 4.5
    r = 1e-4
    var_edge = (half / scoring.STROKE_Z) ** 2 - r
    assert scoring.stroke_ok(np.array([var_edge * 0.999]), r, (0.5, 9.5))[0]
    assert not scoring.stroke_ok(np.array([var_edge * 1.001]), r, (0.5, 9.5))[0]
    # at the edge the probability of landing outside the usable stroke is 1e-6
    assert 2 * norm.sf(half / np.sqrt(var_edge + r)) == pytest.approx(1e-6, rel=1e-6)


def test_minimax_choice_equals_brute_force_on_a_small_set():
    cov, r = _cov(), 1e-5
    xy = RNG.uniform([-200, -150], [200, 150], (60, 2))
    rows = SURF.basis(xy[:, 0], xy[:, 1])
    ok = np.ones(60, bool)
    i = scoring.minimax_choice(rows, cov, r, ok, top=60, watch=60)
    worst = [np.diag(rows @ bl.covariance_after(cov, rows[j:j + 1], r) @ rows.T).max()
             for j in range(60)]
    assert i == int(np.argmin(worst))


def test_refine_does_not_lower_the_score_and_respects_bounds():
    cov, gram, r = _cov(), SURF.gram(), 1e-5
    start = np.array([10.0, 20.0])
    xy, score = scoring.refine(SURF, start, cov, gram, r, [(-150, 150), (-100, 100)], lambda x, y: True)
    d0 = scoring.variance_drop(SURF.basis(start[:1], start[1:]), cov, gram, r)[0][0]
    assert score >= d0 - 1e-15
    assert -150 <= xy[0] <= 150 and -100 <= xy[1] <= 100
    d1 = scoring.variance_drop(SURF.basis(xy[:1], xy[1:]), cov, gram, r)[0][0]
    assert d1 == pytest.approx(score, rel=1e-9)


def test_candidate_grid_respects_allowed_region():
    keep_out = lambda x, y: not (-50 <= x <= 50 and -50 <= y <= 50)  # noqa: E731
    c = scoring.candidate_grid(SURF, keep_out, (-190, 190), (-140, 140), 2000)
    assert 1500 < len(c.xy_mm) <= 2100
    assert not np.any((np.abs(c.xy_mm[:, 0]) <= 50) & (np.abs(c.xy_mm[:, 1]) <= 50))
    np.testing.assert_allclose(c.rows, SURF.basis(c.xy_mm[:, 0], c.xy_mm[:, 1]))


def test_travel_order_is_a_permutation_no_longer_than_nearest_neighbour_or_given_order():
    pts = RNG.uniform(0, 100, (12, 2))
    order = route.travel_order((0, 0), pts)
    assert sorted(order) == list(range(12))
    best = route.path_length_mm((0, 0), pts[order])
    assert best <= route.path_length_mm((0, 0), pts) + 1e-9
    # brute force on 7 points: 2-opt from nearest neighbour is within 15 % of the optimum
    from itertools import permutations
    few = pts[:7]
    opt = min(route.path_length_mm((0, 0), few[list(p)]) for p in permutations(range(7)))
    assert route.path_length_mm((0, 0), few[route.travel_order((0, 0), few)]) <= 1.15 * opt


def test_stopping_rules_compose():
    s = stopping.Status(touches=10, mean_std_mm=0.003, max_std_mm=0.02)
    assert (stopping.MeanStdBelow(0.004) | stopping.TouchBudget(100))(s) == "mean_std_bound"
    assert (stopping.MaxStdBelow(0.01) | stopping.TouchBudget(10))(s) == "touch_budget"
    assert (stopping.MeanStdBelow(0.004) & stopping.MaxStdBelow(0.01))(s) is None
    assert (stopping.MeanStdBelow(0.004) & stopping.MaxStdBelow(0.03))(s) == "mean_std_bound"
    assert stopping.MaxStdBelow(0.01)(s) is None


def test_a_rule_of_ones_own_composes_and_one_without_a_call_is_refused_on_creation():
    class Few(stopping.StopRule):
        name = "few"

        def __call__(self, status):
            return self.name if status.touches >= 10 else None

    s = stopping.Status(touches=10, mean_std_mm=0.003, max_std_mm=0.02)
    assert (stopping.MaxStdBelow(0.01) | Few())(s) == "few"

    class Forgot(stopping.StopRule):
        name = "forgot"

    with pytest.raises(TypeError, match="abstract"):
        Forgot()


def test_survey_module_example_runs_as_a_doctest(monkeypatch):
    """The survey module's docstring example (start, ask, tell, stop_reason) runs as written."""
    import doctest
    from pathlib import Path

    from adaptive_cal.planning import survey

    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the example reads configs/
    result = doctest.testmod(survey, raise_on_error=False, verbose=False)
    assert result.attempted >= 10 and result.failed == 0
