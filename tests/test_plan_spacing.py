"""The planner keeps touches apart (``plan.min_spacing_mm``) once the self-checks found structure
finer than the knots: no touch is planned within the spacing of an earlier one, nor of another
in its batch, while points further away are allowed; on a plate too full for it the spacing is
halved until one is."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import adaptive_cal

sys.path.insert(0, str(Path(__file__).parent))
from helpers import sim_cell  # noqa: E402

adaptive_cal.use_float64()


def _plan(**plan):
    from adaptive_cal.cell.build import survey_plan

    return survey_plan(sim_cell(plan={"candidates": 2000, **plan}))


def test_apart_is_the_brute_force_distance_test():
    from adaptive_cal.planning.ask import apart

    rng = np.random.default_rng(0)
    xy = rng.uniform(-200, 200, (3000, 2))
    for n in (1, 5, 8, 9, 60):  # the direct branch and the k-d tree
        t = rng.uniform(-200, 200, (n, 2))
        d = np.sqrt(((xy[:, None] - t[None]) ** 2).sum(-1)).min(1)
        assert np.array_equal(apart(xy, t, 30.0), d >= 30.0)
    assert apart(xy, [], 30.0).all() and apart(xy, t, 0.0).all()


def test_default_spacing_is_half_the_planning_knot_interval():
    from adaptive_cal.cell.build import min_spacing

    plan = _plan()
    s = plan.model.surface
    half = 0.5 * max(np.diff(s.sx.knots).max(), np.diff(s.sy.knots).max())
    assert plan.min_spacing_mm == pytest.approx(half) and half > 5.0
    assert _plan(min_spacing_mm=0).min_spacing_mm == 0.0
    assert min_spacing(sim_cell(plan={"min_spacing_mm": 12.5}), s) == 12.5


def _touched(plan):
    """A state whose belief is the prior's but whose probe already touched the point the
    planner takes first: without the spacing it would take it again."""
    from adaptive_cal.gaussian import belief as bl
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.ask import ask

    state = sv.start(plan)
    (x0, x1), (y0, y1) = plan.bounds_mm
    xy = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1], [0.5 * (x0 + x1), 0.5 * (y0 + y1)]])
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])  # five readings: the stroke is free
    state = replace(state, belief=bl.condition(state.belief, rows, np.zeros(5), 1e-5))
    first = ask(plan, state, 1)[0]
    found = np.full(plan.adequacy_regions, 1e-6)  # as if the checks found finer structure
    return replace(state, touched_xy_mm=((first.x_mm, first.y_mm),), grown_mm2=found), first


def test_no_touch_is_planned_within_the_spacing_of_an_earlier_one():
    from adaptive_cal.planning.ask import ask

    off = _plan(min_spacing_mm=0)
    state, first = _touched(off)
    again = ask(off, state, 1)[0]
    assert np.hypot(again.x_mm - first.x_mm, again.y_mm - first.y_mm) < 1.0  # could fail
    on = _plan(min_spacing_mm=40.0)
    state, first = _touched(on)
    t = ask(on, state, 1)[0]
    assert np.hypot(t.x_mm - first.x_mm, t.y_mm - first.y_mm) >= 40.0 - 1e-9


def test_a_batch_keeps_its_spacing_among_itself_and_from_earlier_touches():
    from adaptive_cal.planning.ask import ask

    plan = _plan(min_spacing_mm=40.0)
    state, first = _touched(plan)
    batch = ask(plan, state, 8)
    pts = np.array([[t.x_mm, t.y_mm] for t in batch] + [[first.x_mm, first.y_mm]])
    assert len(batch) == 8
    d = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1))
    assert d[np.triu_indices(len(pts), 1)].min() >= 40.0 - 1e-9


def test_a_plate_too_full_for_the_spacing_still_gets_a_touch():
    from adaptive_cal.planning.ask import ask

    plan = _plan(min_spacing_mm=5000.0)  # no point of the plate keeps it
    state, first = _touched(plan)
    t = ask(plan, state, 1)
    assert len(t) == 1 and plan.allows(t[0].x_mm, t[0].y_mm)


def test_touches_are_kept_apart_only_once_finer_structure_was_found():
    from dataclasses import replace as rep

    from adaptive_cal.planning.adequacy import Adequacy
    from adaptive_cal.planning.ask import ask, kept_apart

    plan = _plan(min_spacing_mm=40.0)
    state, first = _touched(plan)
    assert kept_apart(plan, state) == 40.0
    quiet = rep(state, grown_mm2=np.zeros(plan.adequacy_regions))
    assert kept_apart(plan, quiet) == 0.0 and kept_apart(plan, rep(state, grown_mm2=None)) == 0.0
    again = ask(plan, quiet, 1)[0]  # nothing found: the touch beside the first is allowed
    assert np.hypot(again.x_mm - first.x_mm, again.y_mm - first.y_mm) < 1.0
    edges = np.linspace(0, 1, 4)
    bad = Adequacy(False, {}, np.zeros((3, 3)), edges, edges, 45.0, np.zeros((3, 3), int))
    assert kept_apart(plan, rep(quiet, adequacy=bad)) == 40.0


def test_touches_kept_apart_still_plan_a_batch_ahead():
    """The spacing does not count as the stroke steering the choice: with most of the plate
    within the spacing of a touch, the time-aware planner still plans ahead (a batch)."""
    from adaptive_cal.planning.ask import FREE, apart, ask

    plan = _plan(min_spacing_mm=40.0)
    state, first = _touched(plan)
    rng = np.random.default_rng(1)
    (x0, x1), (y0, y1) = plan.bounds_mm
    xy = np.stack([rng.uniform(x0, x1, 60), rng.uniform(y0, y1, 60)], 1)
    state = replace(state, touched_xy_mm=tuple(map(tuple, xy)), touches=60)
    assert apart(plan.candidates.xy_mm, xy, 40.0).mean() < FREE  # most of the plate is near
    batch = ask(plan, state)
    assert plan.batch == 1 and plan.time_aware and len(batch) > 1


def _sixty(plan, unresolved_mm2: float = 0.0, adequate: bool = True):
    """A state of 60 touches spread over the plate (the belief of ``_touched``) whose checks
    found ``unresolved_mm2`` of variance the spline cannot follow in each of 3 x 3 regions."""
    from adaptive_cal.planning.adequacy import Adequacy

    state, _ = _touched(plan)
    rng = np.random.default_rng(2)
    (x0, x1), (y0, y1) = plan.bounds_mm
    xy = np.stack([rng.uniform(x0, x1, 60), rng.uniform(y0, y1, 60)], 1)
    (px0, px1), (py0, py1) = plan.plate_mm
    ex, ey = np.linspace(px0, px1, 4), np.linspace(py0, py1, 4)
    checks = Adequacy(adequate, {}, np.full((3, 3), unresolved_mm2), ex, ey, 45.0,
                      np.full((3, 3), 7))
    return replace(state, touched_xy_mm=tuple(map(tuple, xy)), touches=60, grown_mm2=None,
                   adequacy=checks)


def test_a_batch_ends_where_its_picks_would_meet_the_bound_unresolved_variance_included():
    """A batch planned ahead ends where its picks would meet the bound by the status the stop
    sees (``survey.status``), the unresolved variance the checks found included: while it
    keeps the bound unmet the batch runs on. Judged by the spline's variance alone it ended
    after one pick, and on rough plates the last 64 touches were each a lone pick 100-380 mm
    from the one before (fails with the old spline-only status). A failing check alone does
    not run a batch on: it is cut where the bound would be met once the checks pass (they are
    judged again as the readings come)."""
    from adaptive_cal.planning.ask import ask
    from adaptive_cal.planning.survey import status

    plan = _plan(min_spacing_mm=0, stop={"mean_std_mm": 1.0, "min_touches": 0})
    state = _sixty(plan)
    assert plan.stop(status(plan, state)) == "mean_std_bound"  # the spline alone meets 1 mm
    assert len(ask(plan, state)) == 1  # ... so a batch ends after its first pick
    unresolved = _sixty(plan, 4.0)  # 2 mm RMS the spline cannot follow
    assert plan.stop(status(plan, unresolved)) is None
    assert len(ask(plan, unresolved)) == plan.lookahead  # 64 planned ahead (at most 2 x 60)
    failing = _sixty(plan, adequate=False)
    assert plan.stop(status(plan, failing)) is None  # the stop waits for the checks ...
    assert len(ask(plan, failing)) == 1  # ... the batch is cut as if they pass


def test_touches_left_reads_the_budget_of_a_composed_rule():
    """The touch budget under | is the smallest one; under & it stops only with the other
    rule, so it is no budget; a bound alone has none."""
    from adaptive_cal.planning.stopping import (AtLeast, MeanStdBelow, TouchBudget,
                                                touches_left)

    bound = MeanStdBelow(0.004)
    assert touches_left((bound & AtLeast(30)) | TouchBudget(200), 60) == 140
    assert touches_left(TouchBudget(300) | bound | TouchBudget(150), 60) == 90
    assert touches_left(TouchBudget(50), 60) == 0
    assert touches_left(bound & TouchBudget(200), 60) is None
    assert touches_left(bound | AtLeast(200), 60) is None  # AtLeast is a floor, not a budget


def test_the_rest_of_the_budget_is_one_batch_when_it_is_at_most_twice_the_touches_made():
    """A plate the touch budget will end is finished in one tour: with the bound out of reach
    (the unresolved variance alone misses it) and the rest of the budget at most twice the
    touches made, the batch runs to the budget (rough plates: two tours of 64 and 57 touches at
    44-47 mm a step became one at about 33 mm, 10 s of 675 s a plate); with more left it is
    ``plan.lookahead`` as before, and it never runs past the budget. A bound in reach keeps
    the lookahead (a long batch planned under early hyper-parameters met it 4-32 touches late
    on 4 of 40 study plates)."""
    from dataclasses import replace as rep

    from adaptive_cal.planning.ask import ask, out_of_reach
    from adaptive_cal.planning.route import path_length_mm

    sizes = {}
    for budget in (100, 150, 180, 181, 400):
        plan = _plan(min_spacing_mm=0, stop={"mean_std_mm": 1.0, "min_touches": 0,
                                             "max_touches": budget})
        sizes[budget] = ask(plan, _sixty(plan, 4.0))  # 2 mm RMS unresolved: 1 mm out of reach
    assert len(sizes[100]) == 40  # cut at the budget, as before
    assert len(sizes[150]) == 90 and len(sizes[180]) == 120  # the rest, in one tour
    assert len(sizes[181]) == len(sizes[400]) == plan.lookahead  # more than 2 x 60 left

    reach = _plan(min_spacing_mm=0, stop={"mean_std_mm": 1e-4, "min_touches": 0,
                                          "max_touches": 150})  # 0.1 um: no 90 picks meet it
    in_reach = rep(_sixty(reach, 4.0), adequacy=None)  # ... but a spline known exactly would
    assert not out_of_reach(reach, in_reach) and out_of_reach(reach, _sixty(reach, 4.0))
    assert len(ask(reach, in_reach)) == reach.lookahead
    # one tour of 120 steps shorter than the 64 of a lookahead batch would (the same picks
    # lead both: the greedy order does not depend on how many follow)
    one = np.array([[t.x_mm, t.y_mm] for t in sizes[180]])
    first = np.array([[t.x_mm, t.y_mm] for t in sizes[400]])
    start = plan.here_xy_mm(_sixty(plan, 4.0).touched_xy_mm)
    assert path_length_mm(start, one) / 120 < path_length_mm(start, first) / 64
