"""Recordings written by other tools, valid by DESIGN.md, read the way the format says:
the direction of arrival follows from the order of ALL the rows the robot went to (a rejected
or gated touch is a move), a t_s blank on some rows does not discard the known ones, and a
``round`` column with several values holds several rounds (each its own tilt)."""
import numpy as np

from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.design import arrival, build_design, split_rounds, touch_times
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.formats.recording import read_recording

from helpers import ROOT, sim_cell

CHENG = ROOT / "adaptive_cal" / "data" / "cheng2025"  # the published readings, as shipped


def _write(path, rows, extra_header=""):
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm" + extra_header]
    lines += [",".join(str(v) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_direction_of_arrival_counts_the_rejected_moves(tmp_path):
    # rows along x, out and back; before some good touches a rejected one at the plate's far
    # side: the robot went there, so the next good touch arrives from it, not from the good
    # touch before (dropping the rejected rows first gets those arrivals wrong)
    rng = np.random.default_rng(3)
    rows, seq, truth, last_x, d = [], 0, [], None, 0.0
    xs = np.linspace(-200, 200, 9)
    for y in np.linspace(-160, 160, 8):
        for x in np.concatenate([xs, xs[::-1]]):
            if last_x is not None and rng.random() < 0.3:
                far = float(rng.choice([-220.0, 220.0]))
                rows.append([seq, 3.0 * seq, far, y, 0.0, 9.9, "rejected;stroke_end"])
                d = 1.0 if far > last_x else -1.0
                seq, last_x = seq + 1, far
            if last_x is None:  # no move before the first touch: DESIGN.md's reader says 0
                d = 0.0
            elif x != last_x:  # a touch again in place keeps the last move's direction
                d = 1.0 if x > last_x else -1.0
            truth.append(d)
            reading = (5.0 + 0.01 * x + 0.002 * y + 0.025 * d + 0.002 * rng.standard_normal())
            rows.append([seq, 3.0 * seq, x, y, 0.0, round(reading, 6), ""])
            seq, last_x = seq + 1, x
    rec = read_recording(_write(tmp_path / "rej.csv", rows, ",flags"))
    used = rec.fused
    assert np.array_equal(arrival(rec)[used], np.array(truth))
    assert not np.array_equal(rec.select(used).direction, np.array(truth))  # the old reading
    cell = sim_cell(probe={"usable_mm": [0.5, 9.5], "noise_std_mm": 0.002},
                    simulation={"effects": {"tilt": {"a": 0.0, "b": 0.0, "c": 0.0}},
                                "unknown": ["tilt"]})
    f = explain([rec], cell).findings
    assert f["verdict"] == "reversal"
    span = next(e for e in f["left_out"] if e["effect"] == "reversal")["params"]["span_mm"]
    assert abs(span - 0.05) < 0.003  # +x arrival minus -x arrival, 2 x 25 um


def test_blank_times_on_some_rows_are_filled_not_all_discarded(tmp_path):
    rows = [[i, "" if i in (1, 3, 7) else 10.0 * i, 0.0, 0.0, 0.0, 5.0] for i in range(8)]
    rows[0][1] = ""  # before the first known time (row 2): touch_time_s a row back from it
    rec = read_recording(_write(tmp_path / "t.csv", rows))
    t = touch_times(rec, touch_time_s=4.0)
    assert np.allclose(t, [12.0, 16.0, 20.0, 30.0, 40.0, 50.0, 60.0, 64.0])
    blank = [[i, "", 0.0, 0.0, 0.0, 5.0] for i in range(3, 6)]
    assert np.allclose(touch_times(read_recording(_write(tmp_path / "b.csv", blank)), 4.0),
                       [12.0, 16.0, 20.0])  # none known: seq x touch_time_s


def test_a_round_column_with_two_values_is_two_rounds(tmp_path):
    cell = load_cell(ROOT / "configs" / "cheng2025-cell.yaml")
    parts = [read_recording(CHENG / n) for n in ("round0_initial.csv",
                                                 "round1_first_correction.csv")]
    rows, seq = [], 0
    for r, rec in enumerate(parts):
        for i in range(len(rec)):
            rows.append([seq, "", rec.x_mm[i], rec.y_mm[i], rec.z_mm[i], rec.reading_mm[i], r])
            seq += 1
    one = read_recording(_write(tmp_path / "both.csv", rows, ",round"))
    split = split_rounds(one)
    assert [len(s) for s in split] == [len(p) for p in parts]
    assert split[1].path.endswith("both.csv (round 1)")
    design = build_design([one], cell)
    assert design.rounds == 2
    f = explain([one], cell).findings
    two = explain(parts, cell).findings
    assert f["verdict"] == two["verdict"] == "form"
    assert abs(f["fit"]["rms_after_mm"] - two["fit"]["rms_after_mm"]) < 1e-9
    assert f["fit"]["rms_after_mm"] < 0.04  # 150 -> 31 um, as the two files give


def test_flatness_and_report_refuse_several_rounds_in_one_file_naming_them(tmp_path):
    # one surface's figure of two rounds' stacked tilts read 4.7 mm of "flatness"; refused
    import subprocess
    import sys

    rows = [[i, "", x, y, 0.0, 5.0 + (0.01 if i >= 12 else 0.0) * x, i // 12]
            for i, (x, y) in enumerate([(x, y) for _ in range(2) for y in (-100, 0, 100)
                                        for x in (-150, -50, 50, 150)])]
    path = _write(tmp_path / "two.csv", rows, ",round")
    for args in (["flatness", str(path)],
                 ["report", str(path), "--robot", str(ROOT / "configs" / "sim-cell.yaml"),
                  "--out", str(tmp_path / "r.html")]):
        p = subprocess.run([sys.executable, "-m", "adaptive_cal.cli", *args], capture_output=True,
                           text=True)
        assert p.returncode != 0 and "Traceback" not in p.stderr
        assert "two.csv: column round holds 2 rounds (0, 1)" in p.stderr, p.stderr
    assert not (tmp_path / "r.html").exists()


def test_time_that_runs_backwards_within_a_round_is_said_naming_the_lines(tmp_path, capsys):
    """t_s is the time since the run's start, rows in touch order: a file whose times run
    backwards (reversed in a spreadsheet) gave a drift of the opposite sign without a word."""
    rows = [[i, 10.0 * i, 0.0, 0.0, 0.0, 5.0] for i in range(6)]
    rows[4][1] = 1.0  # line 7 (two header lines): 1 s after 30 s on line 6
    rec = read_recording(_write(tmp_path / "back.csv", rows))
    said = [n for n in rec.notes if "time runs backwards" in n]
    assert len(said) == 1 and said[0].startswith(f"{tmp_path / 'back.csv'}:7: t_s 1 s after 30 s "
                                                 "on line 6") and "(1 time)" in said[0]
    assert "time runs backwards" in capsys.readouterr().err
    # each round has its own clock; blank times are skipped
    rounds = [[i, "" if i == 2 else 10.0 * (i % 3), 0.0, 0.0, 0.0, 5.0, i // 3] for i in range(6)]
    rec = read_recording(_write(tmp_path / "rounds.csv", rounds, ",round"))
    assert not any("backwards" in n for n in rec.notes)
