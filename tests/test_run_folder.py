"""A run folder's integrity: one process at a time, resume by the last seq + 1 with a cut row
repaired, results replaced whole and valid JSON, and a batch that never outruns the budget."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording
from adaptive_cal.formats.writing import repair_cut_row
from adaptive_cal.run import session
from adaptive_cal.run.folder import (LOCK_NAME, RunFolderBusy, finite_json, replace_atomically,
                                     run_lock)

from helpers import ROOT, SIM_CELL, sim_cell

HOLD = ("import sys, time; from adaptive_cal.run.folder import run_lock\n"
        "with run_lock(sys.argv[1]):\n    print('locked', flush=True); time.sleep(120)\n")


def _holder(folder):
    """A second process holding ``folder``'s lock until killed."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE,
                            env=env, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_process_on_the_folder_fails_at_once_naming_folder_and_holder(tmp_path, capsys):
    out = tmp_path / "run"
    session.run(sim_cell(), out, progress=False, max_new_touches=3)
    before = (out / "recording.csv").read_text()
    proc = _holder(out)
    try:
        t0 = time.monotonic()
        with pytest.raises(RunFolderBusy, match=f"pid {proc.pid}"):
            session.run(sim_cell(), out, resume=True, progress=False)
        assert main(["run", "--resume", str(out), "--robot", str(SIM_CELL), "--no-progress"]) == 2
        assert time.monotonic() - t0 < 30  # at once: no wait for the holder
        err = capsys.readouterr().err
        assert str(out) in err and f"pid {proc.pid}" in err and "Traceback" not in err
        assert (out / "recording.csv").read_text() == before  # nothing written
    finally:
        proc.send_signal(signal.SIGKILL)  # a killed holder: its lock must not block
        proc.wait(timeout=30)
    assert (out / LOCK_NAME).read_text().strip() == str(proc.pid)  # the stale pid is still there
    r = session.run(sim_cell(), out, resume=True, progress=False, max_new_touches=2)
    assert r["touches"] == 5


def test_the_lock_is_released_on_every_exit_path(tmp_path):
    out = tmp_path / "f"
    with run_lock(out):
        with pytest.raises(RunFolderBusy, match=str(os.getpid())):
            with run_lock(out):  # another open file: flock conflicts within one process too
                pass
    for exc in (ValueError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            with run_lock(out):
                raise exc
        with run_lock(out):  # free again
            pass
    # an error inside a run (no admissible point) releases it as well
    with pytest.raises(session.NoAdmissiblePoint):
        session.run(sim_cell(model={"offset_std_mm": 5.0}), tmp_path / "x", progress=False)
    with run_lock(tmp_path / "x"):
        assert (tmp_path / "x" / LOCK_NAME).read_text().strip() == str(os.getpid())


def _rewrite_seq(path, seqs):
    lines = path.read_text().splitlines()
    data = [i for i, l in enumerate(lines) if l and not l.startswith("#")][1:]
    assert len(data) == len(seqs)
    for i, s in zip(data, seqs):
        lines[i] = f"{s}," + lines[i].split(",", 1)[1]
    path.write_text("\n".join(lines) + "\n")


def test_resume_continues_from_the_last_seq_plus_one(tmp_path):
    cell, out = sim_cell(), tmp_path / "run"
    session.run(cell, out, progress=False, max_new_touches=6)
    rec_path = out / "recording.csv"
    _rewrite_seq(rec_path, [100, 101, 102, 110, 111, 112])  # starts at 100, with a gap
    with pytest.raises(RecordingError, match="not the recording the map saved beside it"):
        session.run(cell, out, resume=True, progress=False, max_new_touches=3)  # edited since
    for name in ("belief.npz", "result.json"):  # as a run killed before its results leaves it
        (out / name).unlink()
    r = session.run(cell, out, resume=True, progress=False, max_new_touches=3)
    rec = read_recording(rec_path)  # readable: seq still increases
    assert rec.seq.tolist() == [100, 101, 102, 110, 111, 112, 113, 114, 115]
    assert r["touches"] == 9


def test_a_cut_last_row_is_repaired_and_resume_continues(tmp_path, capsys):
    cell, out = sim_cell(), tmp_path / "run"
    session.run(cell, out, progress=False, max_new_touches=5)
    rec_path = out / "recording.csv"
    whole = rec_path.read_text()
    with open(rec_path, "a") as f:
        f.write("5,31.2,12.5")  # a crash mid-write: the required numbers are not all there
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said as a message line, not a Python warning
        r = session.run(cell, out, resume=True, progress=False, max_new_touches=2)
    err = capsys.readouterr().err
    assert f"{rec_path}:{whole.count(chr(10)) + 1}: the last row was cut by a crash" in err
    assert "dropped, a required number is missing" in err and "Warning" not in err
    assert (out / "recording.cut.txt").read_text().endswith("\n5,31.2,12.5\n")  # kept aside
    rec = read_recording(rec_path)
    assert rec.seq.tolist() == list(range(7)) and r["touches"] == 7
    assert rec_path.read_text().startswith(whole)  # the rows before are untouched


def test_repair_keeps_a_whole_row_that_only_lacks_its_newline(tmp_path):
    p = tmp_path / "r.csv"
    head = "# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,flags\n"
    p.write_text(head + "0,1.0,2.0,3.0,4.0,5.0,\n1,2.0,2.0,3.0,4.0,5.1,")
    assert repair_cut_row(p) is None
    assert read_recording(p).seq.tolist() == [0, 1]
    p.write_text(head + "0,1.0,2.0,3.0,4.0,5.0,\n1,2.0,2.0,3.0,4.0,5.")  # a field missing
    assert repair_cut_row(p) == "1,2.0,2.0,3.0,4.0,5."
    assert p.read_text() == head + "0,1.0,2.0,3.0,4.0,5.0,\n"
    assert repair_cut_row(p) is None  # idempotent


def test_non_finite_numbers_become_null_and_the_json_stays_valid():
    value = {"a": float("nan"), "b": [1.0, float("inf"), np.float64("-inf")],
             "c": np.array([0.5, np.nan]), "d": {"e": np.float64(2.5), "f": np.int64(3)},
             "g": (True, None, "x")}
    clean = finite_json(value)
    text = json.dumps(clean, allow_nan=False)  # the oracle: raises on NaN / Infinity
    assert json.loads(text) == {"a": None, "b": [1.0, None, None], "c": [0.5, None],
                                "d": {"e": 2.5, "f": 3}, "g": [True, None, "x"]}


def test_a_file_replaced_atomically_is_old_or_new_never_half(tmp_path):
    p = tmp_path / "result.json"
    p.write_text("old")

    def half(f):
        f.write("ne")
        raise KeyboardInterrupt  # a Ctrl-C mid-write

    with pytest.raises(KeyboardInterrupt):
        replace_atomically(p, half)
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["result.json"]
    replace_atomically(p, lambda f: f.write("new"))
    assert p.read_text() == "new" and os.listdir(tmp_path) == ["result.json"]


def test_result_json_is_strict_json_and_not_ahead_of_the_recording(tmp_path):
    out = tmp_path / "run"
    session.run(sim_cell(), out, progress=False, max_new_touches=4)

    def refuse(name):
        raise ValueError(f"{name} in result.json")

    r = json.loads((out / "result.json").read_text(), parse_constant=refuse)
    assert r["touches"] == len(read_recording(out / "recording.csv")) == 4
    assert sorted(p.name for p in out.iterdir() if p.name.endswith(".tmp")) == []


def test_a_batch_larger_than_the_budget_makes_no_more_touches_than_the_budget(tmp_path):
    cell = sim_cell(plan={"batch": 40, "candidates": 2000,
                          "stop": {"mean_std_mm": 1e-6, "max_touches": 10}})
    r = session.run(cell, tmp_path / "run", progress=False)
    assert r["stopped_because"] == "touch_budget"
    assert r["touches"] == len(read_recording(tmp_path / "run" / "recording.csv")) == 10


def test_resuming_a_finished_run_changes_nothing(tmp_path):
    cell = sim_cell(plan={"candidates": 2000, "stop": {"mean_std_mm": 1e-6, "max_touches": 6}})
    out = tmp_path / "run"
    r = session.run(cell, out, progress=False)
    assert r["stopped_because"] == "touch_budget"
    files = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.iterdir()
             if p.name != LOCK_NAME}
    again = session.run(cell, out, resume=True, progress=False)
    assert again["already_finished"] == "touch_budget" and again["touches"] == 6
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.iterdir()
            if p.name != LOCK_NAME} == files  # no rewrite of result.json, nor anything else


def test_the_progress_bar_shows_each_bound_with_its_unit():
    from types import SimpleNamespace

    from adaptive_cal.planning.stopping import Status

    shown = []
    bar = SimpleNamespace(set_postfix_str=lambda text, refresh: shown.append(text),
                          update=lambda n: None)
    session._update(bar, sim_cell(), Status(touches=3, mean_std_mm=0.0039, max_std_mm=0.0102))
    assert shown == ["RMS std 3.9 um / bound 4.0 um, max std 10.2 um, bound met"]
    # why the run goes on past a met bound: the touch floor, then a model that fails its checks
    session._update(bar, sim_cell(), Status(23, 0.0039, 0.0102), floor=30)
    assert shown[-1].endswith(", bound met, going on to the touch floor of 30")
    session._update(bar, sim_cell(), Status(31, 0.0039, 0.0102, adequate=False), floor=30)
    assert shown[-1].endswith(", bound met, going on: the model's self-checks fail")
    session._update(bar, sim_cell(), Status(31, 0.0039, 0.0102, repeats_owed=7), floor=30)
    assert shown[-1].endswith(", bound met, going on: 7 repeat readings measure the probe's own "
                              "noise")
    session._update(bar, sim_cell(), Status(23, 0.0041, 0.0102), floor=30)
    assert shown[-1] == "RMS std 4.1 um / bound 4.0 um, max std 10.2 um"


def test_replaced_files_keep_the_usual_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        replace_atomically(tmp_path / "a.json", lambda f: f.write("{}"))
    finally:
        os.umask(old)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600


def test_a_touch_recorded_but_not_fused_when_stopped_at_once_is_said(tmp_path, monkeypatch):
    """An outside audit (2026-12-01): a second Ctrl-C between a touch's row and its fusion left
    8 rows beside a map and result.json of 7 with no word, and report blamed a resume that never
    happened. The count is in result.json, the INCOMPLETE line and report's refusal."""
    from adaptive_cal.cli.common import UserError
    from adaptive_cal.cli.run_guards import refuse_stale_map
    from adaptive_cal.formats.writing import RecordingWriter
    from adaptive_cal.report.status import missing

    real = RecordingWriter.append

    def second_ctrl_c(self, **row):
        real(self, **row)
        if row["seq"] == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(RecordingWriter, "append", second_ctrl_c)
    out = tmp_path / "run"
    r = session.run(sim_cell(), out, progress=False)
    assert r["touches"] == 2 and r["recorded_not_fused"] == 1
    assert "1 touch more in the recording, stopped before it was fused: --resume fuses it" \
        in missing(r)
    with pytest.raises(UserError, match="stopped at once .* after it recorded them"):
        refuse_stale_map(out, "report")
    monkeypatch.setattr(RecordingWriter, "append", real)
    r = session.run(sim_cell(), out, resume=True, progress=False, max_new_touches=1)
    assert r["touches"] == 4 and "recorded_not_fused" not in r


def test_a_folder_a_run_is_using_is_said_so_not_sent_to_resume(tmp_path, capsys):
    """An outside audit (2026-12-01): while a run held the folder, a second `run --out` said
    'exists: continue it with --resume' (which then said 'in use'), and report said its results
    were missing, to be written by --resume."""
    from adaptive_cal.report.status import unfinished

    out = tmp_path / "run"
    session.run(sim_cell(), out, progress=False, max_new_touches=2)
    (out / "result.json").unlink()
    (out / "belief.npz").unlink()
    proc = _holder(out)
    try:
        assert main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"is in use by another run (pid {proc.pid})" in err and "--resume" not in err
        said = unfinished(out, "result.json")
        assert f"a run (pid {proc.pid}) is going on" in said and "--resume" not in said
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    (out / "cell.yaml").write_text(SIM_CELL.read_text())  # as the CLI's run leaves it
    assert "adaptive-cal run --resume" in unfinished(out, "result.json")
