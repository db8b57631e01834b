"""The measurement loop end to end on the simulated cell: stopping, outputs, resume, Ctrl-C,
gating, prior-from, criteria, bad input."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.cell.schema import load_cell, load_yaml
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import ask
from adaptive_cal.run import session
from adaptive_cal.run.devices import open_cell

from helpers import SIM_CELL, drive, sim_cell


def test_no_bound_stops_before_as_many_touches_as_coefficients_unless_told():
    cell = sim_cell()
    plan = survey_plan(cell)
    k = plan.model.form_surface.size  # the cell's knots (a model that may grow plans on finer ones)
    m = drive(plan, open_cell(cell))
    assert sv.stop_reason(plan, m) == "mean_std_bound" and m.touches >= k
    # 4.5 um: at 4 um the floor-free run happens to stop at 30 = k touches since the form
    # kernels are weighed (2026-12-01; 28 at 4.5 um, 27 at 5 um)
    early = sim_cell(plan={"stop": {"mean_std_mm": 0.0045, "max_touches": 120, "min_touches": 0}})
    plan0 = survey_plan(early)
    m0 = drive(plan0, open_cell(early))
    assert sv.stop_reason(plan0, m0) == "mean_std_bound" and m0.touches < k


def test_cli_run_stops_at_the_bound_and_writes_everything(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 0
    for f in ("recording.csv", "result.json", "surface.png", "convergence.png", "belief.npz",
              "cell.yaml"):
        assert (out / f).exists(), f
    r = json.loads((out / "result.json").read_text())
    assert r["stopped_because"] == "mean_std_bound"
    assert r["posterior"]["mean_std_mm"] <= 0.004
    assert r["touches"] == len(read_recording(out / "recording.csv"))
    assert set(r["tilt"]) >= {"rx_deg", "ry_deg", "a", "b", "c"}
    for k in ("least_squares", "range", "minimum_zone"):
        lo, hi = r["flatness_mm"][k]["ci95"]
        assert lo <= hi
    assert set(r["truth"]) == {"rms_error_mm", "max_error_mm", "coverage95"}
    # the form kernels' evidence shares at the last refit, the MAP's kernel the heaviest
    weights = r["hyper"]["kernel_weights"]
    assert sum(weights.values()) == pytest.approx(1.0) and set(weights) <= {"se", "m52"}
    assert weights[r["hyper"]["kernel"]] == max(weights.values())
    # the simulated plate: tilt a = 0.0140, b = 0.0019 (configs/sim-cell.yaml)
    assert r["tilt"]["a"] == pytest.approx(0.0140, abs=5e-5)
    assert r["tilt"]["b"] == pytest.approx(0.0019, abs=5e-5)
    assert "stopped: RMS std bound met (mean_std_bound)" in capsys.readouterr().out


def test_no_reading_lands_outside_the_stroke_and_first_touches_wait_for_the_belief(tmp_path):
    cell = sim_cell()
    plan = survey_plan(cell)
    m = sv.start(plan)
    t0 = ask(plan, m)[0]
    assert t0.predicted_std_mm * 4.89 <= 4.5  # the first touch is one the stroke can promise
    drive(plan, open_cell(cell), state=m)
    rec_dir = tmp_path / "r"
    session.run(cell, rec_dir, progress=False)
    rec = read_recording(rec_dir / "recording.csv")
    assert np.all((rec.reading_mm > 0.5) & (rec.reading_mm < 9.5))


def test_no_point_can_be_promised_gives_a_clear_error(tmp_path):
    cell = sim_cell(model={"offset_std_mm": 5.0})
    with pytest.raises(session.NoAdmissiblePoint, match="usable probe stroke"):
        session.run(cell, tmp_path / "x", progress=False)
    # refused before the devices are opened and the recording is begun
    assert not (tmp_path / "x" / "recording.csv").exists()


def test_interrupted_run_resumes_without_repeating_or_losing_a_touch(tmp_path):
    cell = sim_cell()
    out = tmp_path / "run"
    r1 = session.run(cell, out, progress=False, max_new_touches=7)
    assert r1["stopped_because"] == "interrupted" and r1["touches"] == 7
    first = (out / "recording.csv").read_text().splitlines()
    r2 = session.run(cell, out, resume=True, progress=False)
    assert r2["stopped_because"] == "mean_std_bound"
    lines = (out / "recording.csv").read_text().splitlines()
    assert lines[: len(first)] == first  # nothing rewritten
    rec = read_recording(out / "recording.csv")
    # what DESIGN.md does not say about the flags column, said in the file for any reader
    assert f"# flags: {session.FLAGS_META}" in lines[:5] and rec.meta["flags"] == session.FLAGS_META
    assert "gated, rejected or invalid is not a reading of the plate" in session.FLAGS_META
    np.testing.assert_array_equal(rec.seq, np.arange(len(rec)))
    assert r2["touches"] == len(rec) > 7
    # the closure after a resume: the first place again, timed from the recording's first row
    c = r2["closure"]
    assert c["made"] and c["passed"] and set(rec.flags[-1]) == {"closure"}
    assert c["elapsed_s"] == pytest.approx(rec.t_s[-1] - rec.t_s[c["first_touch"]], abs=2e-3)
    assert (rec.x_mm[-1], rec.y_mm[-1]) == pytest.approx((rec.x_mm[c["first_touch"]],
                                                         rec.y_mm[c["first_touch"]]), abs=1e-3)
    with pytest.raises(FileExistsError, match="--resume"):
        session.run(cell, out, progress=False)


@pytest.mark.slow
def test_ctrl_c_leaves_a_recording_that_resume_continues(tmp_path):
    cell_file = tmp_path / "cell.yaml"
    data = load_yaml(SIM_CELL)
    data["plan"] = {"stop": {"mean_std_mm": 0.0005, "max_touches": 400}}
    import yaml
    cell_file.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot",
                             str(cell_file), "--out", str(out), "--no-progress"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    rec = out / "recording.csv"
    deadline = time.time() + 120
    while time.time() < deadline:
        # 8 rows written (8 header lines): n >= 8 below however soon the loop stops after it
        if rec.exists() and len(rec.read_text().splitlines()) >= 16:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    assert proc.returncode == 130, proc.stderr.read().decode()
    result = json.loads((out / "result.json").read_text())
    assert result["stopped_because"] == "interrupted"
    n = len(read_recording(rec))
    assert result["touches"] == n >= 8
    data["plan"]["stop"]["mean_std_mm"] = 0.004  # reachable: the resumed run finishes
    cell_file.write_text(yaml.safe_dump(data))
    assert main(["run", "--resume", str(out), "--robot", str(cell_file), "--no-progress"]) == 0
    rec2 = read_recording(rec)
    np.testing.assert_array_equal(rec2.seq, np.arange(len(rec2)))
    assert len(rec2) >= n


class _OutlierCycle:
    """Wraps a probe cycle and adds +0.3 mm to one chosen touch (a chip under the probe)."""

    def __init__(self, cycle, bad):
        self.cycle, self.bad, self.count = cycle, bad, 0
        self.motion = cycle.motion

    def touch(self, x, y, z, plate_top=None):
        t = self.cycle.touch(x, y, z, plate_top)
        self.count += 1
        if self.count == self.bad:
            from dataclasses import replace
            return replace(t, reading_mm=t.reading_mm + 0.3)
        return t


def test_an_outlier_is_gated_retaken_and_both_rows_kept(tmp_path, monkeypatch):
    real_open = session.open_cell

    def fake_open(cell, **kw):
        oc = real_open(cell, **kw)
        oc.cycle = _OutlierCycle(oc.cycle, bad=10)
        return oc

    monkeypatch.setattr(session, "open_cell", fake_open)
    result = session.run(sim_cell(), tmp_path / "g", progress=False)
    rec = read_recording(tmp_path / "g" / "recording.csv")
    assert "gated" in rec.flags[9] and "retake" in rec.flags[10]
    assert rec.x_mm[9] == rec.x_mm[10] and rec.y_mm[9] == rec.y_mm[10]
    assert not rec.fused[9] and rec.fused[10]
    assert result["fused"] == int(rec.fused.sum())
    assert result["truth"]["max_error_mm"] < 0.05  # the 0.3 mm chip did not enter the map


def _failing_at(monkeypatch, touch: int, error: Exception):
    """The sim cell's touch number ``touch`` raises ``error`` (a device that fails mid-run);
    returns the real ``open_cell`` to put back."""
    real_open = session.open_cell

    class _Fails:
        def __init__(self, cycle):
            self.cycle, self.motion, self.count = cycle, cycle.motion, 0

        def touch(self, x, y, z, plate_top=None):
            self.count += 1
            if self.count == touch:
                raise error
            return self.cycle.touch(x, y, z, plate_top)

    monkeypatch.setattr(session, "open_cell",
                        lambda cell, **kw: setattr(oc := real_open(cell, **kw), "cycle",
                                                   _Fails(oc.cycle)) or oc)
    return real_open


def test_a_device_failure_keeps_every_reading_reports_and_resumes(tmp_path, monkeypatch):
    from adaptive_cal.hardware.base import AdapterError

    real_open = _failing_at(monkeypatch, 6, AdapterError("link lost: jog the probe clear and "
                                                         "--resume"))
    out = tmp_path / "d"
    with pytest.raises(AdapterError, match="link lost"):
        session.run(sim_cell(), out, progress=False)
    assert len(read_recording(out / "recording.csv")) == 5  # every reading taken is kept
    result = json.loads((out / "result.json").read_text())
    assert result["stopped_because"] == "interrupted" and result["touches"] == 5
    monkeypatch.setattr(session, "open_cell", real_open)
    r = session.run(sim_cell(), out, resume=True, progress=False)
    assert r["stopped_because"] == "mean_std_bound"
    rec = read_recording(out / "recording.csv")
    np.testing.assert_array_equal(rec.seq, np.arange(len(rec)))


def test_a_device_failure_mid_run_prints_the_incomplete_summary_then_the_error(tmp_path,
                                                                              monkeypatch, capsys):
    from adaptive_cal.hardware.base import AdapterError

    _failing_at(monkeypatch, 4, AdapterError("link lost: reconnect, then continue with --resume"))
    out = tmp_path / "d"
    assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 2
    said = capsys.readouterr()
    # the three touches made are shown as what they are -- not a result -- and where they are
    assert said.out.startswith("INCOMPLETE: interrupted after 3 touches")
    assert "stopped: interrupted after 3 touches" in said.out and f"--resume {out}" in said.out
    assert "link lost" in said.err and "link lost" not in said.out
    assert len(read_recording(out / "recording.csv")) == 3
    assert "link lost" in json.loads((out / "result.json").read_text())["error"]


def test_a_probe_left_down_mid_run_is_said_before_the_summary(tmp_path, monkeypatch, capsys):
    from adaptive_cal.hardware.base import ProbeLeftDown

    _failing_at(monkeypatch, 4, ProbeLeftDown("THE PROBE MAY BE DOWN at x=1.000 y=2.000 mm: "
                                              "jog it clear"))
    out = tmp_path / "d"
    lines = []  # stdout and stderr in the order they were written
    monkeypatch.setattr(sys, "stdout", type("W", (), {"write": lambda s, t: lines.append(
        ("out", t)), "flush": lambda s: None, "isatty": lambda s: False})())
    monkeypatch.setattr(sys, "stderr", type("W", (), {"write": lambda s, t: lines.append(
        ("err", t)), "flush": lambda s: None, "isatty": lambda s: False})())
    assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 2
    said = [(w, t) for w, t in lines if t.strip()]
    first = next(i for i, (_, t) in enumerate(said) if "PROBE MAY BE DOWN" in t)
    summary = next(i for i, (_, t) in enumerate(said) if t.startswith("INCOMPLETE"))
    assert said[first][0] == "err" and first < summary  # the danger first, then the summary
    assert sum("PROBE MAY BE DOWN" in t for _, t in said) == 1  # said once


def test_a_frozen_readout_stops_the_run_with_its_name_and_the_repeats_not_fused(tmp_path,
                                                                               monkeypatch, capsys):
    import dataclasses

    real_open = session.open_cell

    class _Freezes:  # the simulated probe, its readout stuck at the 8th reading's value
        def __init__(self, probe):
            self.probe, self.n, self.last = probe, 0, None

        def read(self):
            self.n += 1
            if self.last is None or self.n < 9:
                self.last = self.probe.read()
            return self.last

    def frozen_open(cell, **kw):
        oc = real_open(cell, **kw)
        oc.cycle = dataclasses.replace(oc.cycle, probe=_Freezes(oc.cycle.probe), frozen_after=4)
        return oc

    monkeypatch.setattr(session, "open_cell", frozen_open)
    out = tmp_path / "f"
    assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 1
    said = capsys.readouterr().out
    assert said.startswith("INCOMPLETE: stopped: the probe read the very same value")
    assert "stopped: readout frozen after 13 touches (10 fused)" in said
    rec = read_recording(out / "recording.csv")
    # the 8th reading and its first two repeats were fused (nothing was seen yet); the next
    # three are kept, flagged and not fused
    assert [set(f) for f in rec.flags[-3:]] == [{"rejected", "frozen"}] * 3
    assert not any(rec.flags[:10])
    assert len(set(rec.reading_mm[7:])) == 1 and len(set(rec.reading_mm[:8])) == 8


def test_prior_from_an_earlier_run_needs_only_a_handful_of_touches(tmp_path):
    cell = sim_cell()
    fresh = session.run(cell, tmp_path / "a", progress=False)
    again = sim_cell(simulation={"seed": 5})
    # the frame was not corrected in between (after a correction: tests/test_recheck.py)
    r = session.run(again, tmp_path / "b", prior_from=tmp_path / "a", correction_applied="none",
                    progress=False)
    assert r["stopped_because"] == "mean_std_bound"
    # 12: 10 before the form kernels were weighed (tests/test_recheck.py says why)
    assert r["touches"] <= 12 and r["touches"] < 0.5 * fresh["touches"]
    assert r["truth"]["rms_error_mm"] < 0.006


def test_worst_point_criterion_beats_integrated_variance_on_a_max_bound():
    touches = {}
    for crit in ("max", "integrated"):
        cell = sim_cell(model={"knots_x": 8, "knots_y": 8, "learn_hyper": False},
                        plan={"stop": {"mean_std_mm": None, "max_std_mm": 0.006, "max_touches": 300,
                                       "min_touches": 0},  # compare the criteria, not the guard
                              "criterion": crit, "candidates": 4000})
        plan = survey_plan(cell)
        m = drive(plan, open_cell(cell))
        assert sv.stop_reason(plan, m) == "max_std_bound"
        touches[crit] = m.touches
    assert touches["max"] < 0.8 * touches["integrated"]


def test_batch_mode_plans_k_touches_ordered_for_travel():
    from adaptive_cal.planning.route import path_length_mm, travel_order

    cell = sim_cell(plan={"batch": 6})
    plan = survey_plan(cell)
    m = sv.start(plan)
    drive_some = open_cell(cell)
    while m.fused < 4 or ask(plan, m, 1)[0].retake:  # learn the tilt: all points in the stroke
        t = ask(plan, m, 1)[0]
        m, _ = sv.tell(plan, m, t.x_mm, t.y_mm, t.z_mm,
                       drive_some.cycle.touch(t.x_mm, t.y_mm, t.z_mm).reading_mm)
    batch = ask(plan, m, from_xy=(0.0, 0.0))
    assert len(batch) == 6
    pts = np.array([[t.x_mm, t.y_mm] for t in batch])
    assert path_length_mm((0, 0), pts) <= path_length_mm((0, 0), pts[::-1]) + 1e-9 or \
        travel_order((0, 0), pts) == list(range(6))


def test_dry_run_moves_nothing_and_lists_the_runs_own_first_touches(tmp_path, capsys):
    """The listed touches are the run's: its stroke-safe start included (the list was once one
    batch planned before any reading, the start's points each three times). Oracle: the first
    touches a real run on the simulated cell makes."""
    assert main(["run", "--robot", str(SIM_CELL), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "nothing moves" in out and len(out.splitlines()) >= 5
    listed = [tuple(map(float, line.split()[1:3])) for line in out.splitlines()
              if line[:3].strip().isdigit()]
    assert len(listed) == 20 and len(set(listed)) == 20
    cell = load_cell(SIM_CELL)
    state = drive(survey_plan(cell), open_cell(cell), limit=3)
    np.testing.assert_allclose(listed[:3], np.asarray(state.touched_xy_mm)[:3], atol=0.006)


def test_dry_run_refuses_what_the_run_would_and_does_not_pretend_to_resume(tmp_path, capsys):
    """A stroke no point fits: the run refuses before its first touch, and so does the dry run
    (it printed 'about 0 touches' and exited 0); --dry-run with --resume is refused, not
    ignored."""
    import yaml
    data = load_yaml(SIM_CELL)
    data["probe"]["usable_mm"] = [4.99, 5.01]
    f = tmp_path / "narrow.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 2
    assert "no allowed point can be promised" in capsys.readouterr().err
    assert main(["run", "--robot", str(SIM_CELL), "--resume", str(tmp_path), "--dry-run"]) == 2
    assert "does not continue --resume" in capsys.readouterr().err


@pytest.mark.parametrize("patch,key", [
    ({"workplane": {"x_mm": [-225, 225], "y_mm": [-185, 185], "colour": 1}}, "workplane.colour"),
    ({"probe": {"noise_std_mm": 0}}, "probe.noise_std_mm"),
    ({"workplane": {"x_mm": [10, 10], "y_mm": [-185, 185]}}, "workplane.x_mm"),
    ({"plan": {"stop": {"mean_std_mm": -0.001}}}, "plan.stop.mean_std_mm"),
    ({"workplane": {"x_mm": [-225, 225], "y_mm": [-185, 185],
                    "keep_outs": [{"x_mm": [-300, 300], "y_mm": [-300, 300]}]}}, "keep_outs[0]"),
    # a clamp in another frame or unit: wholly off the plate, it would protect nothing
    ({"workplane": {"x_mm": [-225, 225], "y_mm": [-185, 185],
                    "keep_outs": [{"x_mm": [260, 310], "y_mm": [60, 110]}]}},
     "keep_outs[0] x_mm=[260.0, 310.0] y_mm=[60.0, 110.0] lies wholly outside the workplane"),
    ({"workplane": None}, "workplane"),
    # 400,000 candidates x 576 coefficients: 1.8 GB of rows a decision, refused, not an
    # out-of-memory 'internal error' from JAX
    ({"model": {"knots_x": 24, "knots_y": 24, "tilt_std_deg": 1.0, "offset_std_mm": 0.5},
      "plan": {"stop": {"mean_std_mm": 0.004, "max_touches": 120}, "candidates": 400000}},
     "plan.candidates=400000 with 576 spline coefficients"),
    # 40 x 40 knots: a decision would take several seconds
    ({"model": {"knots_x": 40, "knots_y": 40, "tilt_std_deg": 1.0, "offset_std_mm": 0.5}},
     "model.knots_x x knots_y = 40 x 40 = 1600 spline coefficients: at most 576"),
])
def test_bad_cell_files_name_the_key(tmp_path, patch, key, capsys):
    import yaml
    data = load_yaml(SIM_CELL)
    data.update(patch)
    if data["workplane"] is None:
        del data["workplane"]
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err
    assert not (tmp_path / "o" / "recording.csv").exists()  # nothing moved, nothing written


def test_malformed_recording_row_is_refused_with_its_line(tmp_path, cheng_round0):
    lines = cheng_round0.read_text().splitlines()
    lines[6] = lines[6].replace("-157.5", "abc")  # line 7 of the file: touch 1
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"bad.csv:7: column x_mm: 'abc'"):
        read_recording(bad)
    lines = cheng_round0.read_text().splitlines()
    lines[7] = lines[7].replace("2,,", "1,,", 1)  # touch 2 numbered 1 again
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match="does not increase"):
        read_recording(bad)


def test_flatness_command_reproduces_the_paper_with_intervals(cheng_round0, capsys):
    assert main(["flatness", str(cheng_round0), "--json", "--samples", "100"]) == 0
    out = json.loads(capsys.readouterr().out)
    ls = out["flatness_mm"]["least_squares"]
    assert ls["value"] == pytest.approx(0.5414, abs=0.001)
    assert ls["ci95"][0] < ls["value"] < ls["ci95"][1]
    assert set(out["flatness_mm"]) == {"least_squares", "range", "minimum_zone"}
    assert out["tilt"]["ry_deg"] == pytest.approx(-0.80, abs=0.01)


class _Rows:
    """A recording stand-in for the loop: keeps each row and what the state held when it came."""

    def __init__(self):
        self.rows, self.loop = [], None

    def __call__(self, row):
        self.rows.append(row)
        state = self.loop.state
        assert state.touches == row.seq  # not yet counted: the row is written first
        assert state.fused == len([r for r in self.rows[:-1] if "gated" not in r.flags
                                   and "rejected" not in r.flags])


def test_the_loop_writes_each_reading_before_it_is_fused_and_loses_none_at_a_refit(monkeypatch):
    """Issue 16, defect 1: a kill during the fusion (here: the refit of the 9th reading raises)
    leaves the reading in the recording; a failed write leaves it out of the belief."""
    from adaptive_cal.run import loop as lp

    cell = sim_cell()
    plan = survey_plan(cell)
    rows = _Rows()
    real_fuse = sv.fuse

    def dies_at_the_refit(plan_, state, told):
        if state.fused + told.fused == plan.hyper_after + 1:
            raise KeyboardInterrupt("killed during the refit")
        return real_fuse(plan_, state, told)

    monkeypatch.setattr(lp.sv, "fuse", dies_at_the_refit)
    loop = lp.SurveyLoop(plan, sv.start(plan), open_cell(cell).cycle, record=rows)
    rows.loop = loop
    with pytest.raises(KeyboardInterrupt):
        loop.run()
    assert len(rows.rows) == loop.state.touches + 1  # the last reading is written, not fused
    assert loop.state.fused == plan.hyper_after

    monkeypatch.setattr(lp.sv, "fuse", real_fuse)

    def write_fails(row):
        raise OSError("disk full")

    loop = lp.SurveyLoop(plan, sv.start(plan), open_cell(cell).cycle, record=write_fails)
    with pytest.raises(OSError):
        loop.run()
    assert loop.state.touches == 0 and loop.state.fused == 0  # never fused what was not written


def test_a_rejected_touch_keeps_its_real_position_and_is_never_fused():
    from adaptive_cal.hardware.base import TouchRejected
    from adaptive_cal.run.loop import SurveyLoop

    class _RejectsThird:
        def __init__(self, cycle):
            self.cycle, self.motion, self.clock, self.count = cycle, cycle.motion, cycle.clock, 0

        def touch(self, x, y, z, plate_top=None):
            self.count += 1
            if self.count == 3:
                raise TouchRejected("stroke end", 9.9, ("rejected", "stroke_end"))
            return self.cycle.touch(x, y, z, plate_top)

    cell = sim_cell()
    plan = survey_plan(cell)
    rows, steps = [], []
    loop = SurveyLoop(plan, sv.start(plan), _RejectsThird(open_cell(cell).cycle),
                      record=rows.append, hooks=(steps.append,),
                      stop=lambda state, status: "enough" if state.touches >= 5 else None)
    assert loop.run() == "enough"
    third = steps[2]
    assert third.told is None and third.rejected is not None
    assert loop.state.touched_xy_mm[2] == (third.target.x_mm, third.target.y_mm)
    assert np.all(np.isfinite(loop.state.touched_xy_mm))
    assert rows[2].flags == ("rejected", "stroke_end") and rows[2].reading_mm == 9.9
    kept = [r for r in rows if "gated" not in r.flags and "rejected" not in r.flags]
    assert loop.state.touches == 5 and loop.state.fused == len(kept) <= 4
    assert [r.seq for r in rows] == list(range(5))


def test_the_survey_shell_equals_the_pure_functions():
    """Survey (the notebook shell) and sv.tell on the same readings give the same state."""
    from adaptive_cal.planning.shell import Survey

    cell = sim_cell()
    plan = survey_plan(cell)
    shell, state, cycle = Survey(plan), sv.start(plan), open_cell(cell).cycle
    for _ in range(10):
        t = shell.ask()[0]
        assert ask(plan, state)[0] == t
        reading = cycle.touch(t.x_mm, t.y_mm, t.z_mm).reading_mm
        told = shell.tell(t.x_mm, t.y_mm, t.z_mm, reading)
        state, told2 = sv.tell(plan, state, t.x_mm, t.y_mm, t.z_mm, reading)
        assert told == told2
    np.testing.assert_array_equal(shell.belief.mean, state.belief.mean)
    assert shell.touches == state.touches == 10 and len(shell.history) == 11
    assert shell.stop_reason() == sv.stop_reason(plan, state)


def test_a_bound_that_looks_like_um_typed_as_mm_is_warned_before_anything_moves(tmp_path,
                                                                                 capsys):
    import yaml

    data = load_yaml(SIM_CELL)
    data["plan"]["stop"]["mean_std_mm"] = 4  # meant 4 um
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "warning: plan.stop.mean_std_mm: 4 mm is 44% of the probe's usable stroke (9 mm)" in err
    assert "(4 um is 0.004)" in err
    data["plan"]["stop"]["mean_std_mm"] = 0.004
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 0
    assert "warning" not in capsys.readouterr().err
    # with the noise span stated (no touch floor) the prior alone meets 4 mm: the dry run says
    # so -- it said "no allowed point can be promised", which was not why
    data["plan"]["stop"]["mean_std_mm"] = 4
    data["probe"].update(noise_range_mm=[0.003, 0.008])
    data["probe"].pop("noise_std_mm", None)
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 0
    assert "the prior alone already meets the stopping rule" in capsys.readouterr().out


def test_commands_to_copy_quote_a_folder_with_spaces(tmp_path, monkeypatch, capsys):
    import shlex

    out = tmp_path / "my runs" / "plate 1"
    # interrupted after 3 touches: the summary's --resume must survive a copy into a shell
    real = session.run
    monkeypatch.setattr(session, "run", lambda *a, **k: real(*a, **{**k, "max_new_touches": 3}))
    assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 130
    said = capsys.readouterr().out
    command = said.split("Continue with ")[1].split("\n")[0]
    assert shlex.split(command) == ["adaptive-cal", "run", "--resume", str(out)]


def test_a_resume_of_a_finished_run_whose_results_were_lost_takes_no_touch(tmp_path):
    out = tmp_path / "r"
    first = session.run(sim_cell(), out, progress=False)
    assert first["stopped_because"] == "mean_std_bound" and first["closure"]["made"]
    rows = (out / "recording.csv").read_text()
    (out / "result.json").unlink()  # as a crash while they were written leaves it
    again = session.run(sim_cell(), out, resume=True, progress=False)
    assert (out / "recording.csv").read_text() == rows  # the closure was not made twice
    assert again["stopped_because"] == "mean_std_bound" and again["touches"] == first["touches"]
    assert again["closure"]["repeat_touches"] == first["closure"]["repeat_touches"]
    assert again["closure"]["passed"] is True


def test_a_reading_cut_short_while_judged_is_kept_flagged_and_not_fused(monkeypatch):
    """A second Ctrl-C landing in the judgement of a reading that was taken: the reading is
    written (cut;rejected: kept, never fused) before the interrupt goes on (an outside audit: it
    was lost)."""
    from adaptive_cal.run import loop as lp

    cell = sim_cell(plan={"candidates": 2000})
    plan = survey_plan(cell)
    opened = open_cell(cell)
    real, calls, rows = lp.sv.judge, [0], []

    def judge(*a, **k):
        calls[0] += 1
        if calls[0] == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(lp.sv, "judge", judge)
    loop = lp.SurveyLoop(plan, sv.start(plan), opened.cycle, record=rows.append)
    with pytest.raises(KeyboardInterrupt):
        loop.run()
    opened.close()
    assert len(rows) == 3 and set(rows[-1].flags) == {"cut", "rejected"}
    assert loop.state.fused == 2 and loop.state.touches == 2  # taken, kept, not fused
    assert cell.probe.usable_mm[0] <= rows[-1].reading_mm <= cell.probe.usable_mm[1]


def test_a_second_ctrl_c_while_the_results_are_written_leaves_them_whole(tmp_path, monkeypatch):
    import signal as sig

    real = session.write_results

    def pressed_twice(*a, **k):  # the user presses Ctrl-C twice more as the results are written
        os.kill(os.getpid(), sig.SIGINT)
        os.kill(os.getpid(), sig.SIGINT)
        return real(*a, **k)

    monkeypatch.setattr(session, "write_results", pressed_twice)
    r = session.run(sim_cell(), tmp_path / "r", progress=False, max_new_touches=4)
    assert r["stopped_because"] == "interrupted" and r["touches"] == 4
    assert (tmp_path / "r" / "result.json").exists() and (tmp_path / "r" / "belief.npz").exists()


@pytest.mark.parametrize("edit", ["bom", "crlf", "reordered"])
def test_a_resume_appends_to_a_recording_a_spreadsheet_saved_as_the_reader_reads_it(tmp_path,
                                                                                   edit):
    """A recording read everywhere (byte-order mark, CRLF line ends, columns in another order:
    docs/recording.md) was refused by --resume ("its header differs"); now continued, in the
    file's own column order and line ends, with the same readings."""
    cell = sim_cell()
    out = tmp_path / "run"
    session.run(cell, out, progress=False, max_new_touches=5)
    path = out / "recording.csv"
    before = read_recording(path)
    text = path.read_text(encoding="utf-8")
    if edit == "bom":
        path.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    elif edit == "crlf":
        path.write_bytes(text.replace("\n", "\r\n").encode("utf-8"))
    else:
        lines = text.splitlines()
        k = next(i for i, l in enumerate(lines) if not l.startswith("#"))
        order = [6, 0, 2, 3, 1, 4, 5] + list(range(7, len(lines[k].split(","))))
        lines[k:] = [",".join(l.split(",")[i] for i in order) for l in lines[k:]]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    r = session.run(cell, out, resume=True, progress=False, max_new_touches=3)
    assert r["touches"] == 8
    after = read_recording(path)
    np.testing.assert_array_equal(after.seq, np.arange(8))
    np.testing.assert_array_equal(after.reading_mm[:5], before.reading_mm)
    raw = path.read_bytes()
    if edit == "crlf":
        assert raw.count(b"\r\n") == raw.count(b"\n")  # no mixed line ends
    else:
        assert b"\r" not in raw


def test_a_keep_out_over_the_plates_centre_is_named_when_no_first_touch_fits(tmp_path, capsys):
    """A fixture of 200 x 150 mm over the centre of the simulated plate: while the tilt is
    unknown the first touches must lie near the centre, so none is allowed. The refusal names
    the keep-out (before: "the keep-outs and the edge margin leave no point near the plate's
    centre", none named; an outside audit, 2026-11-29)."""
    import yaml
    data = load_yaml(SIM_CELL)
    data["workplane"]["keep_outs"] = [{"x_mm": [-100, 100], "y_mm": [-75, 75]}]
    f = tmp_path / "fixture.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "workplane.keep_outs[0] (x_mm [-100.0, 100.0], y_mm [-75.0, 75.0]) covers the point " \
           "whose height the prior knows (0, 0) mm" in err


def test_the_map_under_a_keep_out_is_said_to_be_untouched_with_its_band(tmp_path):
    """A clamp over a corner: result.json's keep_outs gives how far its map lies from any touch
    and the band's std there, and the summary says it is extrapolated (an outside audit,
    2026-11-29: a corner keep-out's map 13-23 um off under bands of 9-13 um, nothing said)."""
    from adaptive_cal.run.results import result_of

    cell = sim_cell(workplane={"keep_outs": [{"x_mm": [-225, -150], "y_mm": [110, 185]}]})
    plan, opened = survey_plan(cell), open_cell(cell)
    state = drive(plan, opened, limit=30)
    r = result_of(cell, plan, state, tmp_path / "no-recording.csv", "limit",
                  rng=np.random.default_rng(0))
    (k,) = r["keep_outs"]
    assert k["x_mm"] == [-225, -150] and k["y_mm"] == [110, 185] and k["index"] == 0
    xy = np.asarray(state.touched_xy_mm)
    assert not np.any((xy[:, 0] >= -225) & (xy[:, 0] <= -150) & (xy[:, 1] >= 110)
                      & (xy[:, 1] <= 185))
    corner = min(np.hypot(x + 225, y - 185) for x, y in xy)  # the plate's corner, brute force
    assert corner <= k["farthest_from_touch_mm"] <= corner + 1e-9
    gx, gy, _, std = sv.grid(plan, state.belief, 61, state)  # the plate's band, its corner
    assert gx[0] == -225 and gy[-1] == 185
    assert k["std_max_mm"] == pytest.approx(std[0, -1], rel=1e-9)
    assert k["std_rms_mm"] <= k["std_max_mm"]
    assert "keep_outs[0] (x -225..-150, y 110..185 mm) is never touched" in k["text"]
    assert f"rests on touches up to {corner:.0f} mm away" in k["text"]


def test_too_few_candidates_are_named_when_no_first_touch_fits(tmp_path, capsys):
    """An outside audit (2026-12-01): plan.candidates 16 (allowed by the schema) left no grid
    point near the plate's centre, and the refusal blamed the prior and the keep-outs."""
    import yaml
    data = load_yaml(SIM_CELL)
    data["plan"]["candidates"] = 16
    f = tmp_path / "coarse.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "among the 16 points of plan.candidates=16" in err and "give more candidates" in err
    assert "keep-outs" not in err


def test_max_std_alone_is_the_bound_and_two_bounds_both_hold_the_run():
    """An outside audit (2026-12-02): a cell stating plan.stop.max_std_mm alone kept the default
    mean bound, which stopped the run (any bound stopped it) while the max bound was unmet: the
    summary said INCOMPLETE, and the --resume it advised answered 'already finished'."""
    from adaptive_cal.cell.build import stop_rule
    from adaptive_cal.planning.stopping import Status
    from tests.helpers import sim_cell

    alone = sim_cell(plan={"stop": {"max_std_mm": 0.008, "max_touches": 120}})
    assert alone.plan.stop.mean_std_mm is None
    rule = stop_rule(alone, 30)
    assert rule(Status(touches=40, mean_std_mm=0.003, max_std_mm=0.0082)) is None
    assert rule(Status(touches=40, mean_std_mm=0.009, max_std_mm=0.0079)) == "max_std_bound"
    both = sim_cell(plan={"stop": {"max_std_mm": 0.008, "mean_std_mm": 0.004}})
    rule = stop_rule(both, 30)
    assert rule(Status(touches=40, mean_std_mm=0.003, max_std_mm=0.0082)) is None
    assert rule(Status(touches=40, mean_std_mm=0.0041, max_std_mm=0.0079)) is None
    assert rule(Status(touches=40, mean_std_mm=0.0039, max_std_mm=0.0079)) is not None
    assert rule(Status(touches=200, mean_std_mm=0.1, max_std_mm=0.1)) == "touch_budget"
