"""explain uses the readings the run would: a reading outside the probe's usable stroke
(``probe.usable_mm``) is set aside by the rule ``run``, ``flatness --robot`` and ``report``
share (``report.replay.for_replay``), and the findings say which and why (``readings.not_used``).
The library's ``explain`` takes the rows as flagged, as ``survey.replay`` does: the commands
judge a replayed reading."""
import json

import yaml

from adaptive_cal.analysis.explain import explain
from adaptive_cal.cell.schema import load_yaml
from adaptive_cal.cli import main
from conftest import ROOT

CELL = ROOT / "configs" / "cheng2025-cell.yaml"


def _counting_from_zero(tmp_path):
    """The reference cell with a gauge that counts from its rest (stroke 0 .. 10 mm): round 0's
    published readings below 0 (seq 0, 19, 20) are outside its usable stroke."""
    data = load_yaml(CELL)
    data["probe"] = {**{k: v for k, v in data["probe"].items() if k != "rest_mm"},
                     "usable_mm": [0.0, 10.0]}
    path = tmp_path / "from-zero.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_explain_sets_aside_the_readings_outside_the_usable_stroke_and_says_which(
        tmp_path, cheng_round0, cheng_round1, capsys):
    cell = _counting_from_zero(tmp_path)
    out = tmp_path / "e.json"
    assert main(["explain", str(cheng_round0), str(cheng_round1), "--robot", str(cell),
                 "--json", str(out)]) == 0
    said = capsys.readouterr()
    f = json.loads(out.read_text())
    aside = f["readings"]["not_used"]
    assert [(r["seq"], r["recording"]) for r in aside] == [(s, str(cheng_round0)) for s in (0, 19, 20)]
    assert [r["reading_mm"] for r in aside] == [-0.208, -0.405, -0.315]
    assert all("probe.usable_mm" in r["why"] and "0 .. 10 mm" in r["why"] for r in aside)
    assert f["readings"]["used"] + f["readings"]["suspect"] == 77
    assert f["verdict"] == "form"
    assert f"readings not used: 3 ({cheng_round0}: seq 0, 19, 20): outside" in said.out
    assert "(seq 0: -0.208 mm)" in said.err  # said as flatness --robot says it


def test_explain_and_flatness_robot_use_the_same_touches(tmp_path, cheng_round0, capsys):
    cell = _counting_from_zero(tmp_path)
    out = tmp_path / "e.json"
    assert main(["explain", str(cheng_round0), "--robot", str(cell), "--json", str(out)]) == 0
    said = capsys.readouterr()
    assert "readings not used: 3 (seq 0, 19, 20): outside the probe's usable stroke 0 .. 10 mm" in said.out
    assert str(cell) in said.out
    readings = json.loads(out.read_text())["readings"]
    assert readings["used"] + readings["suspect"] == 37
    assert main(["flatness", str(cheng_round0), "--robot", str(cell)]) == 0
    assert f"{cheng_round0}: 37 touches" in capsys.readouterr().out


def test_nothing_is_said_where_every_reading_is_inside(cheng_round0, capsys):
    f = explain([cheng_round0], CELL).findings
    assert "not_used" not in f["readings"] and f["readings"]["used"] == 40
    assert main(["explain", str(cheng_round0), "--robot", str(CELL)]) == 0
    assert "not used" not in capsys.readouterr().out


def test_a_cell_whose_stroke_holds_few_of_the_readings_does_not_empty_the_recording(
        tmp_path, cheng_round0, capsys):
    """A cell written for a gauge that reads around its zero (zero_mm 0, the default usable
    0.5 .. 9.5 mm) set aside most of round 0 -- explain then refused the recording ('40 rows,
    0 of them fused'). Where more than a fifth of the readings lie outside the stroke the cell
    does not describe the gauge: the readings are used, the mismatch said, by explain and
    flatness --robot alike."""
    data = load_yaml(CELL)
    data["probe"] = {k: v for k, v in data["probe"].items() if k not in ("rest_mm", "usable_mm")}
    cell = tmp_path / "sloppy.yaml"
    cell.write_text(yaml.safe_dump(data))
    # round 0 as a gauge zeroed 2 mm further in reads it: -2.4 .. 4.0 mm, half below 0.5 mm
    lines = cheng_round0.read_text().splitlines()
    shifted = [line if not line[:1].isdigit() else ",".join(
        line.split(",")[:5] + [f"{float(line.split(',')[5]) - 2.0:.4f}"]) for line in lines]
    cheng_round0 = tmp_path / "round0-zeroed-mid.csv"
    cheng_round0.write_text("\n".join(shifted) + "\n")
    out = tmp_path / "e.json"
    assert main(["explain", str(cheng_round0), "--robot", str(cell), "--json", str(out)]) == 0
    said = capsys.readouterr()
    assert "lie outside the probe's usable stroke [0.5, 9.5] mm" in said.err
    assert "the cell's probe block does not describe this recording's gauge" in said.err
    f = json.loads(out.read_text())
    assert "not_used" not in f["readings"] and f["verdict"] == "form"
    assert f["readings"]["used"] + f["readings"]["suspect"] == 40
    assert main(["flatness", str(cheng_round0), "--robot", str(cell)]) == 0
    assert f"{cheng_round0}: 40 touches" in capsys.readouterr().out


def test_one_file_of_two_rounds_names_the_round_of_each_reading_set_aside(
        tmp_path, cheng_round0, cheng_round1):
    """Rounds in one file (a ``round`` column, seq running on): a reading set aside names its
    round, as a reading of several files names its recording (an outside audit)."""
    rows = []
    for k, path in enumerate((cheng_round0, cheng_round1)):
        body = [line for line in path.read_text().splitlines() if line and line[0] != "#"][1:]
        rows += [f"{int(r.split(',')[0]) + 40 * k},{r.split(',', 1)[1]},{k}" for r in body]
    both = tmp_path / "both.csv"
    both.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,round\n"
                    + "\n".join(rows) + "\n")
    out = tmp_path / "e.json"
    assert main(["explain", str(both), "--robot", str(_counting_from_zero(tmp_path)),
                 "--json", str(out)]) == 0
    aside = json.loads(out.read_text())["readings"]["not_used"]
    assert [(r["seq"], r["round"]) for r in aside] == [(0, 0.0), (19, 0.0), (20, 0.0)]
    assert all("recording" not in r for r in aside)


def test_readings_spread_wider_than_the_whole_stroke_are_asked_if_they_are_um(tmp_path,
                                                                               cheng_round0,
                                                                               capsys):
    """A 30 um bow across y at round 0's touches, read as a gauge's relative readout in um and
    written as if mm: the readings spread 30 "mm", more than the probe's whole stroke, which no
    reading of it can -- the warning asks whether they are um (an audit, 2026-12-01: it only
    asked 'signed readings?', and explain then reported 7,560 um of structure)."""
    lines = cheng_round0.read_text().splitlines()

    def as_um(line):
        cells = line.split(",")
        y = float(cells[3])
        return ",".join(cells[:5] + [f"{30.0 * (y / 185.0) ** 2 - 10.0:.3f}"])
    path = tmp_path / "round0-um.csv"
    path.write_text("\n".join(as_um(x) if x[:1].isdigit() else x for x in lines) + "\n")
    main(["explain", str(path), "--robot", str(CELL)])
    err = capsys.readouterr().err
    assert "is more than the probe's whole stroke" in err and "readings in um?" in err, err
