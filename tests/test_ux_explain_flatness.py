"""What explain and flatness print: one unit per quantity, each round-to-round statistic named
(explain's test of "unchanged" against flatness --compare's interval of the change), why a
verdict is none, no "-0.0", a value and its sd to the same digits."""
import numpy as np
import pytest

from adaptive_cal.analysis.flatness import ls_flatness_mm
from adaptive_cal.report.explain_text import fixed, left_out_line, none_line, quantity, rounds_lines
from conftest import ROOT

CELL = ROOT / "configs" / "cheng2025-cell.yaml"


def _write(path, x, y, z, reading):
    rows = [f"{i},,{a:g},{b:g},{c:.6f},{r:.6f}" for i, (a, b, c, r) in
            enumerate(zip(x, y, z, reading))]
    path.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n"
                    + "\n".join(rows) + "\n")
    return path


def test_a_value_and_its_sd_have_the_same_decimals_and_no_negative_zero():
    assert quantity("tau_s", 9.9, 82.0, "s") == "tau 10 +- 82 s"
    assert quantity("tau_s", 30.24, 4.1, "s") == "tau 30.2 +- 4.1 s"
    assert quantity("amplitude_mm", -0.1139, 0.0569, "mm") == "amplitude -113.9 +- 56.9 um"
    assert quantity("bow_x", -0.00001, 0.002, "mm") == "bow in x +0.0 +- 2.0 um"
    assert fixed(-0.04, 1) == "0.0" and fixed(-0.04, 1, "+") == "+0.0"
    e = {"effect": "local_defect", "params": {"height_mm": 0.5}, "params_std": {"height_mm": 0.1},
         "log_bayes_factor": 2.7, "summary": "x",
         "given_verdict": {"left_out": False, "log_bayes_factor": -0.04}}
    line = left_out_line(e, {"height_mm": "mm"}, "form")
    assert "0.0 with form in the model" in line and "-0.0" not in line


def test_verdict_none_says_why():
    rep = {"verdict": "none", "verdict_probability": 0.514, "ambiguous_with": [],
           "threshold": {"log_bayes_factor": 1.0},
           "candidates": [{"effect": "local_defect", "log_bayes_factor": -0.09},
                          {"effect": "probe_gain", "log_bayes_factor": -0.057}]}
    line = none_line(rep)
    assert "no left-out effect is supported by the data" in line  # the report's words
    assert "best candidate, probe_gain, has log Bayes factor -0.06 against none" in line
    assert "above 1.0" in line and "other 0.49" in line and "2 candidates" in line


def test_rounds_line_is_a_test_of_unchanged_in_um_and_points_to_flatness_compare():
    r = {"flatness_mm": [0.54172, 0.59604], "change_mm": 0.05432, "null_change_95_mm": [-0.0611, 0.0604],
         "repeatability_mm": 0.0179, "p_value": 0.082, "exceeds_noise": False, "matched_points": 40}
    text = "\n".join(rounds_lines(r))
    assert "flatness (least squares) 541.7 -> 596.0 um, change +54.3 um" in text
    assert 'test of "plate unchanged"' in text and "p = 0.082, within the noise" in text
    assert "-61.1 .. +60.4 um (95 %)" in text and "the same 40 points" in text
    assert "flatness FIRST.csv --compare LATER.csv" in text and " mm" not in text


def test_rounds_flatness_is_of_the_heights_not_the_readings(tmp_path):
    """Approach heights z that vary from touch to touch (as a run's do): the flatness of a round
    is that of reading + z; the readings alone were used before (a different surface)."""
    from adaptive_cal.analysis.explain.design import build_design
    from adaptive_cal.analysis.explain.rounds import flatness_change
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording

    gx, gy = np.meshgrid(np.linspace(-200, 200, 9), np.linspace(-165, 165, 5))
    x, y = gx.ravel(), gy.ravel()
    rng = np.random.default_rng(1)
    form = 0.2 * (y / 165) ** 2 + 0.05 * np.cos(x / 60)
    paths, heights = [], []
    for r in range(2):
        h = 5.0 + 0.002 * x + form + 0.002 * rng.standard_normal(x.size)
        z = 0.4 * np.sin(x / 45.0) + 0.3 * (x * y / 3e4) ** 2  # not a plane
        paths.append(_write(tmp_path / f"r{r}.csv", x, y, z, h - z))
        heights.append(h)
    design = build_design([read_recording(p) for p in paths], load_cell(CELL))
    out = flatness_change(design, np.random.default_rng(0), draws=200)
    for r in range(2):
        assert out["flatness_mm"][r] == pytest.approx(ls_flatness_mm(x, y, heights[r]), abs=1e-6)
    assert out["matched_points"] == x.size
    assert out["repeatability_mm"] < 0.005  # the noise, not the approach heights' pattern


def test_explain_figures_with_verdict_none_show_no_after(tmp_path):
    """Nothing removed: one map column and no "after" points, and the figure says why."""
    import adaptive_cal
    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.report.explain_figures import residual_against, residual_maps

    adaptive_cal.use_float64()
    gx, gy = np.meshgrid(np.linspace(-200, 200, 8), np.linspace(-165, 165, 5))
    x, y = gx.ravel(), gy.ravel()
    reading = 3.0 + 0.001 * x - 0.002 * y + 0.01 * np.random.default_rng(3).standard_normal(x.size)
    e = explain([read_recording(_write(tmp_path / "flat.csv", x, y, 0 * x, reading))],
                load_cell(CELL), rng=np.random.default_rng(0))
    assert e.findings["verdict"] == "none"
    fig = residual_maps(e)
    titles = [ax.get_title() for ax in fig.axes]
    assert not any(t.startswith("with none") for t in titles)
    assert "nothing removed" in fig._suptitle.get_text()
    fig = residual_against(e, "position")
    ax = fig.axes[0]
    assert len(ax.collections) == 1 and "nothing removed" in ax.get_title()


def test_compare_table_is_in_um_and_names_its_interval():
    from adaptive_cal.cli.flatness import compare_table

    def side(name, ls, mz, rg):
        return {"recording": name, "flatness_mm": {"least_squares": {"value": ls},
                                                   "minimum_zone": {"value": mz},
                                                   "range": {"value": rg}}}

    change = {k: {"diff_ci95": [lo, hi], "p_b_greater": p} for k, lo, hi, p in (
        ("least_squares", -0.0598, 0.1392, 0.78), ("minimum_zone", -0.0423, 0.1062, 0.81),
        ("range", -5.5551, -5.3201, 0.0))}
    lines = compare_table({"first": side("a.csv", 0.54172, 0.4946, 6.4311),
                           "second": side("b.csv", 0.59604, 0.5281, 0.98), "change": change})
    assert lines[0].endswith("(later minus earlier; um):")
    assert lines[2].split()[2:7] == ["541.7", "596.0", "+54.3", "-59.8", ".."]
    assert "+139.2" in lines[2] and "6431.1" in lines[4]
    text = " ".join(line.strip() for line in lines[5:])
    assert "of the plate's figure at the touches, given the two recordings" in text
    assert "(not a p-value)" in text
    assert 'A test of "plate unchanged" with a p-value instead: adaptive-cal explain' in text


def test_bare_recording_spread_and_average_range_in_um(cheng_round0, capsys):
    from adaptive_cal.cli import main

    assert main(["flatness", str(cheng_round0), "--samples", "40"]) == 0
    out = capsys.readouterr().out
    spread = next(line for line in out.splitlines() if "height spread" in line)
    # um, as every flatness figure, and a figure of millimetres in mm beside it
    assert spread.endswith(" um)") and "6431.1 um = 6.43 mm (95 % " in spread
    assert "average range (Cheng Table 8, tilt included) along x 5661.6 um, along y 687.6 um" in out


def test_the_none_line_does_not_name_an_effect_the_tilt_absorbs_whole():
    """An effect the tilt absorbs whole scores exactly 0 (the likelihood of none): the line named
    it the best candidate beside 'the tilt absorbs 100 %' (an outside audit, 2026-12-01)."""
    rep = {"candidates": [{"effect": "probe_gain", "log_bayes_factor": 0.0},
                          {"effect": "thermal_drift", "log_bayes_factor": -0.34}],
           "not_identifiable": [{"effect": "probe_gain", "aliased_with": ["tilt"]}],
           "threshold": {"log_bayes_factor": 1.0}, "verdict_probability": 0.5}
    assert "best candidate, thermal_drift, has log Bayes factor -0.34" in none_line(rep)
    alone = {**rep, "candidates": rep["candidates"][:1]}  # nothing else: said as it is
    assert "best candidate, probe_gain" in none_line(alone)
