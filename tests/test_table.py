"""Readings from another tool (formats/table.py): a plain table of x, y and a reading or height
is read as the recording it stands for. Oracle: the same touches written as a v1 recording give
the same arrays and the same flatness figures."""
import numpy as np
import pytest

from adaptive_cal.analysis.flatness_intervals import recording_flatness
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording

XY = [(0, 0), (100, 0), (0, 100), (100, 100), (50, 50), (25, 75)]
VALUES = [1.0, 1.1, 1.2, 1.25, 1.2, 1.17]


def _v1(path, z=None):
    z = z or [0.0] * len(XY)
    rows = [f"{i},,{x},{y},{zz},{v}" for i, ((x, y), v, zz) in enumerate(zip(XY, VALUES, z))]
    path.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n"
                    + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("header", ["x_mm,y_mm,reading_mm", "X,Y,Height", "y_mm,note,x_mm,height_mm"])
def test_a_table_reads_as_the_recording_it_stands_for(tmp_path, header):
    names = [h.strip().lower() for h in header.split(",")]
    lines = [header]
    for (x, y), v in zip(XY, VALUES):
        cells = {"x_mm": x, "x": x, "y_mm": y, "y": y, "note": "ok"}
        lines.append(",".join(str(cells.get(n, v)) for n in names))
    table = tmp_path / "t.csv"
    table.write_text("\n".join(lines) + "\n")
    got, want = read_recording(table), read_recording(_v1(tmp_path / "r.csv"))
    for k in ("seq", "x_mm", "y_mm", "z_mm", "reading_mm"):
        assert np.array_equal(getattr(got, k), getattr(want, k)), k
    a = recording_flatness(table, np.random.default_rng(0), 50)[0]
    b = recording_flatness(tmp_path / "r.csv", np.random.default_rng(0), 50)[0]
    assert a["flatness_mm"] == b["flatness_mm"] and a["tilt"] == b["tilt"]


def test_a_reading_with_its_approach_height_is_a_recording_without_the_first_line(tmp_path):
    z = [0.5, -0.2, 0.0, 0.3, 0.1, 0.0]
    rec = _v1(tmp_path / "r.csv", z)
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(rec.read_text().splitlines()[1:]) + "\n")
    got = read_recording(bare)
    assert np.array_equal(got.z_mm, z) and np.array_equal(got.reading_mm, VALUES)


@pytest.mark.parametrize("row, says", [("100,abc,1.1", "t.csv:3: column y_mm: 'abc'"),
                                       ("100,0,nan", "t.csv:3: column reading_mm"),
                                       ("100,0", "t.csv:3: column reading_mm: ''"),
                                       ("1e12,0,1", "t.csv:3: column x_mm")])
def test_bad_table_values_are_refused_naming_line_and_column(tmp_path, row, says):
    table = tmp_path / "t.csv"
    table.write_text(f"x_mm,y_mm,reading_mm\n0,0,1\n{row}\n")
    with pytest.raises(ValueError, match=says.replace("(", r"\(")):
        read_recording(table)


def test_a_csv_that_is_neither_says_both_forms(tmp_path, capsys):
    other = tmp_path / "o.csv"
    other.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(RecordingError, match="first line must be"):
        read_recording(other)
    assert main(["flatness", str(other)]) == 2
    err = capsys.readouterr().err
    assert "x_mm, y_mm and reading_mm or height_mm" in err and "Traceback" not in err


def test_flatness_of_a_table_from_the_command_line(tmp_path, capsys):
    table = tmp_path / "t.csv"
    table.write_text("x_mm,y_mm,reading_mm\n" + "\n".join(
        f"{x},{y},{v}" for (x, y), v in zip(XY, VALUES)) + "\n")
    assert main(["flatness", str(table)]) == 0
    out = capsys.readouterr().out
    assert "flatness of the 6 touched points" in out


def test_a_bad_value_is_named_by_its_column_as_the_header_names_it(tmp_path):
    """An outside audit (2026-12-01): the header said y_mm, the message 'column y'."""
    table = tmp_path / "t.csv"
    table.write_text("X,Y,Height\n0,0,1\n100,abc,1.1\n")
    with pytest.raises(ValueError, match="t.csv:3: column y: 'abc'"):
        read_recording(table)


def test_heights_in_um_in_a_mm_column_are_warned_about(tmp_path):
    """An outside audit (2026-12-01): a table of heights in um, read as mm, gave a 62 deg tilt
    and no word about units."""
    table = tmp_path / "um.csv"
    table.write_text("x_mm,y_mm,height_mm\n0,0,0\n100,0,15.3\n0,100,22.1\n100,100,40.2\n")
    notes = read_recording(table).notes
    assert any("column height_mm: the heights' least-squares plane tilts 16.1 deg" in n
               and "um in a mm column?" in n for n in notes), notes
    table.write_text("x_mm,y_mm,height_mm\n0,0,0\n100,0,0.0153\n0,100,0.0221\n100,100,0.0402\n")
    assert not any("tilts" in n for n in read_recording(table).notes)


def test_a_levelled_plate_in_um_and_flagged_rows_are_judged_right(tmp_path):
    """A second audit: a levelled plate's 30 um bow written in um was read as 31 mm of flatness
    with no word (its plane tilts under 5 deg); a mm table whose two rejected rows (not used)
    lay far off was warned about as um."""
    table = tmp_path / "lev.csv"
    rows = [(x, y, 30.0 * (1 - ((x - 200) / 200) ** 2)) for x in range(0, 401, 50)
            for y in (0, 100, 200)]
    table.write_text("x_mm,y_mm,height_mm\n" + "".join(f"{x},{y},{h}\n" for x, y, h in rows))
    assert any("stray 30 mm from their least-squares plane" in n for n in
               read_recording(table).notes), read_recording(table).notes
    table.write_text("x_mm,y_mm,height_mm\n" + "".join(f"{x},{y},{h / 1000}\n"
                                                        for x, y, h in rows))
    assert not any("um in a mm column" in n for n in read_recording(table).notes)
    flagged = tmp_path / "flagged.csv"
    good = [f"{x},{y},{0.001 * x},\n" for x in (0, 10, 20) for y in (0, 10, 20)]
    flagged.write_text("x_mm,y_mm,height_mm,flags\n" + "".join(good)
                       + "5,5,3.0,rejected\n15,15,-3.0,gated\n")
    assert not any("um in a mm column" in n for n in read_recording(flagged).notes)
