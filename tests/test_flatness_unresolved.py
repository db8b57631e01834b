"""The whole plate's flatness interval carries the structure finer than the knots (s_u^2), and a
run says where a narrow feature could hide between its touches (``largest_gap``)."""
from types import SimpleNamespace

import numpy as np
import pytest

from adaptive_cal.analysis.flatness_answer import (answer_lines, largest_gap, plate_answer,
                                                   unresolved_draws)
from adaptive_cal.gaussian import belief as bl


def _dense_cov(xy, var, length):
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1)
    return np.exp(-0.5 * d2 / length**2) * np.sqrt(np.outer(var, var))


@pytest.mark.parametrize("shuffled", [False, True])
def test_unresolved_draws_have_the_stated_covariance(shuffled):
    """Monte Carlo against the dense covariance s_i s_j exp(-d^2 / 2 l^2): on the plan's grid
    (Kronecker path) and on the same points in another order (dense path). With S = 20,000
    draws the sample covariance's sd is at most sqrt(2 / S) v_max = 1 % of the largest variance;
    allowed 5 sd."""
    ux, uy = np.linspace(-100.0, 100.0, 9), np.linspace(-60.0, 60.0, 7)
    gx, gy = np.meshgrid(ux, uy, indexing="ij")
    xy = np.c_[gx.ravel(), gy.ravel()]
    var = np.linspace(1.0, 4.0, len(xy)) * 1e-6
    if shuffled:
        order = np.random.default_rng(3).permutation(len(xy))
        xy, var = xy[order], var[order]
    draws = unresolved_draws(xy, var, 30.0, np.random.default_rng(1), 20_000)
    want = _dense_cov(xy, var, 30.0)
    assert np.abs(np.cov(draws.T) - want).max() <= 5 * np.sqrt(2 / 20_000) * var.max()
    assert np.abs(draws.mean(0)).max() <= 5 * np.sqrt(var.max() / 20_000)


def test_no_unresolved_variance_changes_nothing():
    """Zero variance: zeros, and the generator untouched, so every later draw keeps its digits."""
    rng = np.random.default_rng(5)
    out = unresolved_draws(np.zeros((4, 2)), np.zeros(4), 10.0, rng, 3)
    assert out.shape == (3, 4) and not out.any()
    assert rng.standard_normal() == np.random.default_rng(5).standard_normal()


def _plane_belief():
    """A belief over a flat plate: rows of (1, x, y) with a tiny covariance, on a 21 x 21 grid."""
    g = np.linspace(-100.0, 100.0, 21)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    xy = np.c_[gx.ravel(), gy.ravel()]
    rows = np.c_[np.ones(len(xy)), xy / 100.0]
    return xy, rows, bl.Belief(np.zeros(3), np.eye(3) * 1e-14)


def test_unresolved_structure_widens_the_whole_plate_interval_to_its_own_flatness():
    """A plate the spline knows exactly flat (mean 0, std ~0), with s_u = 5 um everywhere: the
    interval of its flatness is that of the unresolved field alone -- brute force: the minimum
    zone of fields drawn independently here from the same covariance (400 each side; the
    medians agree within 10 %)."""
    xy, rows, belief = _plane_belief()
    var = np.full(len(xy), 25e-6)
    _, bare = plate_answer(xy, rows, belief, np.random.default_rng(0), 100)
    assert bare["minimum_zone"]["ci95"][1] < 1e-5  # 0.01 um: the spline's variance alone
    _, plate = plate_answer(xy, rows, belief, np.random.default_rng(0), 400, var, 40.0)
    from adaptive_cal.analysis import flatness as fl
    root = np.linalg.cholesky(_dense_cov(xy, var, 40.0) + 1e-14 * np.eye(len(xy)))
    brute = [fl.minimum_zone_mm(xy[:, 0], xy[:, 1], root @ z).value_mm
             for z in np.random.default_rng(9).standard_normal((400, len(xy)))]
    lo, hi = plate["minimum_zone"]["ci95"]
    assert lo > 10e-3 and hi < 40e-3  # um-scale: between 2 and 8 sd of the field
    assert np.median(brute) == pytest.approx(plate["minimum_zone"]["value"], rel=0.1)


def test_largest_gap_is_the_fill_distance_of_the_touches():
    """Touches at the four corners of a square of candidates: the farthest candidate is the
    centre, half the diagonal away; one more touch there moves the gap to an edge's midpoint."""
    g = np.linspace(0.0, 100.0, 101)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    plan = SimpleNamespace(candidates=SimpleNamespace(xy_mm=np.c_[gx.ravel(), gy.ravel()]))
    corners = [(0, 0), (100, 0), (0, 100), (100, 100)]
    gap = largest_gap(plan, corners)
    assert (gap["x_mm"], gap["y_mm"]) == (50.0, 50.0)
    assert gap["radius_mm"] == pytest.approx(50.0 * np.sqrt(2.0))
    gap = largest_gap(plan, corners + [(50, 50)])
    assert gap["radius_mm"] == pytest.approx(50.0)
    assert largest_gap(plan, np.zeros((0, 2))) is None
    line = answer_lines({"flatness_mm": {}, "largest_gap": gap})
    assert line == []  # no whole-plate answer, no gap line
    lines = answer_lines({"flatness_mm": {"least_squares": {"value": 1e-3, "ci95": [0, 2e-3]}},
                          "largest_gap": gap})
    assert lines[-1].startswith("largest gap between touches: 50 mm radius around (")
