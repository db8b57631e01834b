"""The library's ask/tell (``Survey.tell``) and a frozen readout: the same reading touch after
touch (a stale serial value, a register not updated, a value typed again) was fused every time,
and the learned noise collapsed onto the repeats -- the run's probe cycle already rejected them
(tests/test_probe_cycle.py). Now the survey rejects them the same way, from the cell's readout
step and stated noise."""
import warnings

import numpy as np
import pytest

import adaptive_cal
from adaptive_cal.cell.build import readout_frozen_after
from adaptive_cal.hardware.base import frozen_after

from helpers import ROOT


def _survey(**probe):
    adaptive_cal.use_float64()
    cell = adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml")
    cell = cell.model_copy(update={"probe": cell.probe.model_copy(update=probe)})
    return adaptive_cal.start_survey(cell)


def _plate(x, y):
    return 5.0 + 0.001 * x - 0.0005 * y


def test_a_frozen_readout_is_rejected_not_fused_and_ends_the_survey():
    survey = _survey()
    k = survey.plan.frozen_after
    assert k == readout_frozen_after(
        adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml")) == frozen_after(1e-4, 0.005, 120) == 4
    rng = np.random.default_rng(0)
    for _ in range(6):  # live readings first
        t = survey.ask(1)[0]
        survey.tell(t.x_mm, t.y_mm, t.z_mm, _plate(t.x_mm, t.y_mm) + rng.normal(0, 0.005))
    fused = survey.state.fused
    stuck = round(_plate(0, 0), 4)
    flags = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(k - 1 + 3):
            t = survey.ask(1)[0]
            flags.append(survey.tell(t.x_mm, t.y_mm, t.z_mm, stuck).flags)
    # the first k - 1 repeats are fused (they cannot be told from a live probe yet), the rest not
    assert all("frozen" not in f for f in flags[:k - 1])
    assert all(f[:2] == ("rejected", "frozen") for f in flags[k - 1:])
    assert survey.state.fused == fused + k - 1
    assert survey.touches == 6 + k - 1 + 3
    assert sum("frozen" in str(w.message) for w in caught) == 3
    assert survey.stop_reason() == "readout_frozen"
    # a live reading again: fused, the count of frozen touches starts over
    t = survey.ask(1)[0]
    told = survey.tell(t.x_mm, t.y_mm, t.z_mm, _plate(t.x_mm, t.y_mm) + 0.003)
    assert told.fused and survey.stop_reason() != "readout_frozen"


def test_no_check_where_the_readout_is_as_coarse_as_the_noise_and_bad_readings_still_named():
    # a 1 um step against 1 um of noise repeats honestly: no check, every reading fused
    survey = _survey(resolution_mm=0.001, noise_std_mm=0.001)
    assert survey.plan.frozen_after is None
    for _ in range(8):
        t = survey.ask(1)[0]
        assert survey.tell(t.x_mm, t.y_mm, t.z_mm, 5.0).fused
    # what is not a reading is refused as before, and counts as no repeat
    survey = _survey()
    t = survey.ask(1)[0]
    with pytest.raises(TypeError, match="reading_mm = True is not a number"):
        survey.tell(t.x_mm, t.y_mm, t.z_mm, True)
    assert survey.touches == 0


def test_a_restored_state_starts_the_frozen_count_and_the_history_afresh():
    """``survey.state`` may be kept and restored (shell.py): three what-if tells of one genuine
    reading, each undone, made the fourth tell 'frozen' and restoring the start state kept
    ``readout_frozen`` (an outside audit, 2026-12-01)."""
    survey = _survey()
    rng = np.random.default_rng(1)
    for _ in range(3):
        t = survey.ask(1)[0]
        survey.tell(t.x_mm, t.y_mm, t.z_mm, _plate(t.x_mm, t.y_mm) + rng.normal(0, 0.005))
    kept, t = survey.state, survey.ask(1)[0]
    reading = round(_plate(t.x_mm, t.y_mm) + 0.002, 4)
    for _ in range(survey.plan.frozen_after + 1):  # what-ifs, each undone
        assert survey.tell(t.x_mm, t.y_mm, t.z_mm, reading).fused
        survey.state = kept
    assert survey.tell(t.x_mm, t.y_mm, t.z_mm, reading).fused
    assert len(survey.history) == survey.touches + 1 == 5
    start = survey.state
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(survey.plan.frozen_after + 3):  # a frozen readout ends the survey...
            t = survey.ask(1)[0]
            survey.tell(t.x_mm, t.y_mm, t.z_mm, 5.0)
    assert survey.stop_reason() == "readout_frozen"
    survey.state = start  # ... and restoring an earlier state leaves it behind
    assert survey.stop_reason() != "readout_frozen" and len(survey.history) == 5


def test_a_retake_told_microns_from_its_point_is_the_retake():
    """A robot reports where it stood, not where it was sent: a retake told 2 um from the gated
    reading's point went unrecognised and the point was gated 99 times over (an outside audit,
    2026-12-01). Within ``gate.SAME_POINT_MM`` (0.1 mm) it is the retake."""
    survey = _survey()
    rng = np.random.default_rng(2)
    for _ in range(24):
        t = survey.ask(1)[0]
        survey.tell(t.x_mm, t.y_mm, t.z_mm, _plate(t.x_mm, t.y_mm) + rng.normal(0, 0.005))
    t = survey.ask(1)[0]
    assert "gated" in survey.tell(t.x_mm, t.y_mm, t.z_mm, _plate(t.x_mm, t.y_mm) + 0.5).flags
    r = survey.ask(1)[0]
    assert (r.x_mm, r.y_mm) == (t.x_mm, t.y_mm)  # the retake is asked for
    told = survey.tell(r.x_mm + 0.002, r.y_mm - 0.002, r.z_mm, _plate(r.x_mm, r.y_mm) + 0.001)
    assert "retake" in told.flags and not survey.retake_pending
