"""An unfinished run is never presented as a result (terminal summary and HTML report open with
what is missing, the tilt correction is provisional), and a failed start leaves nothing in
--out that blocks a retry."""
import os
import socket
import subprocess
import sys

import pytest
import yaml

from adaptive_cal.cli import main
from adaptive_cal.cli.run import _summary
from adaptive_cal.report.status import missing
from adaptive_cal.run import session

from helpers import ROOT, sim_cell


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory):
    """A simulated run stopped after 9 touches, far from its 4 um bound."""
    out = tmp_path_factory.mktemp("interrupted") / "run"
    cell = sim_cell(plan={"candidates": 2000})
    out.mkdir()
    (out / "cell.yaml").write_text((ROOT / "configs" / "sim-cell.yaml").read_text())
    result = session.run(cell, out, progress=False, max_new_touches=9)
    assert result["stopped_because"] == "interrupted" and result["touches"] == 9
    return out, result


def _result(why, touches=30, mean=0.0035, bound=0.004, max_std=None):
    return {"stopped_because": why, "touches": touches,
            "bound": {"mean_std_mm": bound, "max_std_mm": max_std, "max_touches": 120},
            "posterior": {"mean_std_mm": mean, "max_std_mm": 0.009}}


def test_what_is_missing_in_words():
    assert missing(_result("mean_std_bound")) is None
    assert missing(_result("touch_budget", bound=None)) is None  # no bound: the budget is the end
    assert missing(_result("interrupted", 9, 0.039)) == (
        "interrupted after 9 touches; posterior RMS std 39.0 um against the 4 um bound")
    assert missing(_result("touch_budget", 120, 0.0051)) == (
        "touch budget spent after 120 touches; posterior RMS std 5.1 um against the 4 um bound")
    assert missing(_result("no_admissible_point", 3, 0.2)).startswith(
        "stopped: no admissible point after 3 touches; posterior RMS std 200.0 um")
    assert "posterior max std 9.0 um against the 5 um bound" in missing(
        _result("touch_budget", 120, bound=None, max_std=0.005))


def test_terminal_summary_of_an_interrupted_run_opens_with_what_is_missing(interrupted, capsys):
    out, result = interrupted
    _summary(result, out)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("INCOMPLETE: interrupted after 9 touches; posterior RMS std ")
    assert lines[0].endswith(f"um against the 4 um bound. Not a result. Continue with adaptive-cal run --resume {out}")
    assert any(line.startswith("tilt correction (provisional): rx ") for line in lines)


def test_terminal_summary_of_a_finished_run_is_unchanged(capsys):
    r = {**_result("mean_std_bound"), "fused": 29,
         "tilt": {"rx_deg": 0.1, "ry_deg": -0.8, "a": 0.014, "b": 0.0019, "c": 0.2},
         "flatness_mm": {k: {"value": 0.27, "ci95": [0.26, 0.28]}
                         for k in ("least_squares", "minimum_zone")}}
    _summary(r, "runs/x")
    text = capsys.readouterr().out
    assert text.startswith("stopped: RMS std bound met (mean_std_bound) after 30 touches (29 fused)\n")
    assert "INCOMPLETE" not in text and "provisional" not in text
    assert "tilt correction: rx +0.1000 deg, ry -0.8000 deg" in text


def test_report_of_an_interrupted_run_opens_with_what_is_missing(interrupted, capsys):
    out, _ = interrupted
    assert main(["report", str(out)]) == 0
    page = (out / "report.html").read_text(encoding="utf-8")
    banner = page.index("INCOMPLETE: interrupted after 9 touches; posterior RMS std")
    assert banner < page.index("Tilt correction for the controller (provisional)")
    assert banner < page.index("class='cards'")
    assert "tilt correction (provisional)" in page
    assert f"adaptive-cal run --resume {out}" in page
    # the flatness too, in its card and its section (an audit found them unmarked)
    assert banner < page.index("<h2>Flatness (provisional)</h2>")
    cards = page[page.index("class='cards'"):]
    assert "provisional" in cards[cards.index("flatness"):cards.index("RMS posterior std")]


def _silent_cell(tmp_path):
    """The emulated HSES cell pointed at a UDP port nothing listens on."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    data = yaml.safe_load((ROOT / "configs" / "cell-hses-emulated.yaml").read_text())
    data["robot"]["hses"]["port"] = port
    path = tmp_path / "silent-cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_failed_start_leaves_nothing_that_blocks_a_retry(tmp_path):
    """The HSES cell with no controller listening: it does not answer."""
    out = tmp_path / "runs" / "x"
    cmd = [sys.executable, "-m", "adaptive_cal.cli", "run", "--robot", str(_silent_cell(tmp_path)),
           "--out", str(out), "--yes", "--no-progress"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    for _ in range(2):  # the retry fails the same way, not on a folder left behind
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
        assert p.returncode == 2, p.stderr
        assert "no answer" in p.stderr and "run the same command again" in p.stderr
        assert "exists" not in p.stderr and "Traceback" not in p.stderr
        assert not (tmp_path / "runs").exists()


def test_a_failed_start_keeps_what_the_folder_held(tmp_path, capsys):
    out = tmp_path / "x"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    rc = main(["run", "--robot", str(_silent_cell(tmp_path)), "--out", str(out), "--yes",
               "--no-progress"])
    assert rc == 2
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_a_spent_budget_is_continued_with_a_larger_one_as_the_advice_says(tmp_path, capsys):
    """A run that spent its budget said 'Continue with adaptive-cal run --resume DIR', which
    answered 'already finished: nothing to do' (outside CLI audit). The advice names the larger
    plan.stop.max_touches it needs, and that resume goes on."""
    from adaptive_cal.report.status import next_step

    assert next_step(_result("touch_budget", 6, 0.1), "adaptive-cal run --resume r") == (
        "Continue with adaptive-cal run --resume r --robot MORE.yaml, a copy of the run's "
        "cell.yaml with a larger plan.stop.max_touches")
    data = yaml.safe_load((ROOT / "configs" / "sim-cell.yaml").read_text())
    data["plan"]["stop"]["max_touches"] = 6
    (tmp_path / "six.yaml").write_text(yaml.safe_dump(data))
    data["plan"]["stop"]["max_touches"] = 9
    (tmp_path / "more.yaml").write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    assert main(["run", "--robot", str(tmp_path / "six.yaml"), "--out", str(run),
                 "--no-progress"]) == 1
    assert "--robot MORE.yaml, a copy of the run's cell.yaml" in capsys.readouterr().out
    assert main(["run", "--resume", str(run), "--robot", str(tmp_path / "more.yaml"),
                 "--no-progress"]) == 1
    assert "stopped: touch budget spent after 9 touches" in capsys.readouterr().out
