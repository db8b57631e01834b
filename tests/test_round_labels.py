"""A ``round`` column given as text ("first", "A") by another writer: each label is a round, in
the order it first appears, and the reader says so. Before, a text cell in an optional column
became NaN, ``Recording.rounds`` dropped it, and two rounds with different tilts were read as
one surface: millimetres of "form" and a reading noise of 890 um, with no word said."""
import numpy as np

from adaptive_cal.formats import recording
from adaptive_cal.formats.recording import read_recording

HEAD = "# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,round\n"


def _write(tmp_path, labels):
    rows = [f"{i},{i}.0,{10.0 * i},{5.0 * (i % 3)},0,{0.1 * i},{lab}" for i, lab in enumerate(labels)]
    path = tmp_path / "rec.csv"
    path.write_text(HEAD + "\n".join(rows) + "\n")
    return path


def test_text_round_labels_are_rounds_in_order_of_first_appearance(tmp_path, monkeypatch):
    said = []
    monkeypatch.setattr(recording, "say", lambda notes: said.extend(notes))
    rec = read_recording(_write(tmp_path, ["second", "second", "first", "", "first", "third"]))
    r = rec.extra["round"]
    assert r[:3].tolist() == [0.0, 0.0, 1.0] and np.isnan(r[3]) and r[4:].tolist() == [1.0, 2.0]
    assert rec.rounds == [0.0, 1.0, 2.0]
    assert any("column round holds labels" in n and "second = 0, first = 1, third = 2" in n
               for n in said)


def test_numeric_rounds_are_read_as_numbers_and_nothing_is_said(tmp_path, monkeypatch):
    said = []
    monkeypatch.setattr(recording, "say", lambda notes: said.extend(notes))
    rec = read_recording(_write(tmp_path, ["3", "3", "7", "7"]))
    assert rec.rounds == [3.0, 7.0] and not any("round" in n for n in said)


def test_a_label_mixed_with_numbers_keeps_every_round_apart(tmp_path):
    rec = read_recording(_write(tmp_path, ["1", "1", "B", "2"]))
    assert rec.rounds == [0.0, 1.0, 2.0]
