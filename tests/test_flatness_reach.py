"""The flatness of the part of the plate touches could reach (the workplane less its edge
margin): beside the whole plate's figures, never in place of them; checked against numpy's
least squares and scipy's linear programme on the mean map, and against draws made here."""
import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import linprog

from adaptive_cal.analysis.flatness_answer import SAMPLES, answer_lines, flatness_answer
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.run import session

from helpers import sim_cell


def _brute(x, y, z):
    """(least-squares, minimum-zone) flatness in mm, each measured normal to its plane (Cheng
    eq. 5, ISO 1101): numpy lstsq and a linear programme, not adaptive_cal."""
    A = np.c_[x, y, np.ones_like(x)]
    a, b, c = np.linalg.lstsq(A, z, rcond=None)[0]
    ls = np.ptp(z - A @ (a, b, c)) / np.sqrt(1.0 + a * a + b * b)
    n = len(z)  # min w s.t. |z - (a x + b y + c)| <= w / 2
    res = linprog(np.r_[0.0, 0.0, 0.0, 1.0],
                  A_ub=np.r_[np.c_[A, -np.ones(n)], np.c_[-A, -np.ones(n)]], b_ub=np.r_[z, -z],
                  bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    a, b = res.x[:2]
    return float(ls), float(2.0 * res.x[3] / np.sqrt(1.0 + a * a + b * b))


@pytest.fixture(scope="module")
def answered():
    """A sim-cell plan (10 mm edge margin) and a belief from 30 readings of a bowed plate."""
    plan = survey_plan(sim_cell())
    rng = np.random.default_rng(4)
    xy = np.c_[rng.uniform(-215, 215, 30), rng.uniform(-175, 175, 30)]
    u, v = xy[:, 0] / 225.0, xy[:, 1] / 185.0
    heights = 0.3 * v**2 + 0.05 * u * v + 0.002 * rng.standard_normal(30)
    prior = plan.model.belief(plan.model.hyper0)
    belief = bl.condition(prior, plan.model.surface.basis(*xy.T), heights, 0.002**2)
    return plan, belief, flatness_answer(plan, belief, 0.002)


def _reach(plan):
    """A 41 x 41 grid spanning the reachable box, built here with numpy (edges included)."""
    gx, gy = np.meshgrid(np.linspace(-215, 215, 41), np.linspace(-175, 175, 41), indexing="ij")
    xy = np.c_[gx.ravel(), gy.ravel()]
    return xy, plan.model.surface.basis(*xy.T)


def test_within_reach_is_the_map_over_the_reachable_box_to_its_edges(answered):
    """An outside audit (2026-11-29): the figure was taken at the whole plate's grid nodes
    inside the box, which stop at y +-166.5 of +-175 mm: on a plate bowed across y it read
    8 % flatter than the box it names, the interval missing the truth."""
    plan, belief, out = answered
    within = out["flatness_within_reach_mm"]
    assert within["box_mm"] == [[-215.0, 215.0], [-175.0, 175.0]]
    xy, rows = _reach(plan)
    x, y = xy.T
    assert within["eval_points"] == len(x) == len(plan.eval_xy)
    mean = rows @ belief.mean
    ls, mz = _brute(x, y, mean)
    # lstsq against the product's normal equations on heights below 0.4 mm: round-off ~1e-15;
    # the LP's own feasibility tolerance (HiGHS, 1e-7 relative on ~0.3 mm) bounds the other
    assert within["least_squares"]["value"] == pytest.approx(ls, abs=1e-12)
    assert within["minimum_zone"]["value"] == pytest.approx(mz, abs=1e-8)
    # the bow is steepest at the y edges the margin cuts off: within reach is flatter
    ex, ey = plan.eval_xy.T
    assert mz < out["flatness_mm"]["minimum_zone"]["value"]
    # and the box's edges count: the old nodes inside it alone read flatter still
    inside = (np.abs(ex) <= 215) & (np.abs(ey) <= 175)
    assert _brute(ex[inside], ey[inside], (plan.eval_rows @ belief.mean)[inside])[1] < mz
    assert "range" not in within and "extrapolation" in within["means"]


def test_its_interval_is_over_the_same_coefficient_draws(answered):
    """The whole plate is drawn first from default_rng(SEED): the same coefficient draws, on
    the reach grid, give the within-reach interval (least squares: numpy on each draw here)."""
    plan, belief, out = answered
    xy, rows = _reach(plan)
    x, y = xy.T
    draws = bl.sample(belief, np.random.default_rng(0), SAMPLES) @ rows.T
    ls = [_brute(x, y, d)[0] for d in draws]
    lo, hi = out["flatness_within_reach_mm"]["least_squares"]["ci95"]
    assert (lo, hi) == pytest.approx(tuple(np.percentile(ls, [2.5, 97.5])), abs=1e-12)


def test_the_whole_plate_keeps_its_digits_and_a_plate_without_margin_has_no_entry(answered):
    plan, belief, out = answered
    bare = flatness_answer(replace(plan, bounds_mm=plan.plate_mm), belief, 0.002)
    assert bare["flatness_mm"] == out["flatness_mm"] and bare["tilt"] == out["tilt"]
    assert "flatness_within_reach_mm" not in bare


def test_run_result_and_its_lines_carry_it(tmp_path):
    out = tmp_path / "run"
    session.run(sim_cell(), out, progress=False)
    r = json.loads((out / "result.json").read_text())
    within = r["flatness_within_reach_mm"]
    assert within["box_mm"] == [[-215.0, 215.0], [-175.0, 175.0]]
    lines = answer_lines(r)
    plate = [i for i, ln in enumerate(lines) if ln.startswith("flatness of the whole plate")]
    reach = [i for i, ln in enumerate(lines) if ln.startswith("flatness within reach")]
    assert reach == [plate[0] + 1]
    assert "x -215..215, y -175..175 mm; beyond, the map is extrapolated" in lines[reach[0]]
    # what the whole plate's intervals held on plates the prior did not make, said under them
    # (an outside audit, 2026-11-29: 88 of 120 plates, edge roll-off 7 of 17, while every line
    # said "95 %"); a result's flatness_mm says what it is of
    from adaptive_cal.analysis.flatness_answer import PLATE_CALIBRATION, PLATE_IS

    assert lines.index(PLATE_CALIBRATION) > reach[0] and "70-80 %" in PLATE_CALIBRATION
    assert r["flatness_mm_is"] == PLATE_IS
    assert PLATE_CALIBRATION not in answer_lines({"touched_flatness_mm": r["touched_flatness_mm"]})
