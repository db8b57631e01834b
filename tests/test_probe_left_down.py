"""A stop that leaves the probe down says so first, and keeps what was read (issue 16, item 5)."""
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.hardware.base import AdapterError, ProbeLeftDown
from adaptive_cal.planning import survey as sv
from adaptive_cal.run.devices import open_cell
from adaptive_cal.run.loop import SurveyLoop
from tests.helpers import SIM_CELL, sim_cell


class RetractFailsOnce:
    """The simulated cell's motion, whose n-th move fails (a PLC that stalls)."""

    def __init__(self, motion, fail_on):
        self.motion, self.fail_on, self.moves = motion, fail_on, 0

    def move_to(self, x, y, z):
        self.moves += 1
        if self.moves == self.fail_on:
            raise AdapterError("PLC did not answer")
        self.motion.move_to(x, y, z)

    def position(self):
        return self.motion.position()

    def close(self):
        self.motion.close()


def test_a_failed_retract_after_a_good_reading_stops_with_the_warning_first_and_keeps_the_row():
    cell = sim_cell()
    plan = survey_plan(cell)
    opened = open_cell(cell)
    opened.cycle.motion = RetractFailsOnce(opened.cycle.motion, fail_on=3)  # travel, approach, retract
    rows = []
    loop = SurveyLoop(plan, sv.start(plan), opened.cycle, record=rows.append)
    with pytest.raises(ProbeLeftDown) as e:
        loop.run()
    message = str(e.value)
    assert message.startswith("THE PROBE MAY BE DOWN at x=")
    assert "jog the probe clear" in message and "was taken and is kept" in message
    # the reading taken before the retract failed is in the recording and in the state
    assert len(rows) == 1 and rows[0].reading_mm == pytest.approx(e.value.touch.reading_mm)
    assert loop.state.touches == 1 and len(loop.state.heights_mm) == 1
    opened.close()


def test_the_cli_prints_the_warning_first(tmp_path, monkeypatch, capsys):
    from adaptive_cal.cli import main
    from adaptive_cal.hardware import cycle as base

    real = base.ProbeCycle.touch

    calls = []

    def touch(self, x, y, z, plate_top=None):  # the second touch's retract fails
        calls.append((x, y, z))
        if len(calls) == 2:
            self.motion = RetractFailsOnce(self.motion, fail_on=3)
        return real(self, x, y, z, plate_top)

    monkeypatch.setattr(base.ProbeCycle, "touch", touch)
    code = main(["run", "--robot", str(SIM_CELL), "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("adaptive-cal run: error: THE PROBE MAY BE DOWN")
    # nothing taken is lost: both readings are in the recording
    rows = [line for line in (tmp_path / "run" / "recording.csv").read_text().splitlines()
            if line and not line.startswith("#")]
    assert len(rows) == 1 + 2


def test_a_touch_that_begins_below_the_safe_height_and_cannot_lift_says_the_probe_may_be_down():
    """A touch that begins with the tip below the safe height (an earlier stop, a resume) lifts
    first; when that lift fails the tip may still be on the plate: the warning comes first, at
    the last known position. A failure of a later move before the approach does not say so."""
    cell = sim_cell()
    opened = open_cell(cell)
    cycle = opened.cycle
    x, y = 0.0, 0.0
    low = cycle.safe_height_mm - 3.0
    cycle.motion.move_to(x, y, low)  # left low by an earlier stop
    cycle.motion = RetractFailsOnce(cycle.motion, fail_on=1)
    with pytest.raises(ProbeLeftDown) as e:
        cycle.touch(50.0, 40.0, 0.0)
    text = str(e.value)
    assert text.startswith(f"THE PROBE MAY BE DOWN at x={x:.3f} y={y:.3f} mm (last known z="
                           f"{low:.3f} mm)")
    assert "below the safe height when this touch began" in text
    # from the safe height, a failed travel is the adapter's error, not a probe-down warning
    cycle.motion = RetractFailsOnce(cycle.motion.motion, fail_on=99)
    cycle.motion.move_to(x, y, cycle.safe_height_mm)
    cycle.motion.fail_on = cycle.motion.moves + 1
    with pytest.raises(AdapterError) as e:
        cycle.touch(50.0, 40.0, 0.0)
    assert not isinstance(e.value, ProbeLeftDown)
    opened.close()


def test_a_ctrl_c_during_the_retract_says_the_probe_may_be_down_first_and_exits_130(
        monkeypatch, tmp_path, capsys):
    """A second Ctrl-C raises KeyboardInterrupt at once; landing in the retract it bypassed the
    warning (the handler caught Exception only): the run said 'interrupted' with the probe at
    z -0.8 mm. Now the warning comes first, and the CLI exits 130 (an interrupt, not bad
    input)."""
    from adaptive_cal.cli import main
    from adaptive_cal.hardware import cycle as base

    class CtrlCOnRetract(RetractFailsOnce):
        def move_to(self, x, y, z):
            self.moves += 1
            if self.moves == self.fail_on:
                raise KeyboardInterrupt
            self.motion.move_to(x, y, z)

    cell = sim_cell()
    opened = open_cell(cell)
    opened.cycle.motion = CtrlCOnRetract(opened.cycle.motion, fail_on=3)
    with pytest.raises(ProbeLeftDown) as e:
        opened.cycle.touch(50.0, 40.0, 0.0)
    assert str(e.value).startswith("THE PROBE MAY BE DOWN at x=50.000 y=40.000 mm")
    assert "failed (interrupted: Ctrl-C)" in str(e.value) and e.value.interrupted
    opened.close()

    real, calls = base.ProbeCycle.touch, []

    def touch(self, x, y, z, plate_top=None):  # the second touch's retract is interrupted
        calls.append((x, y, z))
        if len(calls) == 2:
            self.motion = CtrlCOnRetract(self.motion, fail_on=3)
        return real(self, x, y, z, plate_top)

    monkeypatch.setattr(base.ProbeCycle, "touch", touch)
    code = main(["run", "--robot", str(SIM_CELL), "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130
    assert err.startswith("adaptive-cal run: error: THE PROBE MAY BE DOWN")
