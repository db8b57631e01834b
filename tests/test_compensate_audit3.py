"""What an outside audit of compensate against the RS274NGC reading and a peer parser (pygcode)
found (2026-11-29): a G1 beside a G4 was read as a rapid (a cut not split, 255 um off the map),
a compensated program was compensated again (heights twice), a G64 P beyond the tolerance, a '%'
inside a line, CR-only CSVs, CSV line numbers after a quoted line break, CR-only G-code written
back with LF, a --mark column written twice, non-ASCII digits and spaces, and ';' / '%' inside
the marks' comments."""
import numpy as np
import pytest

from adaptive_cal.analysis import compensate as cp
from adaptive_cal.formats.toolpath import ToolpathError, read_toolpath, write_toolpath

PLATE = ((-200.0, 200.0), (-150.0, 150.0))


def _wavy(x, y):
    x = np.asarray(x, float)
    return 0.05 * np.sin(x / 30.0), np.full(x.shape, 0.001)


def test_a_motion_code_beside_a_dwell_sets_the_mode_and_the_cut_is_split():
    text = "G21 G90\nG0 Z5.\nG0 X-150. Y-100.\nG0 Z-0.1\nG1 G4 P0.5 F300\nX150. Y100. Z-0.1\n"
    path = read_toolpath(text, "p")
    assert path.moves[-1].cut  # G1 on the dwell's line is the mode of the next line
    res = cp.compensate(path, _wavy, PLATE, 0.01, top_mm=0.05, name="p")
    assert res.added > 10


def test_an_end_on_a_dwell_line_ends_the_program():
    with pytest.raises(ToolpathError, match="line 4: a move after the program's end"):
        read_toolpath("G21 G90\nG0 X0 Y0 Z1\nG4 P1 M2\nG0 X10.\n", "p")


def test_a_compensated_program_is_known_for_one():
    path = read_toolpath("G21 G90\nG0 X0 Y0 Z1\n", "p")
    res = cp.compensate(path, _wavy, PLATE, 0.01, top_mm=0.05, name="p")
    out = write_toolpath(path, res.pieces, header_comment="adaptive-cal 0.1.0 compensate, now")
    assert read_toolpath(out, "o").compensated == (1, "(adaptive-cal 0.1.0 compensate, now)")
    assert read_toolpath("G21 G90\n(my compensate notes)\nG0 X0 Y0 Z1\n", "p").compensated is None


def test_g64_blending_is_read_with_its_largest_tolerance():
    path = read_toolpath("G21 G90 G64 P0.005\nG64 P0.01 Q0.05\nG0 X0 Y0 Z1\n", "p")
    assert path.blend == (2, 0.05)
    assert read_toolpath("G21 G90 G64\nG0 X0 Y0 Z1\n", "p").blend == (1, 0.0)


@pytest.mark.parametrize("line", ["G1 X100. % Y-100.", "G1 X100. %"])
def test_a_tape_mark_inside_a_line_is_refused(line):
    with pytest.raises(ToolpathError, match="line 3: '%' inside a line"):
        read_toolpath(f"%\nG21 G90\n{line}\n%\n", "p")


@pytest.mark.parametrize("line, shown", [("G1 X\u0661\u0660\u0660.", "X\u0661"),
                                         ("G1\u00a0X100.", "\\xa0")])
def test_non_ascii_digits_and_spaces_are_refused(line, shown):
    with pytest.raises(ToolpathError, match="line 2: cannot read") as e:
        read_toolpath(f"G21 G90\n{line}\n", "p")
    assert shown in str(e.value)


def test_a_csv_with_cr_line_ends_is_read_and_bad_rows_are_named_by_their_file_line():
    path = read_toolpath("x_mm,y_mm,z_mm\r0,0,-0.1\r10,0,-0.1\r", "cr.csv")
    assert [m.end for m in path.moves] == [(0.0, 0.0, -0.1), (10.0, 0.0, -0.1)]
    assert write_toolpath(path, {}) == "x_mm,y_mm,z_mm\r0,0,-0.1\r10,0,-0.1\r"
    quoted = 'x_mm,y_mm,z_mm,note\n0,0,-0.1,"two\nlines"\n1e,0,-0.1,x\n'
    with pytest.raises(ToolpathError, match="line 4: z_mm|line 4: x_mm"):
        read_toolpath(quoted, "q.csv")


def test_cr_only_gcode_is_written_back_with_cr():
    text = "G21 G90\rG0 X0 Y0 Z1\rG1 X10. Z-0.1\r"
    assert write_toolpath(read_toolpath(text, "p"), {}) == text


def test_marks_go_into_a_csvs_own_note_column_and_gcode_marks_are_plain():
    path = read_toolpath("x_mm,y_mm,z_mm,compensate_note\n0,0,-0.1,old\n10,0,-0.1,\n", "n.csv")
    out = write_toolpath(path, {}, marks={2: "95 % band; beyond"})
    assert out.splitlines()[0] == "x_mm,y_mm,z_mm,compensate_note"
    assert out.splitlines()[2] == "10,0,-0.1,95 % band; beyond"
    g = read_toolpath("G21 G90\nG0 X0 Y0 Z1\n", "p")
    line = write_toolpath(g, {}, marks={1: "95 % band 12 um; 5 mm beyond (reach)"}).splitlines()[1]
    assert line == "G0 X0 Y0 Z1 (95 pct band 12 um, 5 mm beyond [reach])"
