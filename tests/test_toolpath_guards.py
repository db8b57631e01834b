"""G-code and CSV toolpath words that were read silently and wrongly: each refused naming the
line and the word (a robot or machine must never get a Z computed for another X)."""
import pytest

from adaptive_cal.formats.toolpath import ToolpathError, read_toolpath

START = "G0 X0 Y0 Z1\n"


@pytest.mark.parametrize("program, words", [
    (START + "G1 X10 X20\n", ["line 2", "X given twice", "X10", "X20"]),
    (START + "G1 Y5 Z0.1 Z-0.1\n", ["line 2", "Z given twice"]),
    (START + "G1 X1.5e2\n", ["line 2", "'X1.5e2'", "exponent notation"]),
    (START + "G1 Y-2E+1 X0\n", ["line 2", "'Y-2E+1'", "exponent notation"]),
    (START + "G1 X10 E0.5\n", ["line 2", "E", "extruder"]),
    (START + "G1 E5\n", ["line 2", "E", "extruder"]),  # no X, Y, Z: an extruder move alone
    (START + "G1 A90\n", ["line 2", "A"]),
    ("x_mm,y_mm,z_mm,x_mm\n1,2,3,4\n", ["line 1", "'x_mm' given twice", "columns 1 and 4"]),
    ("x_mm,y_mm,z_mm,note,note\n1,2,3,a,b\n", ["line 1", "'note' given twice"]),
])
def test_ambiguous_words_are_refused_naming_line_and_word(program, words):
    with pytest.raises(ToolpathError) as e:
        read_toolpath(program, "prog")
    for w in words:
        assert w in str(e.value), str(e.value)


@pytest.mark.parametrize("program, end", [
    (START + "G1 X10 (e2 in a comment)\n", (10.0, 0.0, 1.0)),
    (START + "G1 X1.5 ; e2\n", (1.5, 0.0, 1.0)),
    ("G4 P0.5\n" + START + "M3 S1000\nG1 X10 F100\n", (10.0, 0.0, 1.0)),
    ("x_mm,y_mm,z_mm,,\n1,2,3,,\n", (1.0, 2.0, 3.0)),  # blank trailing columns are no names
])
def test_plain_programs_still_read(program, end):
    assert read_toolpath(program, "prog").moves[-1].end == end
