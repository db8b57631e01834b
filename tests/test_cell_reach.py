"""A cell whose plate no touch can reach is refused before any device is opened, naming what
to change (an outside safety audit, 2026-11-24): a workspace z range that leaves out the
approach height over the plate was blamed on the prior ("narrow model.offset_std_mm") and, on a
real controller, refused only after connecting; keep-outs that cover the plate together (each
one alone does not) got a bare "check workplane margin and keep_outs"."""
import contextlib
import io

import pytest
import yaml

from adaptive_cal.cell.schema import ConfigError, parse_cell
from adaptive_cal.cli import main

from helpers import SIM_CELL


def _cell(tmp_path, **change):
    data = yaml.safe_load(SIM_CELL.read_text())
    for key, value in change.items():
        block, leaf = key.split(".")
        data[block][leaf] = value
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path, data


def test_a_workspace_z_range_without_the_approach_height_is_named(tmp_path):
    path, _ = _cell(tmp_path, **{"workspace.z_mm": [5, 60]})
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["run", "--robot", str(path), "--out", str(tmp_path / "run"), "--no-progress"])
    assert code == 2
    text = err.getvalue()
    assert "workspace.z_mm [5.0, 60.0] mm" in text and "approach height of 0 mm" in text
    assert "offset_std_mm" not in text
    assert not (tmp_path / "run" / "recording.csv").exists()


def test_keep_outs_that_cover_the_plate_together_are_refused_at_load(tmp_path):
    _, data = _cell(tmp_path)
    data["workplane"]["keep_outs"] = [{"x_mm": [-300, 0.5], "y_mm": [-300, 300]},
                                      {"x_mm": [0, 300], "y_mm": [-300, 300]}]
    with pytest.raises(ConfigError, match="keep_outs cover the whole plate together"):
        parse_cell(data, "cell")
    data["workplane"]["keep_outs"][1]["x_mm"] = [1, 300]  # a 0.5 mm strip left free
    parse_cell(data, "cell")


def test_an_interrupt_outside_the_touch_loop_says_the_recording_is_kept(tmp_path, monkeypatch):
    """Ctrl-C outside the loop (at set-up or while the results are written) reached the top
    level, which said only "interrupted"; the recording was intact and --resume continued it."""
    import adaptive_cal.cli.run as run_cli

    out = tmp_path / "run"
    out.mkdir()
    (out / "recording.csv").write_text("# adaptive-cal recording v1\n")

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(run_cli, "command", interrupted)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["run", "--robot", str(SIM_CELL), "--out", str(out)]) == 130
    assert f"--resume {out} continues it" in err.getvalue()
    err = io.StringIO()
    with contextlib.redirect_stderr(err):  # nothing recorded: nothing to resume
        assert main(["run", "--robot", str(SIM_CELL), "--out", str(tmp_path / "new")]) == 130
    assert err.getvalue().strip() == "adaptive-cal run: interrupted"


def test_a_reversed_gauge_range_is_refused_at_load():
    from adaptive_cal.cell.schema import load_yaml
    from conftest import ROOT

    data = load_yaml(ROOT / "configs" / "cell-hses-emulated.yaml")
    data["probe"]["serial"]["range_mm"] = [10, 0]
    with pytest.raises(ConfigError, match=r"probe.serial.range_mm: .*\[10.0, 0.0\] must be "
                                          r"\[low, high\]"):
        parse_cell(data, "cell")


def test_a_device_that_never_answered_is_not_resumed(tmp_path, monkeypatch):
    """Nothing recorded: the adapter's "then continue with --resume" became "run the same
    command again", the one the next line gives (the two disagreed)."""
    from adaptive_cal.hardware.base import AdapterError
    from adaptive_cal.run import session

    def no_answer(*a, **k):
        raise AdapterError("robot.hses 127.0.0.1:10940: no answer; check the network, then "
                           "continue with --resume")

    monkeypatch.setattr(session, "open_cell", no_answer)
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert main(["run", "--robot", str(SIM_CELL), "--out", str(tmp_path / "r")]) == 2
    text = err.getvalue()
    assert "then run the same command again." in text and "continue with --resume" not in text
    assert "run the same command again (not --resume)" in text
