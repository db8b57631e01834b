"""A plate the probe cannot reach: touches the probe cycle rejects (stroke end) teach the planner
nothing, so it asked the same touch again until the budget was spent -- 120 times into a plate
6 mm above where the cell file put it -- and the run exited 0. Now three in a row end the loop,
the summary says what to check, and the exit code says "not a result"."""
import contextlib
import json
import io

import yaml

from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.hardware.base import TouchRejected
from adaptive_cal.planning import survey as sv
from adaptive_cal.run.loop import MAX_REJECTED, TOUCHES_REJECTED, run_loop

from helpers import SIM_CELL, sim_cell


class _Refusing:
    """Wraps a probe cycle: the touches numbered in ``refuse`` come back at the stroke's end."""

    def __init__(self, cycle, refuse):
        self.cycle, self.motion, self.clock = cycle, cycle.motion, cycle.clock
        self.refuse, self.k = set(refuse), 0

    def touch(self, x, y, z, plate_top=None):
        k, self.k = self.k, self.k + 1
        if k in self.refuse:
            raise TouchRejected("reading 10.0000 mm outside the usable stroke", 10.0,
                                ("rejected", "stroke_end"))
        return self.cycle.touch(x, y, z, plate_top)


def _plan_and_cell():
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.run.devices import open_cell
    cell = sim_cell()
    return survey_plan(cell), open_cell(cell)


def test_three_rejected_touches_in_a_row_end_the_loop_each_recorded_none_fused():
    plan, opened = _plan_and_cell()
    rows = []
    state, why = run_loop(plan, sv.start(plan), _Refusing(opened.cycle, range(1000)),
                          record=rows.append)
    opened.close()
    assert why == TOUCHES_REJECTED and MAX_REJECTED == 3
    assert state.touches == 3 and state.fused == 0 and len(rows) == 3
    assert all(set(r.flags) == {"rejected", "stroke_end"} for r in rows)


def test_rejections_that_are_not_in_a_row_do_not_end_the_loop():
    plan, opened = _plan_and_cell()
    rows = []
    state, why = run_loop(plan, sv.start(plan), _Refusing(opened.cycle, (1, 2, 4, 5, 7, 8)),
                          record=rows.append,
                          stop=lambda s, st: "limit" if s.touches >= 12 else None)
    opened.close()
    assert why == "limit" and state.touches == 12 and state.fused == 6


def test_a_plate_6_mm_off_nominal_stops_after_one_overrun_not_three(tmp_path):
    """The plate 6 mm above the cell file's (12 sigma of its offset prior): the first touch runs
    past the stroke's top, which no prior could foresee. It used to be sent twice more, each
    1.5 mm past the stroke's end, before 3 rejections in a row ended the run (a second outside
    safety audit, 2026-11-29); now the same approach is not sent again: the run stops there,
    saying what to check, the rejected row kept."""
    data = yaml.safe_load(SIM_CELL.read_text())
    data["simulation"]["effects"]["tilt"]["c"] = 6.0  # the plate 6 mm above the cell file's
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(data))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["run", "--robot", str(cell), "--out", str(tmp_path / "run"),
                     "--no-progress"])
    assert code == 2, err.getvalue()
    assert "would run the probe past its stroke's end again; nothing was sent" in err.getvalue()
    assert "Check the plate's height in the cell file" in err.getvalue()
    assert "INCOMPLETE" in out.getvalue() and "--resume" not in out.getvalue()
    assert "then map again in a new folder" in out.getvalue()
    rec = read_recording(tmp_path / "run" / "recording.csv")
    assert len(rec.reading_mm) == 1 and rec.flags[0] >= {"rejected", "stroke_end"}
    saved = json.loads((tmp_path / "run" / "result.json").read_text())
    assert saved["stopped_because"] == "touches_rejected" and "stroke's end" in saved["error"]
    # a --resume sends that approach no more (an outside audit: each one overran once more)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", "--resume", str(tmp_path / "run"), "--no-progress"]) == 2
    assert len(read_recording(tmp_path / "run" / "recording.csv")) == 1


def test_a_steep_plate_in_a_shallow_workspace_gets_only_approach_heights_inside_it(tmp_path):
    """The gradient refinement of a pick checked the workplane and the stroke but not the
    workspace's z range: on a plate tilted 0.08 / 0.05 mm/mm in a workspace of z -15..15 mm it
    proposed z 19.2 mm, the motion's safety check refused it (nothing was sent) and the run
    ended on an error after 7 touches (an audit, 2026-11-24); then the run went on to its budget,
    every approach height inside the box -- travelling at the safe height 15 mm over a plate
    that stands up to 27 mm there, the free tip reaching 5 mm below (a safety audit,
    2026-11-29). Now every approach height is still inside the box, and the run stops, before
    it sends a travel the plate would stand in the tip's way of, saying so and naming the keys;
    every reading taken is kept."""
    data = yaml.safe_load(SIM_CELL.read_text())
    data["simulation"]["effects"]["tilt"].update(a=0.08, b=0.05)
    data["workspace"]["z_mm"] = [-15, 15]
    data["plan"]["stop"]["max_touches"] = 25
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(data))
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["run", "--robot", str(cell), "--out", str(tmp_path / "run"),
                     "--no-progress"])
    rec = read_recording(tmp_path / "run" / "recording.csv")
    assert code == 2 and 3 <= len(rec.z_mm) < 25, err.getvalue()
    assert "would drag it over the plate" in err.getvalue()
    assert "robot.safe_height_mm" in err.getvalue() and "workspace.z_mm" in err.getvalue()
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["stopped_because"] == "interrupted" and result["touches"] == len(rec.z_mm)
    assert rec.z_mm.min() >= -15 and rec.z_mm.max() <= 15
