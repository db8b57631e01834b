"""A run folder after a crash or a hand edit (an outside audit, 2026-11-29): the map saved in
belief.npz must be the map of the recording and result.json beside it, or report and flatness
refuse and say how to get one answer; a start killed before its first touch, or before its
recording's header, is taken up by the same command again; a temporary file a kill left behind
is removed by the next run on the folder."""
import contextlib
import io
import json
import os
import shutil

import pytest
import yaml

from adaptive_cal.cli import main

from helpers import SIM_CELL

BUDGET = 9


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A short run of the sim cell (its budget spent), its folder kept as written."""
    root = tmp_path_factory.mktemp("consistency")
    cell = yaml.safe_load(SIM_CELL.read_text())
    cell["plan"] = {"stop": {"mean_std_mm": 0.004, "max_touches": BUDGET}, "candidates": 400}
    path = root / "cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        main(["run", "--robot", str(path), "--out", str(root / "run"), "--no-progress"])
    assert json.loads((root / "run" / "result.json").read_text())["touches"] == BUDGET
    return root


def _copy(finished, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(finished / "run", out)
    return out


def _cli(*argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


def _rows(path):
    lines = path.read_text().splitlines(keepends=True)
    return lines, [i for i, line in enumerate(lines) if line[:1].isdigit()]


def test_the_untouched_folder_is_reported(finished, tmp_path):
    out = _copy(finished, tmp_path)
    rc, _, err = _cli("report", str(out), "--out", str(tmp_path / "page.html"))
    assert rc == 0, err
    rc, _, err = _cli("flatness", str(out / "recording.csv"))
    assert rc in (0, 1) and "not the recording" not in err, err


@pytest.mark.parametrize("edit", ["delete", "reading", "flag"])
def test_a_row_deleted_or_edited_since_the_map_was_saved_is_refused(finished, tmp_path, edit):
    out = _copy(finished, tmp_path)
    rec = out / "recording.csv"
    lines, rows = _rows(rec)
    k = rows[4]
    if edit == "delete":
        del lines[k]
    elif edit == "reading":
        cells = lines[k].split(",")
        cells[5] = f"{float(cells[5]) + 0.0001:.6f}"
        lines[k] = ",".join(cells)
    else:
        cells = lines[k].split(",")
        cells[6] = "rejected"
        lines[k] = ",".join(cells)
    rec.write_text("".join(lines))
    for argv in (["report", str(out), "--out", str(tmp_path / "page.html")],
                 ["flatness", str(rec)]):
        rc, _, err = _cli(*argv)
        assert rc == 2 and "is not the recording the map saved beside it" in err, (argv, err)
        assert ("other values" in err) == (edit != "delete") and "Replay the recording" in err


def test_a_crlf_copy_of_the_recording_is_the_same_recording(finished, tmp_path):
    out = _copy(finished, tmp_path)
    rec = out / "recording.csv"
    rec.write_bytes(rec.read_bytes().replace(b"\n", b"\r\n"))
    rc, _, err = _cli("report", str(out), "--out", str(tmp_path / "page.html"))
    assert rc == 0, err


def test_results_of_another_count_than_the_map_are_refused_and_resume_mends_them(finished,
                                                                              tmp_path):
    """The audit's case: killed while the resumed run saved its results, belief.npz new and
    result.json old. report showed one map, flatness the other, both exit 0."""
    out = _copy(finished, tmp_path)
    result = json.loads((out / "result.json").read_text())
    (out / "result.json").write_text(json.dumps({**result, "touches": 5}))
    rc, _, err = _cli("report", str(out), "--out", str(tmp_path / "page.html"))
    assert rc == 2 and "result.json is of 5 touches, belief.npz of 9" in err, err
    assert f"adaptive-cal run --resume {out}" in err
    _cli("run", "--resume", str(out), "--no-progress")
    assert json.loads((out / "result.json").read_text())["touches"] == BUDGET
    rc, _, err = _cli("report", str(out), "--out", str(tmp_path / "page.html"))
    assert rc == 0, err


def test_a_start_killed_before_its_first_touch_is_started_again_by_the_same_command(
        finished, tmp_path):
    """The folder holds the run's copy of the cell file and its lock: the same command goes on
    (it had been refused: 'holds cell.yaml, which a run writes'); --resume says how."""
    cell = finished / "cell.yaml"
    out = tmp_path / "run"
    out.mkdir()
    shutil.copyfile(cell, out / "cell.yaml")
    (out / ".run.lock").write_text("12345\n")
    rc, _, err = _cli("run", "--resume", str(out), "--no-progress")
    assert rc == 2 and f"adaptive-cal run --robot {out / 'cell.yaml'} --out {out}" in err, err
    rc, _, err = _cli("run", "--robot", str(cell), "--out", str(out), "--no-progress")
    assert rc in (0, 1) and json.loads((out / "result.json").read_text())["touches"] == BUDGET
    other = tmp_path / "other"
    other.mkdir()
    (other / "cell.yaml").write_text("name: a user's own file\n")
    rc, _, err = _cli("run", "--robot", str(cell), "--out", str(other), "--no-progress")
    assert rc == 2 and "holds cell.yaml, which a run writes" in err
    assert (other / "cell.yaml").read_text() == "name: a user's own file\n"


def test_a_start_killed_before_its_recordings_header_is_started_again(finished, tmp_path):
    """An empty recording.csv (killed between its creation and its header): --resume had said
    'empty file' and the same command 'exists: continue it with --resume'. Now --resume says
    what to run, and the same command goes on (an empty file holds no reading to lose)."""
    cell = finished / "cell.yaml"
    out = tmp_path / "run"
    out.mkdir()
    shutil.copyfile(cell, out / "cell.yaml")
    (out / "recording.csv").write_bytes(b"")
    rc, _, err = _cli("run", "--resume", str(out), "--no-progress")
    assert rc == 2 and "recording.csv:1: an empty file, nothing to resume" in err, err
    assert f"adaptive-cal run --robot {out / 'cell.yaml'} --out {out}" in err
    rc, _, err = _cli("run", "--robot", str(cell), "--out", str(out), "--no-progress")
    assert rc in (0, 1), err
    assert json.loads((out / "result.json").read_text())["touches"] == BUDGET
    assert (out / "recording.csv").read_text().startswith("# adaptive-cal recording v1")


def test_a_temporary_file_a_kill_left_is_removed_by_the_next_run(finished, tmp_path):
    out = _copy(finished, tmp_path)
    dead = out / ".surface.png.4194399.84813b4f.tmp"  # above Linux's largest pid: no process
    live = out / f".report.html.{os.getpid()}.0123abcd.tmp"  # a writer still at work
    mine = out / "notes.4194399.84813b4f.tmp"  # not a name the writer makes
    for f in (dead, live, mine):
        f.write_bytes(b"x")
    _cli("run", "--resume", str(out), "--no-progress")
    assert not dead.exists() and live.exists() and mine.exists()


def test_a_recording_read_with_another_probe_zero_says_so(finished, tmp_path):
    """An outside audit: a run's recording read with the Cheng cell gave other figures, exit 0,
    without a word. Away from its run folder (whose cell.yaml is compared in full) the
    recording's own probe_zero_mm line is: another zero is said; a cell's name is a label."""
    from helpers import ROOT

    rec = tmp_path / "recording.csv"  # outside its folder: no cell.yaml beside it to compare
    shutil.copyfile(finished / "run" / "recording.csv", rec)
    rc, _, err = _cli("flatness", str(rec), "--robot", str(ROOT / "configs" / "cheng2025-cell.yaml"))
    assert "recorded with probe_zero_mm 5, read with" in err, err
    rc, _, err = _cli("flatness", str(rec), "--robot", str(finished / "cell.yaml"))
    assert "probe_zero_mm" not in err, err
    cheng = ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"  # no such line
    rc, _, err = _cli("flatness", str(cheng), "--robot", str(ROOT / "configs" / "cheng2025-cell.yaml"))
    assert rc == 0 and "probe_zero_mm" not in err, err
