"""plan.stop.max_gap_mm: a variance bound stops the run only once no allowed point is farther
than the radius from a touch, and the planner fills the gaps (farthest point first)."""
import numpy as np
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.planning.gap import largest_gap
from adaptive_cal.planning.stopping import GapBelow, MeanStdBelow, Status

from helpers import loop_on, sim_cell


def _brute_gap(cand, touched):
    """max over candidates of the distance to the nearest touch, by full distance matrix."""
    d = np.sqrt(((cand[:, None, :] - touched[None, :, :]) ** 2).sum(-1))
    return d.min(axis=1).max()


def test_largest_gap_against_brute_force():
    rng = np.random.default_rng(0)
    cand = rng.uniform(-200, 200, (3000, 2))
    touched = rng.uniform(-200, 200, (25, 2))
    radius, i = largest_gap(cand, touched)
    assert radius == pytest.approx(_brute_gap(cand, touched), rel=1e-12)
    assert np.sqrt(((touched - cand[i]) ** 2).sum(1)).min() == pytest.approx(radius, rel=1e-12)
    assert largest_gap(cand, np.zeros((0, 2))) == (float("inf"), -1)


def test_a_bound_waits_for_the_gap():
    rule = MeanStdBelow(0.004) & GapBelow(30.0)
    assert rule(Status(40, 0.003, 0.01, gap_mm=45.0)) is None
    assert rule(Status(40, 0.003, 0.01, gap_mm=30.0)) == "mean_std_bound"
    assert rule(Status(40, 0.005, 0.01, gap_mm=10.0)) is None


def test_config_key_reaches_the_stop_rule():
    with_gap = survey_plan(sim_cell(plan={"stop": {"mean_std_mm": 0.004, "max_gap_mm": 50}}))
    assert with_gap.max_gap_mm == 50
    assert "GapBelow(radius_mm=50" in repr(with_gap.stop)
    plain = survey_plan(sim_cell())
    assert plain.max_gap_mm is None and "GapBelow" not in repr(plain.stop)
    with pytest.raises(Exception, match="max_gap_mm"):
        sim_cell(plan={"stop": {"max_gap_mm": -5}})


def test_a_run_with_a_gap_bound_leaves_no_wider_gap_and_stops_on_its_bound():
    """The simulated cell: the bound alone stops after about 31 touches with a gap of about
    83 mm; with max_gap_mm 60 it stops on the same bound later, every allowed candidate within
    60 mm of a touch (brute force over the plan's candidates)."""
    def run(stop):
        plan, state, why = loop_on(sim_cell(plan={"stop": {"mean_std_mm": 0.004, "max_touches": 120,
                                                            **stop}, "candidates": 2000}))
        touched = np.array(state.touched_xy_mm, float)
        return why, state.touches, _brute_gap(plan.candidates.xy_mm, touched)

    why0, n0, gap0 = run({})
    why, n, gap = run({"max_gap_mm": 60.0})
    assert why0 == why == "mean_std_bound"
    assert gap0 > 60.0 and gap <= 60.0 and n > n0
