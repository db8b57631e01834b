"""Kill tests at every step of a touch (issue 16, deliver 6): before the row is written, after
it is written, during the fusion's refit, during result.json's write and during the figures --
each as a hard kill (an exception nothing in the session catches: files stay as they are) and
as a double Ctrl-C (KeyboardInterrupt: the session writes what it has) -- and one real SIGKILL
of a subprocess run at a seeded random moment. After each: every row written is in the
recording, result.json and belief.npz never hold a touch the recording lacks, and
``run --resume`` continues to a finished run with seq 0, 1, 2, ... and no row lost."""
import json
import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.formats.writing import RecordingWriter, repair_cut_row
from adaptive_cal.planning import survey as sv
from adaptive_cal.run import folder, results, session

from helpers import ROOT, SIM_CELL

BUDGET, KILL_AT = 11, 9  # refits at the 8th, 9th, 10th and 11th reading (hyper_after 8, every 1)


class Killed(BaseException):
    """A kill: nothing in the session catches it, so no result is written on the way out."""


@pytest.fixture(scope="module")
def cell_file(tmp_path_factory):
    cell = yaml.safe_load(SIM_CELL.read_text())
    cell["plan"] = {"stop": {"mean_std_mm": 0.004, "max_touches": BUDGET}, "candidates": 400,
                    "hyper_after": 8, "hyper_every": 1}
    path = tmp_path_factory.mktemp("kill") / "cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    return path


def _written(out):
    return read_recording(out / "recording.csv")


def _check_files(out, rows_written):
    """The recording holds every row written; result.json / belief.npz hold no more."""
    rec = _written(out)
    assert len(rec) == rows_written and list(rec.seq) == list(range(rows_written))
    if (out / "result.json").exists():
        assert json.loads((out / "result.json").read_text())["touches"] <= len(rec)
    if (out / "belief.npz").exists():
        assert int(np.load(out / "belief.npz")["touches"]) <= len(rec)
    return rec


def _resume_to_the_end(out, rec_before):
    # the budget spent with the 4 um bound unmet: not a result, exit 1 (report.status)
    assert main(["run", "--resume", str(out), "--no-progress"]) == 1
    assert json.loads((out / "result.json").read_text())["stopped_because"] == "touch_budget"
    rec = _written(out)
    assert list(rec.seq) == list(range(len(rec))) and len(rec) >= len(rec_before)
    for col in ("x_mm", "y_mm", "z_mm", "reading_mm"):  # no row lost or changed
        assert np.array_equal(getattr(rec, col)[:len(rec_before)], getattr(rec_before, col))
    result = json.loads((out / "result.json").read_text())
    assert result["touches"] == len(rec) and result["stopped_because"] != "interrupted"
    assert int(np.load(out / "belief.npz")["touches"]) == len(rec)


def _arm(monkeypatch, step, exc):
    """Make ``step`` raise ``exc`` at the KILL_AT-th reading (or the first results written)."""
    real_append, real_fuse = RecordingWriter.append, sv.fuse
    real_write_json, real_save = folder.write_json, results._save
    calls = {"append": 0}

    def append(self, **row):
        calls["append"] += 1
        if step == "before write" and calls["append"] == KILL_AT:
            raise exc("killed before the write")
        real_append(self, **row)
        if step == "after write" and calls["append"] == KILL_AT:
            raise exc("killed after the write")

    def fuse(plan, state, told):
        if step == "during refit" and state.fused + 1 == KILL_AT and told.fused:
            raise exc("killed during the refit")
        return real_fuse(plan, state, told)

    def write_json(path, value):
        if step == "during result.json":
            real = folder.replace_atomically

            def dies(p, write, binary=False):
                real(p, lambda f: (write(f), (_ for _ in ()).throw(exc("killed mid-write"))))
            monkeypatch.setattr(folder, "replace_atomically", dies)
        return real_write_json(path, value)

    def save(fig, path):
        if step == "during figures":
            raise exc("killed while drawing the figures")
        return real_save(fig, path)

    monkeypatch.setattr(RecordingWriter, "append", append)
    monkeypatch.setattr(sv, "fuse", fuse)
    monkeypatch.setattr(results, "write_json", write_json)
    monkeypatch.setattr(results, "_save", save)
    return calls


STEPS = ["before write", "after write", "during refit", "during result.json", "during figures"]


@pytest.mark.slow
@pytest.mark.parametrize("step, exc", [(s, Killed) for s in STEPS] + [
    ("after write", KeyboardInterrupt), ("during refit", KeyboardInterrupt),
    ("during figures", KeyboardInterrupt)], ids=lambda v: v if isinstance(v, str) else v.__name__)
def test_a_kill_at_each_step_of_a_touch_loses_nothing_and_resume_finishes(
        tmp_path, monkeypatch, cell_file, step, exc):
    out = tmp_path / "run"
    cell = load_cell(cell_file)
    out.mkdir()
    (out / "cell.yaml").write_text(cell_file.read_text())
    calls = _arm(monkeypatch, step, exc)
    with pytest.raises((Killed, KeyboardInterrupt, OSError)) if exc is Killed else _maybe():
        session.run(cell, out, progress=False)
    monkeypatch.undo()
    written = calls["append"] - (step == "before write")
    if step in ("during result.json", "during figures"):
        written = calls["append"]  # every touch was made and written before the results
    rec = _check_files(out, written)
    assert not list(out.glob(".*.tmp")) or exc is Killed  # a Ctrl-C leaves no temporary file
    _resume_to_the_end(out, rec)


class _maybe:
    """A double Ctrl-C may end in the session's own result (no exception reaches the caller)."""

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        return kind is None or issubclass(kind, KeyboardInterrupt)


@pytest.mark.slow
def test_a_real_sigkill_at_a_random_moment_loses_no_row(tmp_path, cell_file):
    rng = random.Random(16)
    out = tmp_path / "run"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg",
           "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot",
                             str(cell_file), "--out", str(out), "--no-progress"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rows = rng.randrange(2, BUDGET - 2)
    deadline = time.monotonic() + 120
    rec_path = out / "recording.csv"
    while time.monotonic() < deadline and proc.poll() is None:
        if rec_path.exists() and sum(line[:1].isdigit() for line in  # data rows, whole
                                     rec_path.read_text().splitlines(keepends=True)
                                     if line.endswith("\n")) >= rows:
            break
        time.sleep(0.05)
    time.sleep(rng.uniform(0.0, 1.0))  # somewhere in the next touch: ask, touch, write, fuse
    assert proc.poll() is None, "the run ended before the kill"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    repair_cut_row(rec_path)  # what --resume does first
    rec = _written(out)
    assert len(rec) >= rows and list(rec.seq) == list(range(len(rec)))
    if (out / "result.json").exists():
        assert json.loads((out / "result.json").read_text())["touches"] <= len(rec)
    _resume_to_the_end(out, rec)


def test_one_ctrl_c_while_the_results_are_written_still_writes_them(tmp_path, monkeypatch,
                                                                     cell_file):
    """The touches done, one Ctrl-C while the figures and result.json were written (the last
    second of a run) raised at once -- the deferred handler had been taken down with the loop --
    and left a folder of a finished run without its result, which --resume then took a second
    closure touch to make. It is deferred there too now: the results are written whole."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "cell.yaml").write_text(cell_file.read_text())
    real = session.write_results

    def ctrl_c_then_write(*a, **k):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the signal is handled here
        return real(*a, **k)

    monkeypatch.setattr(session, "write_results", ctrl_c_then_write)
    result = session.run(load_cell(cell_file), out, progress=False)
    rec = _written(out)
    saved = json.loads((out / "result.json").read_text())
    assert saved["touches"] == len(rec) == result["touches"] == BUDGET
    assert saved["stopped_because"] == "touch_budget"
    assert int(np.load(out / "belief.npz")["touches"]) == len(rec)
