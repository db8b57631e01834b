"""The lower bound on touches: never above any integer design (brute force on a tiny case)."""
import itertools
import math

import numpy as np
import pytest

from adaptive_cal.gaussian.prior import Hyper, PriorModel
from adaptive_cal.gaussian.spline import Surface
from adaptive_cal.study.bound import (DesignProblem, best_integer_touches, relaxed_design,
                                      relaxed_touches)


@pytest.fixture(scope="module")
def tiny():
    surface = Surface.create(np.linspace(0, 100, 3), np.linspace(0, 80, 3))
    model = PriorModel(surface, 0.01, 0.2, (50.0, 40.0), Hyper(0.05, 60.0, 0.01))
    gx, gy = np.meshgrid(np.linspace(5, 95, 4), np.linspace(5, 75, 3), indexing="ij")
    rows = surface.basis(gx.ravel(), gy.ravel())
    return DesignProblem(model.belief(model.hyper0).cov, surface.gram(), rows, 0.01**2,
                         surface.area_mm2)


def _all_designs(prob, n):
    size = len(prob.rows)
    for combo in itertools.combinations_with_replacement(range(size), n):
        yield prob.integrated_variance(np.bincount(np.asarray(combo, int), minlength=size))


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_relaxed_variance_is_below_every_integer_design(tiny, n):
    w, j, lower = relaxed_design(tiny, n)
    best = min(_all_designs(tiny, n))
    assert lower <= j + 1e-12
    assert lower <= best * (1 + 1e-9)
    assert j <= best * (1 + 1e-6)  # the relaxation is at least as good as the best integer design


def test_relaxed_touches_below_best_integer(tiny):
    j2 = min(_all_designs(tiny, 2))
    j4 = min(_all_designs(tiny, 4))
    for target in (j2 * 1.01, 0.5 * (j2 + j4), j4 * 1.0001):
        best = best_integer_touches(tiny, target, 6, limit=10**6)
        relaxed = relaxed_touches(tiny, target, 6)
        assert best is not None and relaxed <= best
        # brute force agrees: no design of best - 1 touches reaches the target
        assert min(_all_designs(tiny, best - 1)) > target
    assert best_integer_touches(tiny, j4 * 1.0001, 6, limit=10) is None  # too many to enumerate


def test_unreachable_target_is_inf(tiny):
    assert math.isinf(relaxed_touches(tiny, 1e-12, 3))


def test_greedy_design_brackets_the_best_integer_design(tiny):
    """relaxed <= best integer (enumerated) <= greedy, and the greedy count is a real design:
    its touches reach the target, one fewer does not."""
    from adaptive_cal.study.bound import greedy_touches

    j2 = min(_all_designs(tiny, 2))
    j4 = min(_all_designs(tiny, 4))
    for target in (j2 * 1.01, 0.5 * (j2 + j4), j4 * 1.0001):
        best = best_integer_touches(tiny, target, 8, limit=10**6)
        greedy = greedy_touches(tiny, target, 8)
        assert relaxed_touches(tiny, target, 8) <= best <= greedy
    assert greedy_touches(tiny, 1e-12, 3) is None
    # brute-force the greedy choice for a few steps: the closed-form drop picks the argmin of J
    size = len(tiny.rows)
    counts = np.zeros(size, int)
    for step in range(1, 4):
        trial = [tiny.integrated_variance(counts + np.eye(size, dtype=int)[i]) for i in range(size)]
        counts[int(np.argmin(trial))] += 1
        assert greedy_touches(tiny, min(trial) * (1 + 1e-9), 8) <= step


def test_whole_touch_bound_rounds_up_and_stays_below_every_design(tiny):
    """The relaxation in whole touches: above the real-valued bound by less than one touch (or
    the certificate's own slack), never above the best design found by enumeration, and no
    design of one touch fewer reaches the target (brute force)."""
    from adaptive_cal.study.bound import integer_touches

    j2, j3, j4 = (min(_all_designs(tiny, n)) for n in (2, 3, 4))
    raised = 0
    for target in (j3 * 1.0001, j2 * 1.01, 0.5 * (j2 + j4), 0.7 * j2 + 0.3 * j4, j4 * 1.0001):
        relaxed = relaxed_touches(tiny, target, 8)
        whole = integer_touches(tiny, target, 8)
        best = best_integer_touches(tiny, target, 8, limit=10**6)
        assert whole == int(whole) and relaxed < whole <= best
        assert integer_touches(tiny, target, 8, relaxed=relaxed) == whole
        assert min(_all_designs(tiny, int(whole) - 1)) > target
        raised += whole - relaxed
    assert raised >= 1.0  # rounding up tightened the bound by at least a touch in all
    assert math.isinf(integer_touches(tiny, 1e-12, 3))


@pytest.fixture(scope="module")
def tiny_marginal(tiny):
    """Three weighted hyper-parameter points on the tiny problem's candidates."""
    from adaptive_cal.study.bound import MarginalProblem

    surface = Surface.create(np.linspace(0, 100, 3), np.linspace(0, 80, 3))
    model = PriorModel(surface, 0.01, 0.2, (50.0, 40.0), Hyper(0.05, 60.0, 0.01))
    points = [(Hyper(0.05, 60.0, 0.01), 0.5), (Hyper(0.12, 40.0, 0.02), 0.3),
              (Hyper(0.02, 90.0, 0.004), 0.2)]
    parts = tuple(DesignProblem(model.belief(h).cov, surface.gram(), tiny.rows,
                                h.noise_std_mm**2, surface.area_mm2) for h, _ in points)
    return MarginalProblem(parts, tuple(w for _, w in points))


def test_marginal_objective_is_the_weighted_sum_and_its_gradient_is_exact(tiny_marginal):
    """J_marg of an integer design is sum_k a_k J_k (each part computed on its own), and the
    scores are the gradient: dJ/dw_i = -n s_i, checked by central differences."""
    from adaptive_cal.study.bound import _objective

    prob = tiny_marginal
    counts = np.array([2, 0, 1, 0, 0, 1, 0, 0, 0, 3, 0, 1])
    expected = sum(a * p.integrated_variance(counts) for p, a in zip(prob.parts, prob.weights))
    assert prob.integrated_variance(counts) == pytest.approx(expected, rel=1e-12)
    w = np.linspace(1, 2, len(prob.rows))
    w /= w.sum()
    n, eps = 5.0, 1e-6
    _, s = _objective(prob, w, n)
    for i in (0, 4, 11):
        e = np.eye(len(w))[i]
        fd = (_objective(prob, w + eps * e, n, False)[0]
              - _objective(prob, w - eps * e, n, False)[0]) / (2 * eps)
        assert fd == pytest.approx(-n * s[i], rel=1e-5)


def test_marginal_bound_stays_below_every_design_and_one_point_is_the_plain_bound(
        tiny, tiny_marginal):
    """Brute force under the marginal criterion: the certified relaxation is below every integer
    design, the whole-touch bound never above the best enumerated design and no design of one
    touch fewer reaches the target; with a single point of weight 1 it is the plain bound."""
    from adaptive_cal.study.bound import MarginalProblem, integer_touches

    prob = tiny_marginal
    for n in (1, 2, 3):
        _, j, lower = relaxed_design(prob, n)
        assert lower <= min(_all_designs(prob, n)) * (1 + 1e-9) and j >= lower
    j2, j4 = (min(_all_designs(prob, n)) for n in (2, 4))
    for target in (j2 * 1.01, 0.5 * (j2 + j4), j4 * 1.0001):
        whole = integer_touches(prob, target, 8)
        best = best_integer_touches(prob, target, 8, limit=10**6)
        assert whole == int(whole) and whole <= best
        assert min(_all_designs(prob, int(whole) - 1)) > target
    one = MarginalProblem((tiny,), (1.0,))
    for target in (0.5 * (j2 + j4), j4):
        assert relaxed_touches(one, target, 8) == relaxed_touches(tiny, target, 8)
        assert integer_touches(one, target, 8) == integer_touches(tiny, target, 8)
    with pytest.raises(ValueError, match="sum to 1"):
        MarginalProblem((tiny, tiny), (0.5, 0.6))
