"""What an outside audit of flatness and the report found (2026-11-29): --compare's change column
disagreed with the printed figures by a digit, --robot was dropped by --compare without a word,
two different sets of touches were compared without one, the touched points' line did not say
what its interval holds, and report's several-rounds message named an option it lacks."""
import json

import pytest

from adaptive_cal.analysis.flatness_answer import OUTSIDE_NOTE, touched_what
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording

from conftest import ROOT


def _change_rows(out: str) -> dict:
    rows = {}
    for line in out.splitlines():
        parts = line.split()
        if parts[:2] in (["least", "squares"], ["minimum", "zone"]):
            rows[" ".join(parts[:2])] = [float(v) for v in parts[2:5]]
    return rows


def test_the_change_column_is_the_difference_of_the_printed_figures(
        cheng_round0, cheng_round1, capsys):
    assert main(["flatness", str(cheng_round0), "--compare", str(cheng_round1)]) == 0
    rows = _change_rows(capsys.readouterr().out)
    assert rows["least squares"] == [541.7, 596.0, 54.3]  # printed +54.4 before
    for earlier, later, change in rows.values():
        assert change == pytest.approx(later - earlier, abs=1e-9)


def test_compare_says_what_it_does_not_use_and_when_the_touches_differ(tmp_path, cheng_round0,
                                                                       capsys):
    rows = [line for line in cheng_round0.read_text().splitlines() if line[:1] != "#"]
    part = tmp_path / "part.csv"
    part.write_text("# adaptive-cal recording v1\n" + "\n".join(rows[:31]) + "\n")  # 30 touches
    cell = ROOT / "configs" / "cheng2025-cell.yaml"
    assert main(["flatness", str(cheng_round0), "--compare", str(part), "--robot",
                 str(cell)]) == 0
    said = capsys.readouterr()
    err = said.err
    assert f"--robot {cell} is not used by --compare" in err
    assert "touches differ (10 of 40 places" in err and "0 of 30 the other way" in err
    # every verdict of the table says it compares other points (an outside audit, 2026-11-29:
    # an unchanged plate on two designs read "larger" at P(worse) >= 0.95 in 4 of 10 pairs)
    rows = [ln for ln in said.out.splitlines() if ln.startswith(("  least squares",
                                                                   "  minimum zone", "  range"))]
    assert len(rows) == 3 and all(ln.endswith(" (other points)") for ln in rows)
    assert main(["flatness", str(cheng_round0), "--compare", str(part), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["touches_differ"] == {"first_only": 10, "first_places": 40, "second_only": 0,
                                     "second_places": 30}



def test_rounds_at_the_same_places_are_compared_without_the_mark(cheng_round0, cheng_round1,
                                                                   capsys):
    assert main(["flatness", str(cheng_round0), "--compare", str(cheng_round1), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["touches_differ"] is None
    assert main(["flatness", str(cheng_round0), "--compare", str(cheng_round1)]) == 0
    assert "(other points)" not in capsys.readouterr().out


def test_the_touched_line_says_what_its_interval_holds():
    assert "a repeat measurement's figure" in touched_what(40)
    assert "by chance one time in twenty" in OUTSIDE_NOTE


def test_a_report_of_several_rounds_names_its_own_option(tmp_path, cheng_round0):
    """Each command's refusal names the option it has: report --round R since 2026-11-29 (before
    it had none, and named none); any other use names none."""
    rows = [line for line in cheng_round0.read_text().splitlines() if line[:1] != "#"]
    both = tmp_path / "both.csv"
    body = [f"{r},{0 if i < 20 else 1}" for i, r in enumerate(rows[1:])]
    both.write_text("# adaptive-cal recording v1\n" + rows[0] + ",round\n" + "\n".join(body) + "\n")
    with pytest.raises(RecordingError) as e:
        read_recording(both).one_round("a report's map")
    assert "report --round R" in str(e.value) and "flatness --round" not in str(e.value)
    assert "give each round as its own file" in str(e.value)
    with pytest.raises(RecordingError) as e:
        read_recording(both).one_round("a map")
    assert "--round" not in str(e.value)
    with pytest.raises(RecordingError, match="flatness --round R"):
        read_recording(both).one_round("flatness")
