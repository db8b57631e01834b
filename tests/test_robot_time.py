"""Robot time as the cost: the time-aware choice against a brute-force argmax of the same
objective, batches priced along their path and ordered for travel, robot time in result.json,
the terminal and the study records."""
from dataclasses import replace
from itertools import permutations

import numpy as np
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning import route, scoring
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import ask, kept_apart

from adaptive_cal.run.devices import open_cell

from helpers import drive, sim_cell

RNG = np.random.default_rng(14)


def _plan(**kw):
    """The simulated cell's plan on a coarse candidate grid, no refinement, learning off."""
    cell = sim_cell(plan={"candidates": 600, "refine": 0},
                    model={"knots_x": 6, "knots_y": 5, "learn_hyper": False})
    return replace(survey_plan(cell), **kw)


def _told(plan, n):
    """A state after n touches at random allowed points (readings where the belief expects
    them: the covariance does not depend on the readings)."""
    state = sv.start(plan)
    for i in RNG.choice(len(plan.candidates.xy_mm), n, replace=False):
        x, y = plan.candidates.xy_mm[i]
        h = plan.model.surface.basis(np.array([x]), np.array([y]))[0]
        mean = float(h @ state.belief.mean)
        z = plan.approach_height(mean)
        state, _ = sv.tell(plan, state, x, y, z, mean - z + plan.zero_mm)
    return state


def _brute_objective(plan, state, here):
    """dJ / (touch_time_s + |p - here| / speed) for every allowed candidate, by explicit
    posterior covariances (trace(Q C) before minus after, one candidate at a time, in loops);
    a candidate within the spacing touches keep (``ask.kept_apart``) of a touch is not allowed."""
    cov, r, gram = state.belief.cov, state.noise_var, plan.gram
    j0 = np.trace(gram @ cov)
    out = np.full(len(plan.candidates.xy_mm), -np.inf)
    for i, (h, p) in enumerate(zip(plan.candidates.rows, plan.candidates.xy_mm)):
        var = float(h @ cov @ h)
        if scoring.STROKE_Z * np.sqrt(var + r) > 0.5 * (plan.usable_mm[1] - plan.usable_mm[0]):
            continue  # not promised inside the stroke
        if any(np.hypot(p[0] - x, p[1] - y) < kept_apart(plan, state)
               for x, y in state.touched_xy_mm):
            continue  # too close to an earlier touch
        drop = j0 - np.trace(gram @ bl.covariance_after(cov, h[None], r))
        dist = np.sqrt((p[0] - here[0]) ** 2 + (p[1] - here[1]) ** 2)
        out[i] = drop / (plan.touch_time_s + dist / plan.speed_mm_per_s)
    return out


@pytest.mark.parametrize("touches,speed,touch_s,spacing", [
    (6, 150.0, 3.0, None), (12, 20.0, 0.5, None), (12, 500.0, 10.0, None), (12, 20.0, 0.5, 0.0)])
def test_time_aware_choice_is_the_brute_force_argmax_of_drop_per_second(touches, speed, touch_s,
                                                                        spacing):
    plan = _plan(speed_mm_per_s=speed, touch_time_s=touch_s, lookahead=1)
    if spacing is not None:  # None: the cell's default (half the knot interval)
        plan = replace(plan, min_spacing_mm=spacing)
    state = _told(plan, touches)
    if spacing is None:  # as if the checks had found structure finer than the knots
        state = replace(state, grown_mm2=np.full(plan.adequacy_regions, 1e-6))
    here = plan.here_xy_mm(state.touched_xy_mm)
    assert tuple(here) == state.touched_xy_mm[-1]
    brute = _brute_objective(plan, state, here)
    best = plan.candidates.xy_mm[int(np.argmax(brute))]
    t = ask(plan, state, 1)[0]
    np.testing.assert_allclose([t.x_mm, t.y_mm], best)
    # the same from an explicit probe position, and the choice moves with the probe
    other = np.array([-200.0, -170.0])
    t2 = ask(plan, state, 1, from_xy=other)[0]
    np.testing.assert_allclose([t2.x_mm, t2.y_mm],
                               plan.candidates.xy_mm[int(np.argmax(_brute_objective(plan, state,
                                                                                    other)))])


def test_time_blind_choice_is_the_largest_drop_and_the_first_touch_starts_at_the_centre():
    plan = _plan(time_aware=False)
    state = _told(plan, 5)
    brute = _brute_objective(replace(plan, speed_mm_per_s=1e12), state, (0.0, 0.0))
    t = ask(plan, state, 1)[0]
    np.testing.assert_allclose([t.x_mm, t.y_mm], plan.candidates.xy_mm[int(np.argmax(brute))])
    start = sv.start(plan)
    assert tuple(plan.here_xy_mm(start.touched_xy_mm)) == (0.0, 0.0)  # the plate centre


def test_rate_choice_prices_travel_and_refuses_when_nothing_is_allowed():
    xy = np.array([[0.0, 0.0], [300.0, 0.0]])
    drop = np.array([1.0, 1.6])
    ok = np.array([True, True])
    # 3 s + 0 s against 3 s + 2 s: 1 / 3 > 1.6 / 5
    assert scoring.rate_choice(drop, ok, xy, (0.0, 0.0), 150.0, 3.0) == 0
    assert scoring.rate_choice(drop, ok, xy, (300.0, 0.0), 150.0, 3.0) == 1
    assert scoring.rate_choice(drop, ok, xy, (0.0, 0.0), 1e9, 3.0) == 1  # travel free
    assert scoring.rate_choice(drop, np.array([False, False]), xy, (0, 0), 150.0, 3.0) == -1


def _greedy_set(plan, state, k):
    """k picks, each the allowed candidate of largest drop of J after the picks before it,
    by explicit covariances (allowed: inside the stroke under the belief now)."""
    rows, cov, r, gram = plan.candidates.rows, state.belief.cov, state.noise_var, plan.gram
    half = 0.5 * (plan.usable_mm[1] - plan.usable_mm[0])
    ok = [scoring.STROKE_Z * np.sqrt(float(h @ cov @ h) + r) <= half for h in rows]
    chosen = []
    for _ in range(k):
        j0 = np.trace(gram @ cov)
        drops = [j0 - np.trace(gram @ bl.covariance_after(cov, h[None], r)) if a else -np.inf
                 for h, a in zip(rows, ok)]
        chosen.append(int(np.argmax(drops)))
        cov = bl.covariance_after(cov, rows[chosen[-1]][None], r)
    return chosen


def test_a_batch_is_the_greedy_set_and_its_travel_order_never_lengthens_it():
    plan = _plan(lookahead=6)
    state = _told(plan, 8)
    here = plan.here_xy_mm(state.touched_xy_mm)
    picked = plan.candidates.xy_mm[_greedy_set(plan, state, 6)]
    for batch in (ask(plan, state, 6), ask(plan, state)):  # asked for, or planned ahead
        assert len(batch) == 6
        pts = np.array([[t.x_mm, t.y_mm] for t in batch])
        assert sorted(map(tuple, pts)) == sorted(map(tuple, picked))
        assert route.path_length_mm(here, pts) <= route.path_length_mm(here, picked) + 1e-9
    # one touch asked for: the best drop per second alone; no lookahead while time is blind
    assert len(ask(plan, state, 1)) == 1
    assert len(ask(replace(plan, time_aware=False), state)) == 1


def test_no_planning_ahead_while_the_stroke_steers_the_choice():
    plan = _plan(lookahead=6)
    state = sv.start(plan)  # the tilt unknown: only points near the centre are promised
    assert len(ask(plan, state)) == 1


def test_travel_order_never_lengthens_the_given_order():
    for seed in range(60):
        rng = np.random.default_rng(seed)
        n = int(rng.integers(1, 14))
        pts = rng.uniform(-200, 200, (n, 2))
        if seed % 3 == 0:  # a given order already short (a serpentine row): kept or bettered
            pts = pts[np.argsort(pts[:, 0])]
        start = rng.uniform(-200, 200, 2)
        order = route.travel_order(start, pts)
        assert sorted(order) == list(range(n))
        assert route.path_length_mm(start, pts[order]) <= route.path_length_mm(start, pts) + 1e-9
        if n <= 6:  # and never longer than 1.15 x the best open path
            opt = min(route.path_length_mm(start, pts[list(p)]) for p in permutations(range(n)))
            assert route.path_length_mm(start, pts[order]) <= 1.15 * opt + 1e-9


def test_robot_time_is_travel_at_speed_plus_touch_time():
    pts = [(3.0, 4.0), (3.0, 4.0), (6.0, 8.0)]  # a retake at the same point travels nothing
    s, travel = route.robot_time_s((0.0, 0.0), pts, 2.0, 1.5)
    assert travel == pytest.approx(10.0)
    assert s == pytest.approx(10.0 / 2.0 + 3 * 1.5)
    assert route.robot_time_s((0, 0), [], 2.0, 1.5) == (0.0, 0.0)


def test_plan_carries_the_robot_speed_touch_time_and_start():
    cell = sim_cell(robot={"speed_mm_per_s": 123.0, "touch_time_s": 2.5})
    plan = survey_plan(cell)
    assert (plan.speed_mm_per_s, plan.touch_time_s, plan.start_xy_mm) == (123.0, 2.5, (0.0, 0.0))


def test_a_batch_ends_where_its_picks_would_stop_the_survey():
    plan = _plan(lookahead=40)
    state = _told(plan, 5)
    assert len(ask(plan, state)) == 10  # no more planned ahead than twice the touches made
    state = _told(plan, 12)
    picks = _greedy_set(plan, state, 24)
    cov, rows, r = state.belief.cov, plan.candidates.rows, state.noise_var
    area = plan.model.surface.area_mm2
    need = None
    for k, i in enumerate(picks, 1):  # brute force: the first count whose RMS std meets 4 um
        cov = bl.covariance_after(cov, rows[i][None], r)
        if np.sqrt(np.trace(plan.gram @ cov) / area) <= 0.004:
            need = k
            break
    assert need is not None and 1 < need < 24
    batch = ask(plan, state)
    assert len(batch) == need
    assert sorted((t.x_mm, t.y_mm) for t in batch) == sorted(map(tuple, plan.candidates.xy_mm[picks[:need]]))


def test_result_json_terminal_and_report_give_touches_and_robot_time_side_by_side(tmp_path,
                                                                                  capsys):
    import json

    import yaml

    from adaptive_cal.cli import main
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.report.sections import run_section

    from helpers import SIM_CELL

    data = yaml.safe_load(SIM_CELL.read_text())
    data["plan"]["stop"]["max_touches"] = 12
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    # 12 touches, the bound unmet: not a result (exit 1), its figures written all the same
    assert main(["run", "--robot", str(cell), "--out", str(out), "--no-progress"]) == 1
    r = json.loads((out / "result.json").read_text())
    assert r["stopped_because"] == "touch_budget"
    rec = read_recording(out / "recording.csv")
    xy = np.column_stack([rec.x_mm, rec.y_mm])
    s, travel = route.robot_time_s((0.0, 0.0), xy, 150.0, 3.0)  # sim-cell: 150 mm/s, 3 s
    assert r["touches"] == len(xy) == 12
    assert r["travel_mm"] == pytest.approx(travel) and r["robot_time_s"] == pytest.approx(s)
    text = capsys.readouterr().out
    assert (f"estimated robot time: about {s / 60:.1f} min for 12 touches ({travel / 1000:.1f} m "
            "of travel at 150 mm/s, plus 3 s per touch)") in text
    # beside it the cell's own clock, which counts what the estimate leaves out
    assert (f"; the cell's own clock read {rec.t_s[-1] / 60:.1f} min at the last reading (the "
            "estimate leaves out vertical moves and a guarded approach's extra steps)") in text
    assert f"about {s / 60:.1f} min for 12 touches" in run_section(r)
    # result.json keeps that clock (the recording's last t_s), and the report shows it too
    assert r["clock_s"] == pytest.approx(rec.t_s[-1]) and r["clock_s"] > s
    assert f"the cell's own clock read {rec.t_s[-1] / 60:.1f} min at the last reading" \
        in run_section(r)


def test_study_summary_puts_touches_and_robot_time_side_by_side():
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.summary import summarise, table

    from helpers import ROOT

    study, _ = load_study(ROOT / "configs" / "study-tilts.yaml")

    def rec(strategy, plate, touches, time_s, travel):
        return {"strategy": strategy, "plate": plate, "touches": touches, "robot_time_s": time_s,
                "travel_mm": travel, "touches_true": touches, "robot_time_true_s": time_s,
                "true_rms_mm": 0.005, "true_max_mm": 0.02, "coverage95": 0.95,
                "mean_std_mm": 0.005, "trajectory": []}

    records = [rec("adaptive", 0, 60, 200.0, 3000.0), rec("adaptive", 1, 80, 280.0, 4000.0),
               rec("grid", 0, 72, 240.0, 3500.0), rec("grid", 1, 88, 300.0, 4500.0)]
    s = summarise(study.model_copy(update={"strategies": ["adaptive", "grid"]}), records)
    assert s["strategies"]["adaptive"]["stop_travel_mm_mean"] == 3500.0
    vg = s["adaptive_vs_grid"]
    assert {k: vg[k] for k in ("plates", "touch_ratio", "robot_time_ratio")} == {
        "plates": 2, "touch_ratio": pytest.approx(70 / 80),
        "robot_time_ratio": pytest.approx(240 / 270)}
    # paired resampling of 2 plates: (0, 0), (1, 1) or one of each -- 60/72, 80/88 or 70/80
    lo, hi = vg["touch_ratio_ci95"]
    assert 60 / 72 - 1e-12 <= lo <= hi <= 80 / 88 + 1e-12
    text = table(s)
    assert "| adaptive | 70.0 / 78 | 240 | 100% | 70.0 | 240 | 5.00 |" in text
    assert "touches 0.88 x (95 % " in text and ", robot time 0.89 x (95 % " in text
    assert "95 % intervals of the means over the plates" in text


def test_a_probe_position_the_adapter_cannot_read_is_planned_from_the_last_touch():
    """The Modbus and manual adapters know no position before their first move (NaN): the
    choice is then priced from the last touch (or the start), as with no position given -- it
    was NaN for every candidate, and the run ended before its first touch."""
    cell = sim_cell(plan={"candidates": 600},  # the refinement of the best points on
                    model={"knots_x": 6, "knots_y": 5, "learn_hyper": False})
    plan = survey_plan(cell)
    assert plan.refine > 0
    state = _told(plan, 5)
    for n in (1, 3):
        unknown = ask(plan, state, n, from_xy=(np.nan, np.nan))
        assert unknown and [(t.x_mm, t.y_mm) for t in unknown] == [
            (t.x_mm, t.y_mm) for t in ask(plan, state, n)]
    # a whole run through the loop on a motion that never knows where it is
    opened = open_cell(cell)
    opened.cycle.motion.position = lambda: (np.nan, np.nan, np.nan)
    state = drive(survey_plan(cell), opened, limit=6)
    assert state.touches == 6 and np.all(np.isfinite(state.touched_xy_mm))
