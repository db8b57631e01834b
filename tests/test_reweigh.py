"""A gross error fused in full among the first touches (judged against the hyper-prior's wide
mixture) is judged again once the noise is learned: its weight falls to 1 - p, p from its
leave-one-out predictive -- checked against a batch posterior without it -- and nothing else
moves on a clean plate."""
from dataclasses import replace

import numpy as np
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.gate import FLAG_P, W_MIN, Predictive, outlier_probability

from helpers import sim_cell


def _state(spike_um: float, seed: int = 0):
    """40 readings of a flat plate (5 um noise); reading 2 carries ``spike_um`` more."""
    cell = sim_cell(plan={"candidates": 2000}, probe={"noise_std_mm": 0.005})
    plan = survey_plan(cell, grow=False)
    rng = np.random.default_rng(seed)
    xy = np.c_[rng.uniform(-200, 200, 40), rng.uniform(-160, 160, 40)]
    h = 0.005 * rng.standard_normal(40)
    h[2] += spike_um * 1e-3
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    state = replace(sv.start(plan), rows=rows, heights_mm=h, weights=np.ones(40), touches=40,
                    touched_xy_mm=tuple(map(tuple, xy)))
    return plan, sv.refit(plan, state)


def test_a_gross_error_is_lowered_to_its_leave_one_out_outlier_probability():
    plan, state = _state(128.0)
    w = state.fused_weights
    assert w[2] < 0.05 and np.all(np.delete(w, 2) == 1.0)
    # oracle: the batch posterior of the other 39 readings under the state's hyper-parameters
    # (the refit after the reweighing moves them a little: judge with the state's own)
    prior = plan.model.belief(state.hyper, sv.extra_cov(plan, state))
    keep = np.delete(np.arange(40), 2)
    r = state.hyper.noise_std_mm**2
    post = bl.condition(prior, state.rows[keep], state.heights_mm[keep], r / w[keep])
    m, v = bl.predict(post, state.rows[2:3])
    stroke = plan.usable_mm[1] - plan.usable_mm[0]
    p = outlier_probability(Predictive.gaussian(float(m[0]), float(v[0]) + r),
                            float(state.heights_mm[2]), stroke)
    again = sv.reweighed(plan, state)  # judged again under the final fit: the same weight
    assert (again if again is not None else w)[2] == pytest.approx(1.0 - p, abs=1e-6)
    assert p > 1 - FLAG_P


def test_a_clean_plate_keeps_every_weight():
    for seed in range(5):
        _, state = _state(0.0, seed)
        assert np.all(state.fused_weights == 1.0)


@pytest.mark.parametrize("n", [40, 160])
def test_a_certain_gross_error_keeps_a_finite_weight_and_the_fit_stays_finite(n):
    """p rounds to 1.0 for a 2 mm error: its weight is floored at ``W_MIN``, not 0 (a weight of
    0 gave the reading an infinite noise variance, the hyper-parameter fit NaN, and a
    heavy-tailed plate's run ended in 'Eigenvalues did not converge' at its closure)."""
    cell = sim_cell(plan={"candidates": 2000}, probe={"noise_std_mm": 0.005})
    plan = survey_plan(cell, grow=False)
    rng = np.random.default_rng(3)
    xy = np.c_[rng.uniform(-200, 200, n), rng.uniform(-160, 160, n)]
    h = 0.005 * rng.standard_normal(n)
    h[5] += 2.0
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    state = replace(sv.start(plan), rows=rows, heights_mm=h, weights=np.ones(n), touches=n,
                    touched_xy_mm=tuple(map(tuple, xy)))
    state = sv.refit(plan, state)
    w = state.fused_weights
    assert sv.W_MIN <= w[5] < 1e-5 and np.all(np.delete(w, 5) > 0.5)
    assert np.all(np.isfinite(state.belief.mean)) and np.all(np.isfinite(state.belief.cov))
    assert np.isfinite(state.hyper.noise_std_mm) and state.hyper.noise_std_mm < 0.01
    again = sv.refit(plan, state)  # a second refit (the closure's) from the floored weights
    assert np.all(np.isfinite(again.belief.mean))


class _FirstTouchMisreads:
    """A probe cycle whose first reading is ``error_mm`` high (a chip under the first touch)."""

    def __init__(self, cycle, error_mm):
        self.cycle, self.error_mm, self.n = cycle, error_mm, 0

    def __getattr__(self, name):
        return getattr(self.cycle, name)

    def touch(self, x_mm, y_mm, z_mm, plate_top=None):
        t = self.cycle.touch(x_mm, y_mm, z_mm, plate_top)
        self.n += 1
        return replace(t, reading_mm=t.reading_mm + self.error_mm) if self.n == 1 else t


def _first_touch_misread_run():
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.run.loop import run_loop

    cell = sim_cell(plan={"candidates": 2000, "stop": {"mean_std_mm": 0.006,
                                                      "max_touches": 40}})
    plan = survey_plan(cell)
    opened = open_cell(cell)
    rows = []
    try:
        state, why = run_loop(plan, sv.start(plan), _FirstTouchMisreads(opened.cycle, 1.4),
                              record=rows.append)
    finally:
        opened.close()
    return plan, state, why, rows


def test_a_gross_error_on_the_first_touch_is_condemned_when_a_retake_contradicts_it():
    """1.4 mm on the first reading: the gate retakes the next, genuine reading, the retake
    confirms it (surprise), and the first reading is then judged against the confirmed pair:
    weight W_MIN, the map and its approach heights rest on the genuine readings (before: the
    run built its map on the error, 57 of 60 touches at the stroke's end)."""
    plan, state, why, rows = _first_touch_misread_run()
    flags = [r.flags for r in rows[:3]]
    assert "gated" in flags[1] and "surprise" in flags[2]  # the scenario as it happened
    assert state.fused_weights[0] == sv.W_MIN and np.all(state.fused_weights[1:] > 0.5)
    assert not any("stroke_end" in r.flags for r in rows) and why == "mean_std_bound"
    # the map at the first place is the genuine surface, not the error
    x0, y0 = rows[0].x_mm, rows[0].y_mm
    m, _ = bl.predict(state.belief, plan.model.surface.basis(np.array([x0]), np.array([y0])))
    genuine = rows[0].reading_mm - 1.4 - plan.zero_mm + rows[0].z_mm
    assert abs(float(m[0]) - genuine) < 0.03


def test_a_replay_condemns_the_same_first_reading(tmp_path):
    """The decision is a function of the recording: a replay (resume, report) makes it."""
    import csv

    from adaptive_cal.formats.recording import read_recording

    plan, state, _, rows = _first_touch_misread_run()
    path = tmp_path / "recording.csv"
    with path.open("w", newline="") as f:
        f.write("# adaptive-cal recording v1\n")
        w = csv.writer(f)
        w.writerow(["seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm", "flags"])
        for r in rows:
            w.writerow([r.seq, r.t_s, r.x_mm, r.y_mm, r.z_mm, r.reading_mm, ";".join(r.flags)])
    again = sv.replay(plan, sv.start(plan), read_recording(path))
    assert again.fused_weights[0] == sv.W_MIN
    assert np.allclose(again.fused_weights, state.fused_weights)


def test_condemned_judges_worst_first_against_a_batch_posterior():
    """Two fused readings 7 mm apart that disagree by 1.4 mm, and a gated reading confirmed at
    the second's place as evidence: the first is condemned (its p from the batch posterior of
    the other two, computed densely here), the second kept -- judged all at once, each would
    look wrong against a predictive that averages the other two."""
    from adaptive_cal.planning.robust import condemned

    cell = sim_cell(plan={"candidates": 2000})
    plan = survey_plan(cell)
    h0 = plan.model.hyper0
    prior, r = plan.model.belief(h0), h0.noise_std_mm**2
    rows = plan.model.surface.basis(np.array([43.0, 43.0]), np.array([0.0, 7.3]))
    ev = plan.model.surface.basis(np.array([43.0]), np.array([7.3]))
    heights, ev_h = np.array([1.4, 0.002]), np.array([0.0])
    stroke = plan.usable_mm[1] - plan.usable_mm[0]
    w = condemned(prior, rows, heights, np.ones(2), r, ev, ev_h, stroke)
    post = bl.condition(prior, np.vstack([rows[1:], ev]), np.r_[heights[1], ev_h], r)
    m, v = bl.predict(post, rows[:1])
    p = outlier_probability(Predictive.gaussian(float(m[0]), float(v[0]) + r), 1.4, stroke)
    assert w[0] == pytest.approx(max(1.0 - p, sv.W_MIN), abs=1e-12) and w[1] == 1.0


def test_a_genuine_reading_condemned_early_is_raised_and_a_gross_error_is_not():
    """Weights judged at each refit are raised too where the reading was weighted out: a genuine
    reading a retake's ``confirmed_against`` had set to ``W_MIN`` before the first refit (an
    audit: two genuine readings beside a 0.2 mm error held at 0 for the whole run) takes
    weight 1 again; a 128 um error held out stays out; a reading still in (w > 0.5) whose gate
    flag lowered it is not raised (the noise it inflated may hide it: ``unmask``)."""
    plan, clean = _state(0.0)
    assert np.all(clean.fused_weights == 1.0)
    condemned = replace(clean, weights=np.where(np.arange(40) == 5, W_MIN, 1.0))
    assert np.all(sv.refit(plan, condemned).fused_weights == 1.0)
    kept_in = replace(clean, weights=np.where(np.arange(40) == 5, 0.8, 1.0))
    assert sv.refit(plan, kept_in).fused_weights[5] == 0.8
    plan, bad = _state(128.0)
    out = replace(bad, weights=np.where(np.arange(40) == 2, W_MIN, 1.0))
    assert sv.refit(plan, out).fused_weights[2] < 0.05
