"""A byte that is not UTF-8 is named where it is: file, line and byte of the line. The recording
reader decodes a stream a chunk ahead of the line it hands out, so its error named line 1 for a
bad byte on line 2, and line 502 for one on line 503 (an audit, 2026-11-24). One message for
recordings, height maps and toolpaths (``formats.text.not_utf8``)."""
import pytest

from adaptive_cal.formats.heightmap import HeightMapError, load_heightmap
from adaptive_cal.formats.recording import RecordingError, read_recording
from adaptive_cal.formats.text import not_utf8


def test_the_byte_is_found_on_its_line():
    data = b"abc\nde\xf6f\n"
    assert not_utf8("f.csv", data) == ("f.csv:2: not UTF-8 text (byte 0xf6, byte 3 of the line: "
                                       "invalid start byte)")


def test_a_recording_names_the_line_of_the_bad_byte_deep_in_the_file(tmp_path):
    rows = [f"{i},{i}.0,{i}.0,0,0,0.1" for i in range(600)]
    rows[501] = rows[501] + ",caf\xe9".encode("latin-1").decode("latin-1")
    head = "# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,note\n"
    body = "\n".join(r if i == 501 else r + "," for i, r in enumerate(rows)) + "\n"
    path = tmp_path / "rec.csv"
    path.write_bytes((head + body).encode("latin-1"))
    with pytest.raises(RecordingError, match=r"rec\.csv:504: not UTF-8 text \(byte 0xe9"):
        read_recording(path)


def test_a_height_map_names_the_line_too(tmp_path):
    path = tmp_path / "map.csv"
    path.write_bytes(b"x_mm,y_mm,height_mm\n0,0,0\n0,1,0\xb5\n")
    with pytest.raises(HeightMapError, match=r"map\.csv:3: not UTF-8 text \(byte 0xb5, byte 6 "):
        load_heightmap(path)


def test_the_cli_says_utf16_and_not_utf8_instead_of_printing_the_bytes(tmp_path, capsys):
    """flatness / explain printed "not an adaptive-cal recording (its first line is '\ufffd\ufffd#\\x00 \\x00a...')"
    for a spreadsheet's UTF-16 export (the API said "not UTF-8"; outside audit)."""
    from adaptive_cal.cli import main

    text = "# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n0,,0,0,0,5\n"
    (tmp_path / "u16.csv").write_bytes(text.encode("utf-16"))
    (tmp_path / "l1.csv").write_bytes("x_mm;y_mm;h\u00f6he\n0;0;5\n".encode("latin-1"))
    for name, said in (("u16.csv", "UTF-16 text (a spreadsheet's 'Unicode text'), not UTF-8"),
                       ("l1.csv", "l1.csv:1: not UTF-8 text (byte 0xf6")):
        assert main(["flatness", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert said in err and "\\x00" not in err, err
