"""The explain subcommand: files it writes, the JSON it promises, and bad input."""
import json
import re

import numpy as np
import pytest
import yaml

from adaptive_cal.cli import main
from adaptive_cal.cell.schema import load_cell
from conftest import ROOT

CELL = ROOT / "configs" / "cheng2025-cell.yaml"
KEYS = {"verdict", "left_out", "not_identifiable", "mismatch", "fit", "model"}


def test_cli_on_the_reference_rounds(tmp_path, cheng_round0, cheng_round1, capsys):
    out = tmp_path / "out"
    rc = main(["explain", str(cheng_round0), str(cheng_round1), "--robot", str(CELL),
               "--json", str(tmp_path / "r.json"), "--out", str(out)])
    assert rc == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert KEYS <= set(rep)
    assert rep["verdict"] == "form"
    from adaptive_cal import __version__

    assert rep["software"] == f"adaptive-cal {__version__}" and rep["written_utc"].endswith("Z")
    e = rep["left_out"][0]
    assert {"effect", "params", "params_std", "log_bayes_factor", "summary"} <= set(e)
    for x in rep["not_identifiable"]:
        assert {"effect", "aliased_with", "why", "suggested_design"} <= set(x)
    assert set(rep["mismatch"]) >= {"rms_mm", "by", "where"}
    assert set(rep["mismatch"]["by"]) == {"position", "time", "direction", "reach", "indication"}
    assert set(rep["fit"]) >= {"rms_before_mm", "rms_after_mm", "cv_rms_before_mm", "cv_rms_after_mm"}
    cell = load_cell(rep["model"])  # the updated cell file is a valid cell with the effect
    assert cell.simulation.effects["form"]["pv_mm"] == pytest.approx(e["params"]["pv_mm"])
    for name in ("residual_map.png", "residual_vs_position.png", "fitted_effect.png"):
        assert (out / name).stat().st_size > 1000
    text = capsys.readouterr().out
    assert "verdict: form" in text and "flatness (least squares) 541.7 -> 596.0 um" in text


def _write(path, rows, header="seq,t_s,x_mm,y_mm,z_mm,reading_mm"):
    lines = ["# adaptive-cal recording v1", header] + [",".join(map(str, r)) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _grid_rows(n=40):
    rng = np.random.default_rng(0)
    xs = np.tile(np.linspace(-200, 200, 10), n // 10 + 1)[:n]
    ys = np.repeat(np.linspace(-165, 165, n // 10 + 1), 10)[:n]
    return [[i, "", x, y, 0, round(0.01 * x + 0.001 * rng.standard_normal(), 6)]
            for i, (x, y) in enumerate(zip(xs, ys))]


@pytest.mark.parametrize("mutate,expect", [
    (lambda r: r.__setitem__(7, [7, "", 300.0, 0.0, 0, 1.0]), ["seq 7", "x_mm", "300"]),
    (lambda r: r.__setitem__(slice(5, None), []), ["5 rows", "at least"]),
    (lambda r: r.__setitem__(3, [3, "", 0.0, 0.0, 0, "abc"]), [":6:", "reading_mm", "abc"]),
    (lambda r: r.__setitem__(4, [2, "", 0.0, 0.0, 0, 1.0]), [":7:", "seq", "does not increase"]),
])
def test_bad_recordings_name_line_or_column(tmp_path, capsys, mutate, expect):
    rows = _grid_rows()
    mutate(rows)
    path = _write(tmp_path / "bad.csv", rows)
    assert main(["explain", str(path), "--robot", str(CELL)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for word in expect:
        assert word in err, err


def test_missing_column_is_named(tmp_path, capsys):
    rows = [r[:5] for r in _grid_rows()]
    path = _write(tmp_path / "bad.csv", rows, header="seq,t_s,x_mm,y_mm,z_mm")
    assert main(["explain", str(path), "--robot", str(CELL)]) == 2
    assert "reading_mm" in capsys.readouterr().err


def test_known_arm_sag_without_base_is_a_config_error(tmp_path, capsys, cheng_round0):
    data = yaml.safe_load(CELL.read_text())
    data["simulation"]["effects"]["arm_sag"] = {"sag_mm_at_1m": 0.1, "p": 2}
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(data))
    assert main(["explain", str(cheng_round0), "--robot", str(cell)]) == 2
    assert "robot.base_xy_mm" in capsys.readouterr().err


def test_sim_is_a_hidden_alias_of_robot(tmp_path, cheng_round0, capsys):
    assert main(["explain", str(cheng_round0), "--sim", str(CELL),
                 "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["verdict"] == "form"
    assert main(["explain", str(cheng_round0)]) == 2
    assert "--robot CELL.yaml" in capsys.readouterr().err


def test_terminal_text_reads_in_um_one_line_per_finding(tmp_path, cheng_round0, cheng_round1, capsys):
    assert main(["explain", str(cheng_round0), str(cheng_round1), "--robot", str(CELL),
                 "--json", str(tmp_path / "r.json")]) == 0
    text = capsys.readouterr().out
    rep = json.loads((tmp_path / "r.json").read_text())
    lines = text.splitlines()
    form = [line for line in lines if line.startswith("  left out: form: ")]
    assert len(form) == 1  # one line per finding
    bow = rep["left_out"][0]["params"]["bow_y"]
    assert f"bow in y {bow * 1e3:+.1f} +- " in form[0]  # heights in um (README: a 0.33 mm bow)
    assert "against none" in form[0] and "log BF" not in text
    assert not re.search(r"\(z [-+]?\d", text)  # the standardized residual is not called z
    w = rep["mismatch"]["where"][0]
    assert (f"residual {w['residual_mm'] * 1e3:+.1f} um near x {w['x_mm']:g}, y {w['y_mm']:g} mm "
            f"({abs(w['z']):.1f} sd") in text
    gain = next(e for e in rep["not_identifiable"] if e["effect"] == "probe_gain")
    touches = gain["suggested_design"]["touches"]
    assert f"{len(touches)} touch(es) at x, y, z (mm): " in text  # the suggested touches printed
    for t in touches:
        assert f"({t['x_mm']:g}, {t['y_mm']:g}, {t['z_mm']:g})" in text
    assert "docs/explain.md" in lines[-2] and lines[-1].startswith("wrote ")  # then the files


def test_the_json_is_written_before_the_terminal_lines(tmp_path, cheng_round0, monkeypatch):
    """`explain ... --json OUT.json | head -1`: the reader leaves after one line, OUT.json is
    still written (it was written after the printing, which the closed pipe ends)."""
    import adaptive_cal.cli.explain as cli_explain

    def closed(report):
        raise BrokenPipeError
    monkeypatch.setattr(cli_explain, "_print", closed)
    out = tmp_path / "r.json"
    assert main(["explain", str(cheng_round0), "--robot", str(CELL), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["verdict"] == "form"


def test_a_touch_the_run_refused_off_the_workplane_does_not_refuse_the_recording(tmp_path, capsys):
    """A row flagged invalid;rejected (tell refused its position) is not used, so its position
    is not held against the recording; the same row unflagged is refused, naming it."""
    rows = [r + [""] for r in _grid_rows()]
    rows[7] = [7, "", 300.0, 0.0, 0, 0.0, "invalid;rejected"]
    header = "seq,t_s,x_mm,y_mm,z_mm,reading_mm,flags"
    ok = _write(tmp_path / "ok.csv", rows, header)
    assert main(["explain", str(ok), "--robot", str(CELL), "--no-figures"]) == 0
    rows[7][-1] = ""
    bad = _write(tmp_path / "bad.csv", rows, header)
    assert main(["explain", str(bad), "--robot", str(CELL), "--no-figures"]) == 2
    assert "seq 7" in capsys.readouterr().err


def test_an_effect_fitted_per_round_is_printed_round_by_round(tmp_path, cheng_round0,
                                                              cheng_round1, capsys):
    """Round 1 given a bow along x of its own: form is fitted per round, and the terminal said
    'internal error: TypeError' (an outside audit) after writing --json."""
    lines = cheng_round1.read_text().splitlines()
    head = [i for i, line in enumerate(lines) if line.startswith("seq,")][0]
    cols = lines[head].split(",")
    xi, ri = cols.index("x_mm"), cols.index("reading_mm")
    out = lines[:head + 1]
    for line in lines[head + 1:]:
        f = line.split(",")
        if len(f) == len(cols) and not line.startswith("#"):
            x = float(f[xi])
            f[ri] = f"{float(f[ri]) + 0.35 * ((x / 225.0) ** 2 - 1 / 3):.4f}"
        out.append(",".join(f))
    bowed = tmp_path / "round1_bowed.csv"
    bowed.write_text("\n".join(out) + "\n")
    js = tmp_path / "e.json"
    assert main(["explain", str(cheng_round0), str(bowed), "--robot", str(CELL),
                 "--json", str(js)]) == 0
    said = capsys.readouterr().out
    form = next(e for e in json.loads(js.read_text())["left_out"] if e["effect"] == "form")
    assert isinstance(form["params"]["bow_x"], list)  # per round
    assert "bow in x per round 0: " in said and ", 1: " in said


def test_an_earlier_explains_files_are_not_left_beside_new_findings(tmp_path, cheng_round0,
                                                                     capsys):
    """explain --out into a folder of an earlier explain left its figures and explained cell
    file there: a fitted_effect.png of a form beside a verdict none. They are removed once the
    new findings are written, and said."""
    out = tmp_path / "out"
    assert main(["explain", str(cheng_round0), "--robot", str(CELL), "--out", str(out)]) == 0
    first = {p.name for p in out.iterdir()}
    assert {"cheng2025-cell-explained.yaml", "fitted_effect.png", "residual_map.png"} <= first
    capsys.readouterr()
    # a level plate read with the probe's noise alone at the same touches: nothing to name
    rng = np.random.default_rng(5)
    text = cheng_round0.read_text().splitlines()
    head = [line for line in text if line.startswith("#")] + ["seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    rows = [line.split(",") for line in text if line and line[0].isdigit()]
    null = tmp_path / "null.csv"
    null.write_text("\n".join(head + [",".join(r[:5] + [f"{2.0 + 0.01 * rng.normal():.4f}"])
                                      for r in rows]) + "\n")
    (out / "notes.txt").write_text("mine")  # not explain's: stays
    assert main(["explain", str(null), "--robot", str(CELL), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "verdict: none" in said
    left = {p.name for p in out.iterdir()}
    assert "cheng2025-cell-explained.yaml" not in left and "fitted_effect.png" not in left
    assert "residual_map.png" in left and "notes.txt" in left
    removed = next(line for line in said.splitlines() if line.startswith("removed "))
    assert "cheng2025-cell-explained.yaml" in removed and "fitted_effect.png" in removed
    assert "notes.txt" not in removed and removed.endswith("do not go with these findings")
