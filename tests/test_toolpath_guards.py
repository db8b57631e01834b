"""G-code and CSV toolpath words that were read silently and wrongly: each refused naming the
line and the word (a robot or machine must never get a Z computed for another X)."""
import pytest

from adaptive_cal.formats.toolpath import ToolpathError, read_toolpath

START = "G0 X0 Y0 Z1\n"
HEAD = "G21 G90\n"
# what a controller could run differently from how the text reads (compensate's audit)
CONTROL_CASES = [
    # a subprogram runs from its call's position, not the one the text gives (a rapid into the
    # plate, found with a call at Z5 and the subprogram after M30 reading the main's last Z)
    (HEAD + START + "M98 P2000\nM30\nO2000\nG0 X100. Y100.\nM99\n", ["line 3", "M98"]),
    (HEAD + START + "M97 P100\n", ["line 3", "M97"]),
    (HEAD + START + "G1 X10. F100\nM99\n", ["line 4", "M99"]),
    (HEAD + START + "M30\nG1 X10.\n", ["line 4", "after the program's end", "line 3"]),
    # Grbl moves to a G4 line's X; a Fanuc dwells X seconds
    (HEAD + START + "G4 P0.5 X150.\nG1 Y-100.\n", ["line 3", "dwell"]),
    # a form feed / NEL / stray CR inside a comment starts a new block to some readers
    (HEAD + START + "G1 Z-0.5 F100 ; note\x0cG1 Z-3\n", ["line 3", "U+000C"]),
    (HEAD + START + "G1 Z-0.5 ; note\x85G0 Z-3\n", ["line 3", "U+0085"]),
    (HEAD + START + "G1 Z-0.5 ; note\rG0 Z-3\n", ["line 3", "U+000D"]),
    # the map is one plate in one frame
    (HEAD + "G54\n" + START + "G55\nG0 X10. Y10. Z1.\n", ["line 4", "G55 after G54 (line 2)"]),
    ("X_MM;Y_MM;Z_MM\n1;2;3\n", ["line 1", "comma-separated"]),
    ("x_mm,y_mm,z_mm\n1_0,2,3\n", ["line 2", "'1_0' is not a number"]),
]


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
] + CONTROL_CASES)
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


def test_line_ends_header_case_bom_and_what_is_assumed():
    from adaptive_cal.formats.toolpath import write_toolpath

    crlf = read_toolpath("\ufeffO1000\r\nG21 G90\r\nG0 X0. Y0. Z1.\r\nG1 X10.\r\n", "p")
    assert [m.end for m in crlf.moves] == [(0.0, 0.0, 1.0), (10.0, 0.0, 1.0)]
    text = write_toolpath(crlf, {}, header_comment="hdr")
    assert text.startswith("\ufeffO1000\r\n(hdr)\r\nG21 G90\r\n")  # BOM kept, O number first
    old_mac = read_toolpath("G21 G90\rG0 X0. Y0. Z1.\rG1 X10.\r", "p")  # CR only: CR ends lines
    assert len(old_mac.moves) == 2 and old_mac.assumed == ()
    bare = read_toolpath("G0 X0 Y0 Z1\nG1 X10.5\n", "p")
    assert bare.assumed == ("G21", "G90")
    assert bare.whole_numbers == ((1, "X0"), (1, "Y0"), (1, "Z1"))
    upper = read_toolpath('"X_MM","Y_MM","Z_MM"\n1,2,3\n4,5,6\n', "p")
    assert upper.kind == "csv" and upper.moves[-1].end == (4.0, 5.0, 6.0)
