"""Messages that point the right way: report on a bare recording suggests --robot CELL.yaml
(its folder is not a run folder); on a run folder's recording.csv, the folder. --prior-from
that is no run folder is said so, without an OS error's text, and nothing is created."""
import shutil
from pathlib import Path

import pytest

from adaptive_cal.cli import main

ROOT = Path(__file__).resolve().parents[1]
CELL = str(ROOT / "configs" / "sim-cell.yaml")
REC = ("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n"
       "0,,-200,-160,0,5.1\n1,,200,-160,0,5.2\n2,,0,160,0,5.3\n3,,100,0,0,5.2\n")


def test_report_on_a_bare_recording_suggests_the_cell_file(tmp_path, capsys):
    (tmp_path / "rec").mkdir()
    path = tmp_path / "rec" / "g2.csv"
    path.write_text(REC)
    assert main(["report", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"adaptive-cal report {path} --robot CELL.yaml" in err
    assert f"adaptive-cal report {tmp_path / 'rec'}," not in err  # not a run folder
    assert f"adaptive-cal report {tmp_path / 'rec'})" not in err


def test_report_on_a_run_folders_recording_suggests_the_folder(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "recording.csv").write_text(REC)
    shutil.copyfile(CELL, tmp_path / "run" / "cell.yaml")
    assert main(["report", str(tmp_path / "run" / "recording.csv")]) == 2
    assert f"(adaptive-cal report {tmp_path / 'run'})" in capsys.readouterr().err


@pytest.mark.parametrize("prior, said", [
    ("nothere", "--prior-from nothere: no such run folder"),
    ("afile.csv", "--prior-from afile.csv: a file, not a run folder"),
    ("empty", "--prior-from empty: it has no result.json"),  # the proposed correction's
    ("nores", "--prior-from nores: it has no result.json"),
    ("nomap", "--prior-from nomap: not a run folder with a map, it has no belief.npz"),
])
def test_prior_from_that_is_no_run_folder_is_said_plainly(tmp_path, monkeypatch, capsys, prior,
                                                          said):
    monkeypatch.chdir(tmp_path)
    Path("afile.csv").write_text(REC)
    Path("empty").mkdir()
    Path("nores").mkdir()
    Path("nores/belief.npz").write_bytes(b"")
    Path("nomap").mkdir()
    Path("nomap/result.json").write_text("{}")
    assert main(["run", "--robot", CELL, "--out", "new", "--prior-from", prior,
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert said in err and "Errno" not in err and "FileNotFoundError" not in err
    assert not Path("new").exists()
