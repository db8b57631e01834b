"""Readings can be wrong: invalid readings refused (library and loop), the outlier mixture's
oracles (a spike does not drag the map, clean readings fuse as the Gaussian update, the
false-outlier rate), replay from the flags, and no retake of a genuine reading in the README run."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import adaptive_cal
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.formats.recording import read_recording, surface_height_mm
from adaptive_cal.formats.writing import RecordingWriter
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning import gate, survey as sv
from adaptive_cal.planning.robust import InvalidReading

sys.path.insert(0, str(Path(__file__).parent))
from helpers import sim_cell  # noqa: E402


@pytest.fixture(scope="module")
def plan():
    adaptive_cal.use_float64()
    return survey_plan(sim_cell())


def _learned_state(plan, n=24, seed=0, noise_mm=0.005):
    """A state after n fused readings of a plate drawn from the prior (no refits: fixed hyper)."""
    rng = np.random.default_rng(seed)
    truth = bl.sample(plan.model.belief(plan.model.hyper0), rng, 1)[0]
    state = sv.start(plan)
    idx = rng.choice(len(plan.candidates.xy_mm), n, replace=False)
    xy = plan.candidates.xy_mm[idx]
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    heights = rows @ truth + noise_mm * rng.standard_normal(n)
    from dataclasses import replace
    state = replace(state, rows=rows, heights_mm=heights, weights=np.ones(n),
                    belief=bl.condition(state.belief, rows, heights, state.noise_var),
                    hyper_points=((state.hyper, 1.0),), fitted_at=n)
    return state, truth, rng


def test_invalid_readings_are_refused_naming_the_value_and_change_nothing(plan):
    state, _, _ = _learned_state(plan)
    x, y = plan.candidates.xy_mm[0]
    cases = [((x, y, 0.0, math.nan), "reading_mm = nan"),
             ((x, y, 0.0, math.inf), "reading_mm = inf"),
             ((math.nan, y, 0.0, 5.0), "x_mm = nan"),
             ((900.0, y, 0.0, 5.0), "x_mm = 900"),
             ((-15.0, 85.0, 0.0, 5.0), "keep-out")]
    for args, text in cases:
        with pytest.raises(InvalidReading, match=text):
            sv.tell(plan, state, *args)
    assert issubclass(adaptive_cal.InvalidReading, ValueError)
    # a point in the edge margin is on the plate: accepted
    _, told = sv.tell(plan, state, -222.0, 0.0, 0.0, 5.0 + state.belief.mean[0] * 0)
    assert told is not None


def test_a_reading_that_is_not_a_number_is_refused_naming_it(plan):
    """A notebook's tell("5.0") or tell(None): a TypeError naming the key (it was Python's
    "must be real number, not str"); numpy and JAX scalars are numbers and are taken."""
    import jax.numpy as jnp

    state, _, _ = _learned_state(plan)
    x, y = plan.candidates.xy_mm[0]
    for bad, shown in (("5.0", "'5.0'"), (None, "None"), ([5.0], r"\[5.0\]"),
                       (np.array([5.0]), r"array\(\[5.\]\)")):
        with pytest.raises(TypeError, match=f"reading_mm = {shown} is not a number"):
            sv.tell(plan, state, x, y, 0.0, bad)
    with pytest.raises(TypeError, match="z_mm = 'a' is not a number"):
        sv.tell(plan, state, x, y, "a", 5.0)
    for good in (np.float32(5.0), np.int64(5), np.array(5.0), jnp.asarray(5.0)):
        assert sv.tell(plan, state, x, y, 0.0, good)[1] is not None


def test_nan_reading_leaves_the_belief_bit_identical(plan):
    state, _, _ = _learned_state(plan)
    mean, cov = state.belief.mean.copy(), state.belief.cov.copy()
    with pytest.raises(InvalidReading):
        sv.tell(plan, state, 0.0, 0.0, 0.0, math.nan)
    assert np.array_equal(state.belief.mean, mean) and np.array_equal(state.belief.cov, cov)
    assert state.fused == 24 and sv.stop_reason(plan, state) is None


def test_a_20_sigma_spike_does_not_drag_the_map(plan):
    state, truth, rng = _learned_state(plan)
    noise = 0.005
    x, y = plan.candidates.xy_mm[rng.integers(len(plan.candidates.xy_mm))]
    h = plan.model.surface.basis(np.array([x]), np.array([y]))[0]
    reading = float(h @ truth) + 20 * noise - 0.0 + plan.zero_mm  # z = 0
    new, told = sv.tell(plan, state, x, y, 0.0, reading)
    assert "gated" in told.flags and told.flags[-1].startswith("outlier=")
    moved = abs(float(h @ (new.belief.mean - state.belief.mean)))
    assert moved < noise  # batch posterior without the spike = the state's own belief
    # the retake of a genuine reading at that point is fused, the spike never is
    new2, told2 = sv.tell(plan, new, x, y, 0.0, float(h @ truth) + plan.zero_mm)
    assert told2.fused and "surprise" not in told2.flags and new2.fused == state.fused + 1
    batch = bl.condition(state.belief, h[None], [float(h @ truth)], state.noise_var)
    assert abs(float(h @ (new2.belief.mean - batch.mean))) < 1e-9


def test_robust_weight_bounds_the_pull_of_a_flagged_reading():
    # a Gaussian belief, readings at growing distances: the robust update's pull is (1 - p)
    # times at most the Gaussian one and vanishes for a gross error
    b = bl.Belief(np.zeros(1), np.eye(1) * 1e-4)
    row, r = np.ones(1), 2.5e-5
    for d in (0.5, 3.0, 4.2, 20.0):
        y = d * math.sqrt(1e-4 + r)
        pred = gate.Predictive.gaussian(0.0, 1e-4 + r)
        p = gate.outlier_probability(pred, y, 9.0)
        robust, _ = bl.fuse(b, row, y, r / max(1 - p, 1e-300))
        plain, _ = bl.fuse(b, row, y, r)
        assert abs(robust.mean[0]) <= abs(plain.mean[0]) + 1e-15
        if d >= 20:
            assert p > 0.999 and abs(robust.mean[0]) < 1e-3 * abs(plain.mean[0])


def test_clean_gaussian_readings_fuse_as_the_gaussian_update_monte_carlo(plan):
    """On clean readings (drawn from the predictive itself) the robust judgement fuses with
    weight 1 -- the exact Gaussian update -- except for flagged ones, at a rate bounded by
    P(|z| > 3.8) ~ 1.4e-4 (p >= 0.05 needs |z| >= 3.8 at predictive std <= 20 um and a 9 mm
    stroke); bound asserted: <= eps / 10 = 1e-3 over 20,000 draws."""
    rng = np.random.default_rng(3)
    flagged, gated = 0, 0
    n = 20000
    for sd in (0.005, 0.01, 0.02):
        pred = gate.Predictive.gaussian(0.0, sd**2)
        z = rng.standard_normal(n)
        for y in sd * z[:: 1 if sd == 0.005 else 3]:
            told = gate.judge(pred, y, 2.5e-5, 4.0, None, 0, 0, 0, stroke_mm=9.0)
            flagged += told.outlier_p > 0
            gated += not told.fused
    total = n + 2 * len(range(0, n, 3))
    assert flagged / total <= 1e-3 and gated / total <= 1e-3


def test_flags_round_trip_and_replay_reproduces_the_weights(plan, tmp_path):
    state, truth, rng = _learned_state(plan, n=6)
    path = tmp_path / "rec.csv"
    with RecordingWriter(path) as w:
        for i, (row_xy, flags) in enumerate(zip(plan.candidates.xy_mm[:3],
                                                [(), ("outlier=0.20",), ("gated", "outlier=1.00")])):
            h = plan.model.surface.basis(row_xy[:1], row_xy[1:])[0]
            w.append(seq=i, t_s=0.0, x_mm=row_xy[0], y_mm=row_xy[1], z_mm=0.0,
                     reading_mm=float(h @ truth) + plan.zero_mm, flags=flags)
    rec = read_recording(path)
    assert gate.flagged_p(rec.flags[1]) == 0.2
    fresh = sv.replay(plan, sv.start(plan), rec)
    assert fresh.fused == 2 and np.allclose(fresh.weights, [1.0, 0.8])
    rows = plan.model.surface.basis(rec.x_mm[:2], rec.y_mm[:2])
    heights = surface_height_mm(rec.reading_mm[:2], 0.0, plan.zero_mm)
    ref = bl.condition(sv.start(plan).belief, rows, heights, fresh.noise_var / np.array([1, 0.8]))
    assert np.allclose(fresh.belief.mean, ref.mean, atol=1e-12)
    assert fresh.retake is not None  # the last row was gated


class _BadProbe:
    """Wraps a probe cycle: touch k returns NaN, touch j a position off the plate."""

    def __init__(self, cycle, nan_at=(), off_at=()):
        self.cycle, self.motion, self.clock = cycle, cycle.motion, cycle.clock
        self.nan_at, self.off_at, self.k = set(nan_at), set(off_at), 0

    def touch(self, x, y, z, plate_top=None):
        from dataclasses import replace
        t = self.cycle.touch(x, y, z, plate_top)
        k, self.k = self.k, self.k + 1
        if k in self.nan_at:
            return replace(t, reading_mm=math.nan)
        if k in self.off_at:
            return replace(t, x_mm=900.0)
        return t


def test_the_loop_records_invalid_readings_counts_them_and_goes_on(plan, tmp_path):
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.run.loop import INVALID_READINGS, run_loop
    opened = open_cell(sim_cell())
    rows = []
    probe = _BadProbe(opened.cycle, nan_at=(2,), off_at=(4,))
    state, why = run_loop(plan, sv.start(plan), probe, record=rows.append,
                          stop=lambda s, st: "limit" if s.touches >= 8 else None)
    assert why == "limit" and state.touches == 8 and len(rows) == 8
    assert set(rows[2].flags) == {"invalid", "rejected", "nonfinite"} and rows[2].reading_mm == 0.0
    assert set(rows[4].flags) == {"invalid", "rejected"} and rows[4].x_mm == 900.0
    assert state.fused == 6 and np.all(np.isfinite(state.belief.mean))
    # written, read back and replayed: the invalid rows are never fused
    path = tmp_path / "rec.csv"
    with RecordingWriter(path) as w:
        for r in rows:
            w.append(seq=r.seq, t_s=r.t_s, x_mm=r.x_mm, y_mm=r.y_mm, z_mm=r.z_mm,
                     reading_mm=r.reading_mm, flags=r.flags)
    assert sv.replay(plan, sv.start(plan), read_recording(path)).fused == 6
    # a device that only returns NaN: the loop stops with a clear reason
    probe = _BadProbe(opened.cycle, nan_at=range(100))
    state, why = run_loop(plan, sv.start(plan), probe, record=rows.append)
    assert why == INVALID_READINGS and state.touches == 3 and state.fused == 0
    opened.close()


def test_readme_run_retakes_no_genuine_reading_on_its_first_10_touches(plan):
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.run.loop import run_loop
    opened = open_cell(sim_cell())
    rows = []
    state, _ = run_loop(plan, sv.start(plan), opened.cycle, record=rows.append,
                        stop=lambda s, st: "limit" if s.touches >= 10 else None)
    opened.close()
    assert len(rows) == 10 and sum("gated" in r.flags for r in rows) == 0


def test_a_mixture_component_of_weight_zero_adds_nothing_and_warns_nothing():
    """A hyper-parameter point whose weight underflowed to 0 (a 1 mm bow run printed 'divide
    by zero encountered in log' to the user): the density is the other components' alone."""
    import warnings

    from adaptive_cal.planning.gate import Predictive

    with_zero = Predictive(np.array([0.0, 0.3]), np.array([1e-4, 1e-4]), np.array([1.0, 0.0]))
    alone = Predictive.gaussian(0.0, 1e-4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert with_zero.log_density(0.01) == pytest.approx(alone.log_density(0.01), rel=1e-12)


def test_a_reading_outside_the_usable_stroke_is_refused_even_twice(plan):
    """A reading the probe cannot give (5000 mm on a 10 mm stroke: um for mm; 0.0057: m for
    mm) was gated, and its retake -- the same value again, as a unit mistake repeats itself --
    was fused as a 'surprise': the map went 4994 mm off. Now refused naming the value and the
    stroke, nothing changed, as a probe cycle rejects it."""
    state, _, _ = _learned_state(plan)
    x, y = plan.candidates.xy_mm[0]
    lo, hi = plan.usable_mm
    for bad in (5000.0, hi + 1e-6, lo - 1e-6, 0.0057 if lo > 0.0057 else -1.0):
        for _ in range(2):
            with pytest.raises(InvalidReading, match=f"reading_mm = {bad:g} is outside the "
                                                     f"probe's usable stroke"):
                sv.tell(plan, state, x, y, 0.0, bad)
    assert sv.tell(plan, state, x, y, 0.0, lo)[1] is not None  # the ends are inside


def test_only_a_touch_at_the_gated_point_is_its_retake(plan):
    """A retake is owed at the gated reading's point. A reading told elsewhere before it (a
    batch told in order, a retake not taken) was taken as the retake: 0.5 mm off at a point
    150 mm away was fused at full weight as a 'surprise'. Now it is judged as a new reading
    (gated here) and the retake stays owed at its point; the retake there is then judged as one."""
    state, truth, rng = _learned_state(plan)
    xy = plan.candidates.xy_mm
    (x, y), (x2, y2) = xy[0], xy[np.argmax(np.hypot(*(xy - xy[0]).T))]

    def reading(px, py, off=0.0):
        h = plan.model.surface.basis(np.array([px]), np.array([py]))[0]
        return float(h @ truth) + off + plan.zero_mm

    s1, t1 = sv.tell(plan, state, x, y, 0.0, reading(x, y, 0.5))
    assert "gated" in t1.flags and s1.retake is not None
    s2, t2 = sv.tell(plan, s1, x2, y2, 0.0, reading(x2, y2, 0.5))
    assert not t2.fused and "retake" not in t2.flags and "surprise" not in t2.flags
    # a genuine reading elsewhere is fused as a new one; the retake is still owed at (x, y)
    s3, t3 = sv.tell(plan, s1, x2, y2, 0.0, reading(x2, y2))
    assert t3.fused and "retake" not in t3.flags
    assert s3.retake is not None and s3.retake.at(x, y)
    # and the retake at its point settles it
    s4, t4 = sv.tell(plan, s3, x, y, 0.0, reading(x, y))
    assert "retake" in t4.flags and t4.fused and s4.retake is None
