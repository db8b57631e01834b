"""--resume DIR --robot CELL.yaml: CELL must be the cell DIR was mapped with in everything that
changes the map or the touches (refused naming the keys, nothing in DIR changed); keys that do
not (the name, the stopping rule, how the robot is reached) may differ. A folder whose
belief.npz is not the map its cell.yaml gives is refused by flatness and report with a message,
not a numpy error; its recording replayed with another cell (--robot) is warned about."""
import contextlib
import io
from pathlib import Path

import pytest
import yaml

from adaptive_cal.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _cell(tmp_path, filename, **changes):
    cell = yaml.safe_load((ROOT / "configs" / "sim-cell.yaml").read_text())
    cell["plan"].update(candidates=500, refine=0, stop={"mean_std_mm": 0.001, "max_touches": 6})
    for key, value in changes.items():
        block, _, leaf = key.rpartition(".")
        target = cell
        for part in block.split(".") if block else []:
            target = target.setdefault(part, {})
        target[leaf] = value
    path = tmp_path / filename
    path.write_text(yaml.safe_dump(cell))
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("resume")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", "--robot", str(_cell(d, "cell.yaml")), "--out", str(d / "run"),
                     "--no-progress"]) == 1  # 6 touches, the 1 um bound unmet: not a result
    return d / "run"


def _files(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if p.is_file()}


@pytest.mark.parametrize("changes, keys", [
    ({"workplane.x_mm": [-100, 100]}, ["workplane.x_mm"]),
    ({"probe.zero_mm": 4.0, "probe.usable_mm": [1, 9]}, ["probe.usable_mm", "probe.zero_mm"]),
    ({"model.knots_x": 5}, ["model.knots_x"]),
    ({"simulation.seed": 99}, ["simulation.seed"]),
])
def test_another_cell_on_resume_is_refused_naming_the_keys(run_dir, tmp_path, changes, keys,
                                                           capsys):
    before = _files(run_dir)
    other = _cell(tmp_path, "other.yaml", **changes)
    assert main(["run", "--resume", str(run_dir), "--robot", str(other), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "not the cell" in err and "resume without --robot" in err and "Traceback" not in err
    for key in keys:
        assert f"{key}: " in err
    assert _files(run_dir) == before


def test_a_cell_differing_only_in_what_changes_no_map_resumes(run_dir, tmp_path, capsys):
    d = tmp_path / "run"
    d.mkdir()
    for name, data in _files(run_dir).items():
        (d / name).write_bytes(data)
    cell_before = (d / "cell.yaml").read_bytes()
    rows_before = (d / "recording.csv").read_text().splitlines()
    more = _cell(tmp_path, "more.yaml", name="renamed", **{"plan.stop": {"mean_std_mm": 0.001,
                                                                      "max_touches": 8},
                                                          "robot.speed_mm_per_s": 300})
    assert main(["run", "--resume", str(d), "--robot", str(more), "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert "differs from" in out and "name, plan.stop.max_touches, robot.speed_mm_per_s" in out
    rows = (d / "recording.csv").read_text().splitlines()
    assert rows[: len(rows_before)] == rows_before and len(rows) == len(rows_before) + 2
    assert (d / "cell.yaml").read_bytes() == cell_before


def test_a_belief_that_is_not_its_cells_map_is_refused_by_flatness_and_report(run_dir, tmp_path,
                                                                            capsys):
    d = tmp_path / "run"
    d.mkdir()
    for name, data in _files(run_dir).items():
        (d / name).write_bytes(data)
    cell = yaml.safe_load((d / "cell.yaml").read_text())
    cell["model"]["knots_x"] = 5
    (d / "cell.yaml").write_text(yaml.safe_dump(cell))
    for argv in (["flatness", str(d / "recording.csv")], ["report", str(d)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{d / 'belief.npz'} does not match {d / 'cell.yaml'}" in err
        assert "--robot CELL.yaml" in err and "matmul" not in err
    assert not (d / "report.html").exists()


def test_a_run_folders_recording_replayed_with_another_cell_says_so(tmp_path, capsys):
    cell = _cell(tmp_path, "a.yaml")
    out = tmp_path / "run"
    assert main(["run", "--robot", str(cell), "--out", str(out), "--no-progress"]) == 1
    capsys.readouterr()
    rec = out / "recording.csv"
    other = _cell(tmp_path, "b.yaml", **{"probe.zero_mm": 5.01})
    renamed = _cell(tmp_path, "c.yaml", name="renamed", **{"plan.stop.max_touches": 60})
    assert main(["flatness", str(rec), "--robot", str(other), "--samples", "20"]) == 0
    err = capsys.readouterr().err
    assert f"--robot {other} differs from it in what changes the map (probe.zero_mm)" in err
    assert "not the run's" in err
    for same in (out / "cell.yaml", renamed):  # its own cell, or one that maps the same
        assert main(["flatness", str(rec), "--robot", str(same), "--samples", "20"]) == 0
        assert "warning" not in capsys.readouterr().err
    assert main(["report", str(rec), "--robot", str(other), "--out",
                 str(tmp_path / "r.html")]) == 0
    assert "differs from it in what changes the map (probe.zero_mm)" in capsys.readouterr().err


def _edited(run_dir, tmp_path, name, edit_rows=None, edit_cell=None):
    import shutil

    d = tmp_path / name
    shutil.copytree(run_dir, d)
    if edit_rows is not None:
        rec = d / "recording.csv"
        lines = rec.read_text().splitlines(keepends=True)
        header = next(i for i, ln in enumerate(lines) if ln.startswith("seq,"))
        rec.write_text("".join(edit_rows(lines, header)))
    if edit_cell is not None:
        cell = d / "cell.yaml"
        cell.write_text(edit_cell(cell.read_text()))
    return d


def _cells(line, col, value):
    cells = line.rstrip("\n").split(",")
    cells[col] = value
    return ",".join(cells) + "\n"


@pytest.mark.parametrize("name, edit_rows, edit_cell, said", [
    ("offplate", lambda ls, h: ls[:h + 3] + [_cells(ls[h + 3], 2, "300.0000")] + ls[h + 4:],
     None, ":{line}: touch seq 2 is a fused reading that the run could not have fused"),
    ("stroke", lambda ls, h: ls[:h + 3] + [_cells(ls[h + 3], 5, "9.900000")] + ls[h + 4:],
     None, "reading_mm = 9.9 is outside the probe's usable stroke"),
    ("swapped", lambda ls, h: ls[:h] + [ls[h].replace("x_mm,y_mm", "y_mm,x_mm")] + ls[h + 1:],
     None, "recording.csv"),  # off the workplane or not the map's rows: either refused
    ("deleted", lambda ls, h: ls[:h + 2] + ls[h + 3:], None, "it holds 5 rows, the map 6"),
    ("value", lambda ls, h: ls[:h + 2] + [_cells(ls[h + 2], 5, "5.123456")] + ls[h + 3:],
     None, "with other values in them"),
    ("zero", None, lambda t: t.replace("zero_mm: 5.0", "zero_mm: 5.3"),
     "recorded with probe_zero_mm 5, but the cell resumed has probe.zero_mm 5.3"),
])
def test_a_recording_the_run_could_not_have_made_is_not_resumed(run_dir, tmp_path, capsys, name,
                                                                 edit_rows, edit_cell, said):
    """An outside audit (2026-12-01): --resume fused a touch typed off the workplane, a reading
    outside the stroke, a header with x and y swapped, and the folder's cell.yaml given another
    probe zero (true error 0.3 to 2 mm afterwards, the robot moving on that map), where report
    and flatness refuse the same folder. Refused now before anything is sent, naming the line;
    nothing in the folder changes."""
    d = _edited(run_dir, tmp_path, name, edit_rows, edit_cell)
    before = _files(d)
    assert main(["run", "--resume", str(d), "--no-progress"]) == 2
    err = capsys.readouterr().err
    lines = (d / "recording.csv").read_text().splitlines()
    line = next(i for i, ln in enumerate(lines) if ln.startswith("seq,")) + 4  # 1-based, row 2
    assert said.format(line=line) in err and "nothing was sent" in err, err
    assert "Traceback" not in err and _files(d) == before


def test_keys_that_move_the_frame_or_scale_a_length_may_not_differ_on_resume():
    """An outside audit (2026-12-02): robot.hses.offset_mm 50 um lower on a resume was accepted
    as changing nothing; every new touch read 50 um off and the run ended in 'drift'."""
    from adaptive_cal.cli.run_guards import _differ

    was = {"robot.hses.offset_mm": [0, 0, 0], "robot.hses.host": "10.0.0.2",
           "robot.modbus.scale": 10000, "robot.hses.user_frame": 1, "name": "a"}
    now = {"robot.hses.offset_mm": [0, 0, -0.05], "robot.hses.host": "10.0.0.3",
           "robot.modbus.scale": 1000, "robot.hses.user_frame": 2, "name": "b"}
    bad, fine = _differ(was, now)
    assert bad == ["robot.hses.offset_mm", "robot.hses.user_frame", "robot.modbus.scale"]
    assert fine == ["name", "robot.hses.host"]
