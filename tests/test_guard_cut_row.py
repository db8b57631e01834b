"""A last row cut by a crash mid-write (recording.csv without its last newline): kept where
every required number is there in full (a cut optional field blank, a cut flags word dropped),
never fused on a guess where its flags could have held 'rejected' or 'gated', dropped where a
required number is missing or may itself be cut; the line as it was is appended to
recording.cut.txt (never overwritten) and what was done is one message line."""
import warnings

import pytest

from adaptive_cal.formats.recording import read_recording
from adaptive_cal.formats.writing import cut_file, repair_cut_row, repair_cut_row_said
from adaptive_cal.run import session

from helpers import sim_cell

HEAD = ("# adaptive-cal recording v1\n# probe_zero_mm: 5.0\n"
        "seq,t_s,x_mm,y_mm,z_mm,reading_mm,flags,round\n"
        "10,44.100,40.0000,1.0000,0.7000,5.002100,,0\n")
ROW = "11,47.657,43.0000,1.9663,0.7370,5.010300"


@pytest.mark.parametrize("tail, row, fused, dropped", [
    # the audit's line: every required number whole, the flags cut inside 'closure'; the words
    # after it (sorted: 'rejected' may follow) are unknown, so it is kept but not fused
    (ROW + ",clos", ROW + ",cut;rejected,", False, "clos"),
    (ROW + ",retake;s", ROW + ",retake,", True, "s"),  # nothing NOT_FUSED sorts after 'retake'
    (ROW + ",surprise", ROW + ",surprise,", True, ""),  # a whole word, its ',' cut
    (ROW + ",rejected;stroke_e", ROW + ",rejected,", False, "stroke_e"),
    (ROW + ",ga", ROW + ",cut;rejected,", False, "ga"),  # perhaps 'gated'
    (ROW + ",", ROW + ",cut;rejected,", False, ""),  # the flags not written at all
    (ROW, ROW + ",cut;rejected,", False, ""),  # the reading has all its decimals
    (ROW + ",closure,", ROW + ",closure,", True, ""),  # whole (round blank): only the newline
])
def test_a_row_with_its_required_numbers_whole_is_kept(tmp_path, tail, row, fused, dropped):
    p = tmp_path / "recording.csv"
    p.write_text(HEAD + tail)
    said = repair_cut_row_said(p)
    text = p.read_text()
    assert text == HEAD + row + "\n"
    rec = read_recording(p)
    assert rec.seq.tolist() == [10, 11] and rec.reading_mm[1] == 5.0103
    assert rec.fused.tolist() == [True, fused]
    if row == tail:
        assert said is None and not cut_file(p).exists()
    else:
        assert said.startswith(f"{p}:5: the last row was cut by a crash mid-write: kept")
        assert cut_file(p).read_text().endswith(f"\n{tail}\n")
        assert (dropped == "") == ("dropped" not in said)
    assert repair_cut_row(p) is None and p.read_text() == text  # idempotent


@pytest.mark.parametrize("tail", [ROW[:-2], "11,47.657,43.0000,1.9663,0.7370", "11,47.6",
                                  ROW + ",closure,0,extra"])
def test_a_row_whose_required_numbers_are_not_all_whole_is_dropped_and_kept_aside(tmp_path,
                                                                                  tail):
    p = tmp_path / "recording.csv"
    p.write_text(HEAD + tail)
    assert repair_cut_row(p) == tail
    assert p.read_text() == HEAD
    assert cut_file(p).read_text().endswith(f"\n{tail}\n")


def test_the_side_file_is_appended_never_overwritten(tmp_path):
    p = tmp_path / "recording.csv"
    for tail in (ROW + ",clos", ROW[:-3]):
        p.write_text(HEAD + tail)
        repair_cut_row(p)
    kept = cut_file(p).read_text()
    assert kept.count("cut by a crash") == 2 and f"\n{ROW},clos\n" in kept
    assert kept.endswith(f"\n{ROW[:-3]}\n")


def test_resume_keeps_the_cut_reading_and_says_so_in_one_line(tmp_path, capsys):
    cell, out = sim_cell(), tmp_path / "run"
    session.run(cell, out, progress=False, max_new_touches=4)
    rec_path = out / "recording.csv"
    whole = rec_path.read_text()
    last = whole.splitlines()[-1].split(",")
    cut = ",".join(["4"] + last[1:6]) + ",retake;s"  # required numbers whole, flags cut
    rec_path.write_text(whole + cut)
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = session.run(cell, out, resume=True, progress=False, max_new_touches=1)
    err = capsys.readouterr().err
    assert err.count("cut by a crash") == 1 and "Warning" not in err
    assert "the cut flags word 's' dropped" in err
    rec = read_recording(rec_path)
    assert rec.seq.tolist() == list(range(6)) and r["touches"] == 6
    assert rec_path.read_text().startswith(whole + ",".join(["4"] + last[1:6]) + ",retake,")
    assert rec.fused[4]
