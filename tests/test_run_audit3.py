"""What an outside audit of `run` when things fail found (2026-11-29): a budget spent with a
bound's other terms open exited 0, --out overwrote a user's own cell.yaml and figures, a full disk
lost a taken reading without a word, --resume on a folder without a recording named cell.yaml,
and SIGTERM ended a run silently."""
import errno
import os
import signal

import pytest

from adaptive_cal.cli import main
from adaptive_cal.formats.writing import RecordingWriter
from adaptive_cal.report.status import exit_status, missing
from adaptive_cal.run import session

from helpers import SIM_CELL


def _result(**over):
    r = {"stopped_because": "touch_budget", "touches": 40,
         "bound": {"mean_std_mm": 0.004, "max_std_mm": None, "max_touches": 40,
                   "max_gap_mm": None, "min_touches": 30},
         "posterior": {"mean_std_mm": 0.0035, "max_std_mm": 0.009},
         "largest_gap": {"radius_mm": 60.0}, "model": {"adequate": True}}
    for k, v in over.items():
        r[k] = {**r[k], **v} if isinstance(v, dict) else v
    return r


def test_a_budget_spent_with_any_term_of_the_bound_open_is_not_a_result():
    assert missing(_result()) is None and exit_status(_result()) == 0
    gap = _result(bound={"max_gap_mm": 20.0})
    assert "largest gap between touches 60 mm radius against the 20 mm bound" in missing(gap)
    floor = _result(touches=25)
    assert "25 touches, fewer than the 30 a bound needs" in missing(floor)
    checks = _result(model={"adequate": False})
    assert "self-checks fail" in missing(checks)
    assert {exit_status(r) for r in (gap, floor, checks)} == {1}
    # a result.json of before the floor was written keeps its old reading
    old = _result()
    del old["bound"]["min_touches"]
    assert missing(old) is None


def test_out_never_overwrites_a_users_own_files_of_a_runs_names(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    for name in ("cell.yaml", "surface.png"):
        (out / name).write_text("my own notes")
    rc = main(["run", "--robot", str(SIM_CELL), "--out", str(out), "--no-progress"])
    assert rc == 2
    assert "holds cell.yaml, surface.png, which a run writes" in capsys.readouterr().err
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "cell.yaml": "my own notes", "surface.png": "my own notes"}


def test_resume_on_a_folder_without_a_recording_says_nothing_to_resume(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["run", "--resume", str(tmp_path / "empty")]) == 2
    assert "no recording.csv there, nothing to resume" in capsys.readouterr().err


def test_a_row_that_cannot_be_written_is_said_with_its_values(tmp_path, monkeypatch):
    writer = RecordingWriter(tmp_path / "recording.csv")
    writer.append(seq=0, t_s=0.0, x_mm=1.0, y_mm=2.0, z_mm=0.0, reading_mm=5.0)

    def full(fd):
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError) as e:
        writer.append(seq=1, t_s=4.0, x_mm=10.5, y_mm=-3.0, z_mm=0.0, reading_mm=5.0123)
    writer.close()  # the unwritten buffer is not raised a second time
    assert e.value.filename == str(tmp_path / "recording.csv")
    assert "touch seq 1 could not be written (File too large)" in e.value.strerror
    assert "1,4.000,10.5000,-3.0000,0.0000,5.012300" in e.value.strerror
    assert "--resume" in e.value.strerror


def test_sigterm_stops_a_run_after_its_touch_as_ctrl_c_does():
    hits = []
    guard = signal.signal(signal.SIGTERM, lambda *a: hits.append(1))  # never the default: kill
    try:
        outer = signal.getsignal(signal.SIGTERM)
        with session._deferred_interrupt() as flag:
            os.kill(os.getpid(), signal.SIGTERM)
            assert flag["stop"] and not hits  # no exception: the loop stops after this touch
        assert signal.getsignal(signal.SIGTERM) is outer
    finally:
        signal.signal(signal.SIGTERM, guard)


def test_the_cli_keeps_pymodbus_reconnect_lines_off_stderr(tmp_path, capsys):
    import logging

    logging.getLogger("pymodbus").setLevel(logging.NOTSET)
    main(["flatness", str(tmp_path / "none.csv")])  # any command sets up the CLI's logging
    capsys.readouterr()
    assert logging.getLogger("pymodbus").getEffectiveLevel() == logging.CRITICAL


def test_a_row_a_full_disk_kept_out_is_written_back_by_the_resume(tmp_path):
    """An outside audit (2026-12-01): with the disk full half-way through a row, the error
    printed the row, but --resume dropped its cut start and wrote the next touch under its seq:
    the reading was lost. Now the row is kept whole beside the recording and written back."""
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.formats.writing import repair_cut_row_said, unwritten_file

    path = tmp_path / "recording.csv"
    writer = RecordingWriter(path)
    writer.append(seq=0, t_s=0.0, x_mm=1.0, y_mm=2.0, z_mm=0.0, reading_mm=5.0)
    real = writer._file.write

    def half_then_full(text):
        real(text[:len(text) // 2])
        writer._file.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    writer._file.write = half_then_full
    with pytest.raises(OSError) as e:
        writer.append(seq=1, t_s=4.0, x_mm=10.5, y_mm=-3.0, z_mm=0.0, reading_mm=5.0123)
    writer._file.write = real
    writer.close()
    assert f"kept in {unwritten_file(path)}" in e.value.strerror
    assert not path.read_text().endswith("\n")  # the cut start of the row is in the file
    said = repair_cut_row_said(path)
    assert "1 row a full disk had kept out of it written back" in said
    rec = read_recording(path)
    assert list(rec.seq) == [0, 1] and rec.reading_mm[1] == 5.0123 and rec.x_mm[1] == 10.5
    assert not unwritten_file(path).exists()
    assert repair_cut_row_said(path) is None  # once
