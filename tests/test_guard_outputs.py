"""report, explain and compensate never write an output over one of their inputs or over a run folder's
measurement (recording.csv, result.json, belief.npz, cell.yaml): refused naming the option and
the file, and the file is left byte for byte as it was."""
import os
import shutil
from pathlib import Path

import pytest

from adaptive_cal.cli import main

ROOT = Path(__file__).resolve().parents[1]
REC = ("# adaptive-cal recording v1\n# probe_zero_mm: 5.0\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,flags\n"
       + "".join(f"{i},{i}.0,{x},{y},0,{5 + 0.001 * i:.6f},\n"
                 for i, (x, y) in enumerate([(-200, -160), (0, -160), (200, -160), (-200, 160),
                                             (0, 160), (200, 160)])))


@pytest.fixture
def folder(tmp_path):
    run = tmp_path / "run1"
    run.mkdir()
    (run / "recording.csv").write_text(REC)
    shutil.copyfile(ROOT / "configs" / "sim-cell.yaml", run / "cell.yaml")
    (run / "result.json").write_text('{"touches": 6}\n')
    (run / "belief.npz").write_bytes(b"PK\x05\x06" + bytes(18))
    (tmp_path / "rec.csv").write_text(REC)
    shutil.copyfile(ROOT / "configs" / "sim-cell.yaml", tmp_path / "cell.yaml")
    shutil.copyfile(ROOT / "configs" / "engrave-example.gcode", tmp_path / "prog.gcode")
    return tmp_path


def _contents(d: Path) -> dict:
    return {p: p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("argv, option, target", [
    (["report", "run1", "--out", "run1/recording.csv"], "--out", "run1/recording.csv"),
    (["report", "run1", "--out", "run1/result.json"], "--out", "run1/result.json"),
    (["report", "run1", "--out", "run1/belief.npz"], "--out", "run1/belief.npz"),
    (["report", "run1", "--out", "run1/../run1/cell.yaml"], "--out", "run1/cell.yaml"),
    (["report", "run1", "--out", "run1/explain.json"], "--out", "run1/explain.json"),
    (["report", "rec.csv", "--robot", "cell.yaml", "--out", "rec.csv"], "--out", "rec.csv"),
    (["report", "rec.csv", "--robot", "cell.yaml", "--out", "./cell.yaml"], "--out", "cell.yaml"),
    (["report", "run1/recording.csv", "--robot", "cell.yaml", "--out", "run1/result.json"],
     "--out", "run1/result.json"),
    (["explain", "rec.csv", "--robot", "cell.yaml", "--json", "rec.csv"], "--json", "rec.csv"),
    (["explain", "rec.csv", "--robot", "cell.yaml", "--json", "cell.yaml"], "--json", "cell.yaml"),
    (["explain", "run1/recording.csv", "--robot", "cell.yaml", "--json", "run1/result.json"],
     "--json", "run1/result.json"),
    # --out DIR writes DIR/<cell>-explained.yaml: here that is the recording
    (["explain", "cell-explained.yaml", "--robot", "cell.yaml", "--out", "."], "--out",
     "cell-explained.yaml"),
    # compensate: the program, and the map's run folder (one refusal for all three commands)
    (["compensate", "prog.gcode", "--map", "run1", "--out", "prog.gcode"], "--out", "prog.gcode"),
    (["compensate", "prog.gcode", "--map", "run1", "--out", "run1/recording.csv"], "--out",
     "run1/recording.csv"),
    (["compensate", "--map", "run1", "--grid", "run1/cell.yaml"], "--grid", "run1/cell.yaml"),
])
def test_an_output_over_an_input_is_refused_and_nothing_changes(folder, argv, option, target,
                                                                capsys, monkeypatch):
    monkeypatch.chdir(folder)
    if "cell-explained.yaml" in argv:
        shutil.copyfile("rec.csv", "cell-explained.yaml")
    before = _contents(folder)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {option} " in err and "Traceback" not in err
    assert f"{os.path.normpath(target)} itself" in err
    assert _contents(folder) == before


def test_a_hard_link_to_the_recording_is_the_recording(folder, capsys, monkeypatch):
    monkeypatch.chdir(folder)
    os.link("rec.csv", "link.csv")
    before = _contents(folder)
    assert main(["explain", "rec.csv", "--robot", "cell.yaml", "--json", "link.csv"]) == 2
    assert "--json link.csv is rec.csv itself" in capsys.readouterr().err
    assert _contents(folder) == before


def test_explain_out_that_is_a_file_is_refused(folder, capsys, monkeypatch):
    monkeypatch.chdir(folder)
    before = _contents(folder)
    assert main(["explain", "rec.csv", "--robot", "cell.yaml", "--out", "rec.csv"]) == 2
    assert "--out rec.csv is a file" in capsys.readouterr().err
    assert _contents(folder) == before
