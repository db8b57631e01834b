"""A bare recording replayed with a cell file (flatness/report --robot) is judged as the live
run judges a reading: one outside probe.usable_mm is not used (counted and said with its line),
a touch outside the workplane is refused naming its line and value, one inside a keep-out is
used and said, and no RuntimeWarning reaches the user."""
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from adaptive_cal.cli import main

ROOT = Path(__file__).resolve().parents[1]
CELL = str(ROOT / "configs" / "sim-cell.yaml")  # usable_mm [0.5, 9.5], workplane x +-225
XY = [(x, y) for y in (-150, -75, 0, 75, 150) for x in (-200, -100, 0, 100, 200)]


def _write(path, change=None, flags=None, xy=XY):
    rows = []
    for i, (x, y) in enumerate(xy):
        reading = 5.0 + 0.014 * x + 0.002 * y + 0.1 * (y / 150) ** 2 + 0.001 * np.sin(3 * i)
        rows.append([str(i), f"{3.0 * i:.3f}", f"{x:.4f}", f"{y:.4f}", "0.0000",
                     f"{reading:.6f}", "", "0"])
    for i, column, value in change or []:
        rows[i][column] = value
    for i, value in (flags or {}).items():
        rows[i][6] = value
    path.write_text("# adaptive-cal recording v1\n# probe_zero_mm: 5.0\n"
                    "seq,t_s,x_mm,y_mm,z_mm,reading_mm,flags,round\n"
                    + "".join(",".join(r) + "\n" for r in rows))
    return path


def _flatness(path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would fail the command here
        rc = main(["flatness", str(path), "--robot", CELL, "--json", "--samples", "20"])
    out = capsys.readouterr()
    return rc, (json.loads(out.out) if rc == 0 else None), out.err


def test_a_reading_the_probe_cannot_give_is_not_used_and_said(tmp_path, capsys):
    rc, good, _ = _flatness(_write(tmp_path / "good.csv", [(7, 5, "9.400000")]), capsys)
    assert rc == 0
    path = _write(tmp_path / "rec.csv", [(7, 5, "999"), (7, 5, "999")])
    rc, out, err = _flatness(path, capsys)
    assert rc == 0 and "Warning" not in err
    assert out["touches"] == len(XY) - 1  # the 999 is not among the touched points
    assert "1 reading outside the probe's usable stroke [0.5, 9.5] mm" in err
    assert "line 11 (seq 7: 999 mm)" in err  # 3 lines above the first row
    assert abs(out["tilt"]["ry_deg"]) < 1.0 and out["flatness_mm"]["least_squares"]["value"] < 0.2
    assert good["touches"] == len(XY)  # 9.4 mm is usable: used


def test_a_touch_outside_the_workplane_is_refused_with_its_line(tmp_path, capsys):
    rc, _, err = _flatness(_write(tmp_path / "rec.csv", [(4, 2, "9999")]), capsys)
    assert rc == 2 and "Traceback" not in err
    assert "rec.csv:8: touch seq 4: column x_mm = 9999 lies outside the workplane x_mm" in err


def test_a_row_the_run_already_flagged_is_left_as_flagged(tmp_path, capsys):
    path = _write(tmp_path / "rec.csv", [(4, 2, "9999"), (6, 5, "0.000000")],
                  {4: "invalid;rejected", 6: "rejected;stroke_end"})
    rc, out, err = _flatness(path, capsys)
    assert rc == 0 and out["touches"] == len(XY) - 2 and "usable stroke" not in err
    assert path.read_text().count("9999") == 1  # the file is never changed


def test_report_replays_with_the_same_judgement(tmp_path, capsys):
    path = _write(tmp_path / "rec.csv", [(7, 5, "999")])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["report", str(path), "--robot", CELL, "--out", str(tmp_path / "r.html")]) == 0
    err = capsys.readouterr().err
    assert "line 11 (seq 7: 999 mm)" in err
    _write(path, [(4, 3, "-9999")])
    assert main(["report", str(path), "--robot", CELL, "--out", str(tmp_path / "s.html")]) == 2
    assert "rec.csv:8: touch seq 4: column y_mm = -9999 lies outside" in capsys.readouterr().err
    assert not (tmp_path / "s.html").exists()


@pytest.mark.parametrize("column, offset", [("height_mm", 0.0), ("reading_mm", 5.0)])
def test_a_table_of_heights_is_not_judged_as_indications(tmp_path, column, offset, capsys):
    path = tmp_path / "t.csv"  # heights around 0 mm: outside [0.5, 9.5] as indications
    path.write_text(f"x_mm,y_mm,{column}\n" + "".join(
        f"{x},{y},{offset + 0.014 * x + 0.002 * y + 0.1 * (y / 150) ** 2:.6f}\n" for x, y in XY))
    rc, out, err = _flatness(path, capsys)
    assert rc == 0 and out["touches"] == len(XY) and "usable stroke" not in err


def test_a_touch_inside_a_keep_out_is_used_and_said_with_its_line(tmp_path, capsys):
    """The sim cell's clamp is x -40..10, y 60..110 mm: a recording touching (0, 75) is not of a
    run of this cell (an outside audit, 2026-11-29: replayed with no word). The reading is real,
    so it is used; the warning names its line, seq, place and the keep-out."""
    rc, out, err = _flatness(_write(tmp_path / "rec.csv"), capsys)  # (0, 75) is seq 17
    assert rc == 0 and out["touches"] == len(XY)
    assert ("rec.csv:21: touch seq 17 at (0, 75) mm lies inside keep_outs[0] of " in err
            and "(1 such touch, used): a run of this cell never touches there" in err)
    moved = [(x, y) if (x, y) != (0, 75) else (100, 110) for x, y in XY]
    rc, _, err = _flatness(_write(tmp_path / "free.csv", xy=moved), capsys)
    assert rc == 0 and "keep_outs" not in err

