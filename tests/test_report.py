"""``adaptive-cal report DIR``: one self-contained HTML page per run, checked as text and as
rendered by headless Chromium (skipped, with the reason, where chromium is not installed)."""
import base64
import contextlib
import io
import json
import os
import re
import shutil
import subprocess
import tempfile
from html import escape
from pathlib import Path

import numpy as np
import pytest
import yaml

from adaptive_cal.analysis import flatness as fl
from adaptive_cal.cli import main
from adaptive_cal.report.sections import rotation

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A finished simulated run (a quick bound) with explain's findings beside it."""
    d = tmp_path_factory.mktemp("run")
    cell = yaml.safe_load((ROOT / "configs" / "sim-cell.yaml").read_text())
    cell["plan"].update(candidates=2000, stop={"mean_std_mm": 0.006, "max_touches": 40})
    path = d / "quick-cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    out = d / "run"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["run", "--robot", str(path), "--out", str(out), "--no-progress"]) == 0
    (d / "run-stdout.txt").write_text(printed.getvalue())  # the terminal summary, for the tests
    return out


@pytest.fixture(scope="module")
def explained(run_dir, tmp_path_factory):
    d = tmp_path_factory.mktemp("explained") / "run"
    shutil.copytree(run_dir, d)
    assert main(["explain", str(d / "recording.csv"), "--robot", str(d / "cell.yaml"),
                 "--json", str(d / "explain.json"), "--out", str(d)]) == 0
    return d


def _page(d, capsys):
    assert main(["report", str(d)]) == 0
    assert f"wrote {d / 'report.html'}" in capsys.readouterr().out
    return (d / "report.html").read_text(encoding="utf-8")


def test_rotation_turns_z_onto_the_plate_normal():
    for a, b in [(0.014, 0.0019), (-0.03, 0.02), (0.0, -0.05)]:
        rx, ry = fl.tilt_correction_deg(a, b)
        n = np.array([-a, -b, 1.0]) / np.sqrt(1 + a * a + b * b)
        np.testing.assert_allclose(rotation(rx, ry) @ [0, 0, 1], n, atol=1e-12)
        R = rotation(rx, ry)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_page_is_self_contained_with_every_section_and_unit(run_dir, capsys):
    html = _page(run_dir, capsys)
    result = json.loads((run_dir / "result.json").read_text())
    t, ls = result["tilt"], result["flatness_mm"]["least_squares"]
    # nothing fetched from elsewhere: no links, scripts or remote images
    assert not re.search(r"<(script|link|iframe)\b", html)
    assert not re.search(r"src=['\"](?!data:image/png;base64,)", html)
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", html)
    assert len(images) >= 3  # touches, surface, convergence
    for b64 in images:
        assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"
    for heading in ("Tilt correction for the controller", "Flatness", "Touches on the plate",
                    "Surface and its uncertainty", "Convergence", "The run", "The cell", "Explain"):
        assert f">{heading}" in html, heading
    # the controller's numbers, in deg, and the corrected user frame
    assert f"rx {t['rx_deg']:+.4f} deg" in html and f"ry {t['ry_deg']:+.4f} deg" in html
    assert (f"frame_new = frame_nominal * rotx({t['rx_deg']:+.4f} deg) * "
            f"roty({t['ry_deg']:+.4f} deg)") in html
    assert f"rotx({np.radians(t['rx_deg']):+.6f})" in html  # RoboDK takes radians
    # flatness with its interval, in um, as the terminal prints it
    assert f"{ls['value'] * 1e3:.1f} um" in html
    assert f"(95 % {ls['ci95'][0] * 1e3:.1f} .. {ls['ci95'][1] * 1e3:.1f} um)" in html
    assert "of the whole plate (from the map)" in html and "touched points as measured (Cheng eqs. 1-6;" in html
    assert "minimum zone (ISO 1101)" in html and "95 % interval" in html
    assert "No explain findings" in html  # and it says how to get them
    # the closure touch's verdict, as the terminal says it
    assert result["closure"]["made"] and "closure touch (drift)" in html
    assert escape(result["closure"]["text"]) in html
    assert result["closure"]["text"] in (run_dir.parent / "run-stdout.txt").read_text()


def test_explain_findings_appear_when_present(explained, capsys):
    html = _page(explained, capsys)
    rep = json.loads((explained / "explain.json").read_text())
    assert "Explain: what the simulation left out" in html
    assert f"verdict: <b>{rep['verdict']}</b> (probability {rep['verdict_probability']:.2f}" in html
    assert "leave-one-out RMS" in html
    assert "residual_map.png" in html  # explain's own figure, embedded
    assert "No explain findings" not in html
    assert "Out of date" not in html and "out of date" not in html  # of this very recording


def test_report_says_what_is_unexplained_where_and_what_was_set_aside(explained, tmp_path,
                                                                      capsys):
    """An ``unexplained`` verdict with its axis, detail and places, the suspect readings and the
    noise judgement reach the page, as the terminal prints them (escaped)."""
    d = tmp_path / "run"
    shutil.copytree(explained, d)
    rep = json.loads((d / "explain.json").read_text())
    rep.update({
        "verdict": "unexplained", "verdict_probability": 0.981, "ambiguous_with": [],
        "unexplained": {"axis": "time", "test": "serial correlation", "p_value": 1e-3,
                        "structure_rms_mm": 0.004, "library_share": 0.0,
                        "nearest_library_effect": None,
                        "where": [{"x_mm": 55.0, "y_mm": 15.0, "residual_mm": 0.0054}],
                        "detail": "consecutive readings are correlated (lag-1 +0.32) <x>"},
        "suspect_readings": [{"seq": 7, "x_mm": -20.0, "y_mm": 40.0, "residual_mm": 0.061,
                              "probability": 0.99}],
        "readings": {"total": 31, "used": 30, "suspect": 1, "noise": {
            "distribution": "gaussian", "dof": None, "log_lr_vs_gaussian": 0.0,
            "judged_under": "none",
            "serial": {"lag1_correlation": 0.32, "evidence_factor": 0.47}}}})
    (d / "explain.json").write_text(json.dumps(rep))
    html = _page(d, capsys)
    assert ("verdict: <b>unexplained</b> (probability, bounded from the structure test&#x27;s "
            "p-value 0.98)") in html
    assert "unexplained structure along time: consecutive readings are correlated" in html
    assert "&lt;x&gt;" in html and "<x>" not in html  # the detail is escaped
    assert "near x 55, y 15 mm: residual +5.4 um" in html
    assert "suspect readings, set aside (not physics): 1 of 31" in html
    assert "seq 7 at x -20, y 40 mm: residual +61.0 um, P(gross error) 0.99" in html
    assert "every log Bayes factor scaled by 0.47" in html


def test_out_option_and_errors_without_traceback(run_dir, tmp_path, capsys):
    target = tmp_path / "elsewhere" / "page.html"
    assert main(["report", str(run_dir), "--out", str(target)]) == 0
    assert target.read_text(encoding="utf-8").startswith("<!DOCTYPE html>")
    capsys.readouterr()
    assert main(["report", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "adaptive-cal report: error:" in err and "no such folder" in err
    assert "Traceback" not in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(empty)]) == 2
    err = capsys.readouterr().err
    assert "result.json: missing" in err and "adaptive-cal run --out DIR" in err


def test_without_belief_npz_a_cut_recording_is_refused_and_the_page_says_it_cannot_check(
        run_dir, tmp_path, capsys):
    """An outside audit (2026-12-01): with belief.npz deleted, a recording cut to 4 of its
    touches gave a page of result.json's touches beside a figure of 4, exit 0, no word."""
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    (d / "belief.npz").unlink()
    assert main(["report", str(d)]) == 0
    assert "belief.npz is missing" in capsys.readouterr().err
    lines = (d / "recording.csv").read_text().splitlines(keepends=True)
    (d / "recording.csv").write_text("".join(lines[:8]))
    assert main(["report", str(d)]) == 2
    err = capsys.readouterr().err
    assert "result.json counts" in err and "belief.npz, whose digest" in err, err


@pytest.mark.skipif(CHROMIUM is None, reason="headless render check needs chromium "
                    "(Debian: apt-get install -y chromium); .ci/run installs it")
def test_renders_in_headless_chromium(explained, capsys):
    from matplotlib.image import imread

    _page(explained, capsys)
    shot = Path(os.environ.get("ADAPTIVE_CAL_SCREENSHOT_DIR") or explained) / "report.png"
    shot.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.run(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", "--no-first-run",
             f"--user-data-dir={profile}", f"--screenshot={shot}", "--window-size=1200,3000",
             (explained / "report.html").as_uri()],
            capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    img = imread(shot)[..., :3]
    assert img.shape[:2] == (3000, 1200)
    ink = np.any(img < 0.9, axis=-1)
    assert ink.mean() > 0.05, "the page rendered (nearly) blank"
    # the embedded figures decoded: the viridis/magma maps put strongly coloured pixels on the page
    saturation = img.max(axis=-1) - img.min(axis=-1)
    assert (saturation > 0.4).mean() > 0.01, "no coloured figure pixels: images did not render"


def _flatness_lines(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if line.strip().startswith("flatness of")]


def test_run_flatness_and_report_give_the_same_answer_to_the_digit(run_dir, capsys):
    """Issue 17 item 3: both answers (touched points, whole plate) in the same words and digits
    from run's summary, `flatness` on the run folder's recording, and the report page."""
    from html import unescape

    from adaptive_cal.analysis.flatness_answer import value_text

    run_lines = _flatness_lines((run_dir.parent / "run-stdout.txt").read_text())
    assert len(run_lines) == 2 and "touched points" in run_lines[0] and "whole plate" in run_lines[1]
    assert main(["flatness", str(run_dir / "recording.csv")]) == 0
    assert _flatness_lines(capsys.readouterr().out) == run_lines
    result = json.loads((run_dir / "result.json").read_text())
    page = unescape(_page(run_dir, capsys))
    for answer in ("touched_flatness_mm", "flatness_mm"):
        for key in ("least_squares", "minimum_zone"):
            text = value_text(result[answer][key])
            assert text in page and any(text in line for line in run_lines), (answer, key, text)


def test_every_point_estimate_lies_inside_its_own_interval(run_dir):
    result = json.loads((run_dir / "result.json").read_text())
    for answer in ("touched_flatness_mm", "flatness_mm"):
        for key, f in result[answer].items():
            if isinstance(f, dict):
                lo, hi = f["ci95"]
                assert lo <= f["value"] <= hi, (answer, key, f)
                assert f["value_is"]


def test_entry_falls_back_to_the_posterior_median_outside_the_interval():
    from adaptive_cal.analysis.flatness_answer import MEDIAN, answer_lines, entry

    samples = np.linspace(1.0, 2.0, 401)  # 95 % interval 1.025 .. 1.975, median 1.5
    inside = entry(1.2, samples, "figure")
    assert inside == {"value": 1.2, "ci95": [1.025, 1.975], "value_is": "figure"}
    below = entry(0.5, samples, "figure")
    assert below["value"] == pytest.approx(1.5) and below["value_is"] == MEDIAN
    lines = answer_lines({"flatness_mm": {"least_squares": below, "minimum_zone": inside}})
    assert "least squares 1500.0 um* = 1.50 mm (95 % 1025.0 .. 1975.0 um)" in lines[0]
    assert any(line.startswith("* posterior median") for line in lines)


def test_report_from_a_bare_recording_with_its_cell(run_dir, tmp_path, capsys):
    """Issue 17 item 10: report RECORDING.csv --robot CELL.yaml replays the recording and renders
    the same page, said to be built from a recording; its numbers are `flatness --robot`'s."""
    from html import unescape

    rec = tmp_path / "bare.csv"
    shutil.copyfile(run_dir / "recording.csv", rec)
    cell = tmp_path / "cell.yaml"
    shutil.copyfile(run_dir / "cell.yaml", cell)
    assert main(["report", str(rec)]) == 2
    err = capsys.readouterr().err
    assert "--robot CELL.yaml" in err and "Traceback" not in err
    assert main(["report", str(rec), "--robot", str(cell)]) == 0
    out = tmp_path / "bare.html"
    assert f"wrote {out}" in capsys.readouterr().out
    page = unescape(out.read_text(encoding="utf-8"))
    assert "Built from a recording, not a run" in page
    for heading in ("Tilt correction for the controller", "Flatness", "Touches on the plate",
                    "Surface and its uncertainty", "The run", "The cell"):
        assert f">{heading}" in page, heading
    assert main(["flatness", str(rec), "--robot", str(cell)]) == 0
    lines = _flatness_lines(capsys.readouterr().out)
    assert len(lines) == 2
    # every "V um (95 % L .. H um)" of the terminal is on the page
    texts = [t for line in lines
             for t in re.findall(r"\d+\.\d um\*? \(95 % [\d.]+ \.\. [\d.]+ um\)", line)]
    assert len(texts) == 4
    for text in texts:
        assert text in page, text


def test_a_bare_recordings_page_judges_its_closure_touch_again(run_dir, tmp_path, capsys):
    """A page built from a bare recording showed no drift check; the run folder's page did. It
    is judged again from the recording now (the map of the readings before it): the run's
    verdict within a fifth of its sd (the run also relearns the noise without the drift), and a
    closure reading moved by 10 sd is called a drift."""
    import json
    from html import unescape

    closure = json.loads((run_dir / "result.json").read_text())["closure"]
    assert closure["made"]
    cell = tmp_path / "cell.yaml"
    shutil.copyfile(run_dir / "cell.yaml", cell)
    lines = (run_dir / "recording.csv").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("seq,"))
    cols = lines[head].split(",")
    for name, shift in (("same", 0.0), ("drift", 10 * closure["sd_mm"])):
        moved = list(lines)
        for i in range(head + 1, len(moved)):
            p = moved[i].split(",")
            if "closure" in p[cols.index("flags")]:
                r = cols.index("reading_mm")
                p[r] = f"{float(p[r]) + shift:.6f}"
                moved[i] = ",".join(p)
        rec = tmp_path / f"{name}.csv"
        rec.write_text("\n".join(moved) + "\n")
        assert main(["report", str(rec), "--robot", str(cell)]) == 0
        capsys.readouterr()
        page = unescape((tmp_path / f"{name}.html").read_text(encoding="utf-8"))
        row = page[page.index("closure touch (drift)"):][:700]
        assert "judged again from the recording" in row
        if name == "same":
            import re
            d = float(re.search(r"read ([+-]\d+\.\d) um against", row).group(1)) / 1e3
            assert abs(d - closure["difference_mm"]) < 0.2 * closure["sd_mm"] + 5e-5
            assert "no drift seen" in row
        else:
            assert "the cell drifted during the run" in row


def test_explain_findings_of_an_earlier_recording_are_said_and_only_its_figures_shown(
        explained, tmp_path, capsys):
    """An outside audit: a run resumed after explain showed the earlier findings as the run's,
    and a second explain left the first one's figures embedded under its new verdict."""
    d = tmp_path / "run"
    shutil.copytree(explained, d)
    findings = json.loads((d / "explain.json").read_text())
    (d / "fitted_effect.png").write_bytes((d / "residual_map.png").read_bytes())  # an old one
    findings["readings"]["total"] -= 5  # as if explained before the last five touches
    (d / "explain.json").write_text(json.dumps(findings))
    html = _page(d, capsys)
    result = json.loads((d / "result.json").read_text())
    assert (f"<b>Out of date:</b> explain.json was made from {findings['readings']['total']} "
            f"readings; the run has {result['fused']} fused now") in html
    assert "out of date, of an earlier recording" in html  # its card too
    listed = {Path(f).name for f in findings["figures"]}
    assert "fitted_effect.png" not in listed and "alt='fitted_effect.png'" not in html
    assert all(f"alt='{name}'" in html for name in listed)
    # the page's --out never replaces a file the page embeds
    capsys.readouterr()
    for name in ("convergence.png", "surface.png", "residual_map.png"):
        assert main(["report", str(d), "--out", str(d / name)]) == 2
        assert "itself" in capsys.readouterr().err


def test_the_pages_explain_words_and_units_are_the_terminals(explained, tmp_path, capsys):
    """A left-out warm-up as explain.json holds it (mm, s): the page says it as the terminal
    does, in um with the terminal's digits (it printed the raw "amplitude_mm = 0.1991")."""
    from adaptive_cal.effects import EFFECTS
    from adaptive_cal.report.explain_text import left_out_line

    d = tmp_path / "run"
    shutil.copytree(explained, d)
    rep = json.loads((d / "explain.json").read_text())
    rep["left_out"] = [{"effect": "thermal_drift", "log_bayes_factor": 222.96,
                        "params": {"amplitude_mm": 0.1991, "tau_s": 61.6755},
                        "params_std": {"amplitude_mm": 0.003863, "tau_s": 3.2},
                        "summary": "amplitude_mm = 0.1991 +- 0.003863 at tau_s = 61.6755"}]
    (d / "explain.json").write_text(json.dumps(rep))
    html = _page(d, capsys)
    units = {name: {p.name: p.unit for p in e.params} for name, e in EFFECTS.items()}
    line = left_out_line(rep["left_out"][0], units["thermal_drift"], rep["verdict"]).strip()
    assert "199.1" in line and f"<li>{escape(line)}</li>" in html
    assert "amplitude_mm = 0.1991" not in html


def test_a_missing_recording_is_said_missing(tmp_path, capsys):
    assert main(["report", str(tmp_path / "typo.csv"), "--robot",
                 str(ROOT / "configs" / "cheng2025-cell.yaml")]) == 2
    assert "typo.csv: no such recording" in capsys.readouterr().err


def test_a_run_a_device_stopped_says_what_stopped_it_on_the_page(run_dir, tmp_path, capsys):
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    result = json.loads((d / "result.json").read_text())
    result.update(stopped_because="interrupted", error="THE PROBE MAY BE DOWN at x=1 <y>")
    (d / "result.json").write_text(json.dumps(result))
    html = _page(d, capsys)
    assert "<b>What stopped the run:</b> THE PROBE MAY BE DOWN at x=1 &lt;y&gt;" in html


@pytest.mark.parametrize("damage", [("tilt", None), ("posterior", "gone"), ("touches", True)])
def test_a_result_json_without_what_the_page_needs_is_named_not_an_internal_error(
        run_dir, tmp_path, capsys, damage):
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    key, value = damage
    result = json.loads((d / "result.json").read_text())
    if value == "gone":
        del result[key]
    else:
        result[key] = value
    (d / "result.json").write_text(json.dumps(result))
    for argv in (["report", str(d)], ["flatness", str(d / "recording.csv")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"{d / 'result.json'}: " in err and repr(key) in err, err
        assert "internal error" not in err
        # where the map can come from instead
        assert f"adaptive-cal report {d / 'recording.csv'} --robot {d / 'cell.yaml'}" in err


def test_a_map_older_than_its_recording_is_refused_naming_both_counts(run_dir, tmp_path, capsys):
    """A resumed run killed before it saved again leaves result.json and belief.npz of fewer
    touches than recording.csv: report and flatness refuse, naming both counts and the replay
    (an outside audit: the page showed the 20-touch map under a 104-touch recording, exit 0)."""
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    lines = (d / "recording.csv").read_text(encoding="utf-8").splitlines(keepends=True)
    last = lines[-1].split(",")
    more = [",".join([str(int(last[0]) + k), *last[1:]]) for k in (1, 2)]
    (d / "recording.csv").write_text("".join(lines) + "".join(
        m if m.endswith("\n") else m + "\n" for m in more), encoding="utf-8")
    touches = int(np.load(d / "belief.npz")["touches"])
    for argv in (["report", str(d)], ["flatness", str(d / "recording.csv")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"holds {touches + 2} touches" in err and f"the first {touches}" in err, err
        assert "--robot" in err and "run --resume" in err


def test_the_page_says_what_the_terminal_says_under_the_flatness_and_the_keep_outs(
        run_dir, tmp_path, capsys):
    """The page carries the terminal's lines the audit found missing: what the whole plate's
    intervals held on plates the prior did not make, each never-touched keep-out's line, and
    the readings weighted out of the map."""
    from adaptive_cal.analysis.flatness_answer import PLATE_CALIBRATION
    from adaptive_cal.analysis.local_features import weighted_out, weighted_out_line

    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    page = _page(d, capsys)
    result = json.loads((d / "result.json").read_text())
    assert escape(PLATE_CALIBRATION) in page
    texts = [k["text"] for k in result["keep_outs"]]
    assert texts and all(escape(t) in page for t in texts)
    assert result["weighted_out"] == [] and "weighted out of the map" not in page
    out = weighted_out([4, 9, 12], [1.0, 0.5, 0.02])
    assert out == [{"seq": 9, "outlier_probability": 0.5},
                   {"seq": 12, "outlier_probability": 0.98}]
    assert weighted_out_line(out).startswith("2 readings weighted out of the map as gross errors "
                                             "(outlier probability >= 0.5): seq 9 (p 0.50), seq "
                                             "12 (p 0.98); the touched points' figures include "
                                             "them")


def test_an_unmet_bound_the_cell_never_set_is_said_to_be_the_default(tmp_path):
    """The reference cell's file sets no bound: a replay of its round 0 is incomplete against
    plan.stop.mean_std_mm's default, and the page says so (an outside audit read a bound the
    cell never named)."""
    out = tmp_path / "c0.html"
    assert main(["report", str(ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"),
                 "--robot", str(ROOT / "configs" / "cheng2025-cell.yaml"), "--out", str(out)]) == 0
    page = out.read_text(encoding="utf-8")
    assert escape("um bound (plan.stop.mean_std_mm's default: the cell file sets none)") in page


def test_report_takes_one_round_of_a_recording_that_holds_two(tmp_path, capsys):
    """A recording of two rounds (the reference cell's 0 and 1 in one file, a round column):
    refused without --round naming report --round, and with it the round's own page."""
    data = ROOT / "adaptive_cal" / "data" / "cheng2025"
    rows, seq = [], 0
    for r, name in enumerate(("round0_initial.csv", "round1_first_correction.csv")):
        lines = [ln for ln in (data / name).read_text().splitlines() if not ln.startswith("#")]
        header = lines[0].split(",")
        for ln in lines[1:]:
            cells = dict(zip(header, ln.split(",")))
            cells["seq"] = str(seq)
            seq += 1
            rows.append(",".join([cells[c] for c in header] + [str(r)]))
    two = tmp_path / "two.csv"
    two.write_text("# adaptive-cal recording v1\n" + ",".join(header + ["round"]) + "\n"
                   + "\n".join(rows) + "\n")
    cell = str(ROOT / "configs" / "cheng2025-cell.yaml")
    assert main(["report", str(two), "--robot", cell]) == 2
    assert "report --round R" in capsys.readouterr().err
    assert main(["report", str(two), "--robot", cell, "--round", "1"]) == 0
    assert (tmp_path / "two-round1.html").is_file()
    assert main(["report", str(two), "--robot", cell, "--round", "7"]) == 2
    assert "--round 7" in capsys.readouterr().err


def test_report_and_flatness_refuse_a_saved_map_that_is_not_a_posterior(run_dir, tmp_path,
                                                                       capsys):
    """A NaN in belief.npz's mean is refused by every reader of a saved map (formats.npz
    ``broken_belief``), not only by compensate's: the page and the flatness named no figure."""
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    data = dict(np.load(d / "belief.npz"))
    data["mean"][3] = np.nan
    np.savez(d / "belief.npz", **data)
    for argv in (["report", str(d)], ["flatness", str(d / "recording.csv")]):
        assert main(argv) == 2
        assert "belief.npz: array 'mean' is not a map's" in capsys.readouterr().err


def test_a_finished_run_missing_belief_npz_is_not_told_to_resume(run_dir, tmp_path, capsys):
    """compensate on a finished run whose belief.npz was deleted said the run stopped before
    writing its results and sent the user to --resume, which moves the robot (an audit)."""
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    (d / "belief.npz").unlink()
    gcode = tmp_path / "p.gcode"
    gcode.write_text("G90 G21\nG0 X0 Y0 Z5\nG1 X10 Y0 Z-0.1 F300\n")
    assert main(["compensate", str(gcode), "--map", str(d), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "belief.npz was removed or not copied" in err and "--resume" not in err, err
