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
