"""A recording's flags decide what is fused, however the file was handled: its '#' lines
removed (a spreadsheet's round trip), a plain table with a flags column, hand-edited words
(spaces, capitals), an unknown word (kept, said once with its line, never changing what is
fused) and an outlier probability that is not one."""
import json

import numpy as np
import pytest

from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording

HEADER = "seq,t_s,x_mm,y_mm,z_mm,reading_mm,flags,round"
XY = [(x, y) for y in (-150, -50, 50, 150) for x in (-200, -100, 0, 100, 200)]


def _rows(bad_flags="rejected;stroke_end"):
    """20 touches on a plane tilted 0.01 mm/mm in x; rows 3, 8 and 13 are placeholders at the
    stroke end (reading 9.99, flagged): fusing them tilts the plane by degrees."""
    rows = []
    for i, (x, y) in enumerate(XY):
        bad = i in (3, 8, 13)
        reading = 9.99 if bad else 5.0 + 0.01 * x + 0.0005 * np.sin(i)
        rows.append(f"{i},{3.0 * i:.3f},{x},{y},0,{reading:.6f},{bad_flags if bad else ''},0")
    return rows


def _recording(tmp_path, name="rec.csv", magic=True, bad_flags="rejected;stroke_end"):
    lines = (["# adaptive-cal recording v1", "# probe_zero_mm: 5.0"] if magic else [])
    path = tmp_path / name
    path.write_text("\n".join(lines + [HEADER] + _rows(bad_flags)) + "\n")
    return path


def _flatness(path, capsys):
    assert main(["flatness", str(path), "--json", "--samples", "20"]) == 0
    out = capsys.readouterr()
    return json.loads(out.out), out.err


def test_removing_the_hash_lines_changes_nothing_that_is_fused(tmp_path, capsys):
    full, _ = _flatness(_recording(tmp_path), capsys)
    stripped, err = _flatness(_recording(tmp_path, "nomagic.csv", magic=False), capsys)
    assert full["touches"] == stripped["touches"] == 17
    assert stripped["tilt"]["a"] == pytest.approx(full["tilt"]["a"], abs=1e-9)
    assert abs(stripped["tilt"]["a"] - 0.01) < 1e-4  # the placeholders would tilt it by degrees
    assert "nomagic.csv: its first line is the header of a recording" in err
    assert "3 of 20 rows flagged gated/invalid/rejected are not used" in err
    rec = read_recording(tmp_path / "nomagic.csv")
    assert rec.seq.tolist() == list(range(20)) and rec.t_s[5] == 15.0  # times kept


def test_a_plain_table_with_flags_honours_them(tmp_path, capsys):
    path = tmp_path / "table.csv"
    body = [",".join(r.split(",")[2:7]) for r in _rows()]  # x_mm,y_mm,z_mm,reading_mm,flags
    path.write_text("x_mm,y_mm,z_mm,reading_mm,flags\n" + "\n".join(body) + "\n")
    out, err = _flatness(path, capsys)
    assert out["touches"] == 17 and abs(out["tilt"]["a"] - 0.01) < 1e-4
    assert "table.csv: read as a plain table" in err and "3 of 20 rows" in err
    rec = read_recording(path)
    assert rec.fused.tolist() == [i not in (3, 8, 13) for i in range(20)]


@pytest.mark.parametrize("words", [" rejected ; stroke_end ", "REJECTED", "Gated", "invalid",
                                   "stroke_end; Rejected"])
def test_hand_edited_words_are_read_as_written_by_the_tool(tmp_path, words, capsys):
    rec = read_recording(_recording(tmp_path, bad_flags=words))
    assert rec.fused.tolist() == [i not in (3, 8, 13) for i in range(20)]
    assert capsys.readouterr().err == ""  # nothing unknown to say


def test_an_unknown_word_is_kept_said_once_and_changes_nothing(tmp_path, capsys):
    path = _recording(tmp_path, bad_flags="rejected;chekced")  # rows 3, 8, 13: lines 7, 12, 17
    lines = path.read_text().splitlines()
    lines[8] = lines[8][: lines[8].rindex(",", 0, lines[8].rindex(","))] + ",rejcted,0"  # row 5
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    err = capsys.readouterr().err
    assert rec.fused.tolist() == [i not in (3, 8, 13) for i in range(20)]  # row 5 still fused
    assert "rejcted" in rec.flags[5] and "chekced" in rec.flags[3]
    assert err.count("warning:") == 1 and err.count("\n") == 1
    assert "'rejcted' on line 9 (did you mean 'rejected'?)" in err
    assert "'chekced' on line 7 and 2 more row(s)" in err
    read_recording(path)
    assert capsys.readouterr().err == ""  # once


@pytest.mark.parametrize("word", ["outlier=1.5", "outlier=abc", "outlier=-0.1", "outlier=nan"])
def test_an_outlier_probability_that_is_not_one_is_refused_with_its_line(tmp_path, word):
    with pytest.raises(RecordingError, match=rf"rec.csv:7: column flags: flag '{word}'"):
        read_recording(_recording(tmp_path, bad_flags=word))


def test_an_outlier_probability_of_one_is_what_the_run_writes_for_p_from_0_995(tmp_path):
    """gate.outlier_flag writes two decimals: a reading judged p >= 0.995 carries outlier=1.00
    (weight 0), and its recording must read back."""
    from adaptive_cal.planning.gate import outlier_flag
    word = outlier_flag(0.997)[0]
    assert word == "outlier=1.00"
    rec = read_recording(_recording(tmp_path, bad_flags=word))
    assert word in rec.flags[3]


def test_outlier_weights_are_read_with_spaces(tmp_path):
    rec = read_recording(_recording(tmp_path, bad_flags=" Outlier=0.25 ;rejected"))
    assert "outlier=0.25" in rec.flags[3] and not rec.fused[3]
