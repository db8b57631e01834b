"""The command line explains itself: every option in --help with its unit and default, and
errors on stderr with a non-zero exit and no traceback (unless --debug)."""
import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from adaptive_cal.cli import SUBCOMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[1]
CHENG0 = ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"

# options whose value has a unit: the unit their help must name
UNITS = {
    ("run", "--prior-from"): "(mm)",
    ("emulate", "--move-s"): "(s)",
    ("emulate", "--seconds"): "seconds",
}


def _help(argv, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main(argv + ["--help"])
    assert e.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # unwrap the formatter's line breaks


def _actions(name):
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return [a for a in sub.choices[name]._actions if not isinstance(a, argparse._HelpAction)]


def test_top_level_help_lists_every_command_and_the_units(capsys):
    text = _help([], capsys)
    assert "mm, s, deg" in text and "--debug" in text
    for name, (_, line) in SUBCOMMANDS.items():
        assert name in text
        assert " ".join(line.split()) in text


@pytest.mark.parametrize("name", sorted(SUBCOMMANDS))
def test_each_command_lists_its_options_with_defaults(name, capsys):
    text = _help([name], capsys)
    for action in _actions(name):
        if action.help == argparse.SUPPRESS:  # a hidden alias (explain --sim) is not listed
            continue
        shown = action.option_strings[0] if action.option_strings else action.metavar or action.dest
        assert shown in text, f"{name}: {shown} missing from --help"
        assert action.help, f"{name}: {shown} has no help text"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            assert f"(default: {action.default})" in text, f"{name}: {shown} hides its default"


@pytest.mark.parametrize("name, option, unit", [(n, o, u) for (n, o), u in UNITS.items()])
def test_options_with_a_unit_name_it(name, option, unit, capsys):
    text = _help([name], capsys)
    start = text.index(option + " ", text.index("options:"))  # its entry, not the usage line
    assert unit in text[start:start + 200], f"{name} {option}: unit {unit} not in its help"


def test_report_help(capsys):
    text = _help(["report"], capsys)
    assert "DIR" in text and "(default: DIR/report.html" in text and "(default: None)" not in text


def _fails(argv, capsys, *expected):
    assert main(argv) != 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err and "Traceback" not in out.out
    assert out.err.startswith(f"adaptive-cal {argv[0]}: error:"), out.err
    for text in expected:
        assert text in out.err, out.err
    return out.err


def test_bad_cell_file_names_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nworkplane: {x_mm: [0, 100], y_mm: [0, 100]}\n"
                   "probe: {noise_std_mm: 0, colour: red}\n")
    _fails(["run", "--robot", str(bad), "--out", str(tmp_path / "o")], capsys,
           "probe.noise_std_mm", "greater than 0", "probe.colour", "unknown key")
    assert not (tmp_path / "o").exists()  # nothing written, nothing moved


def test_missing_and_unreadable_cell_files(tmp_path, capsys):
    _fails(["run", "--robot", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o")], capsys,
           "nope.yaml: no such file")
    broken = tmp_path / "broken.yaml"
    broken.write_text("workplane: [\n")
    _fails(["run", "--robot", str(broken), "--out", str(tmp_path / "o")], capsys, "not valid YAML")


def test_missing_recording(tmp_path, capsys):
    _fails(["flatness", str(tmp_path / "missing.csv")], capsys, "missing.csv: no such file")
    _fails(["explain", str(tmp_path / "missing.csv"), "--robot", str(ROOT / "configs" / "cheng2025-cell.yaml")],
           capsys, "missing.csv: no such file")


def test_malformed_recording_row_names_line_and_column(tmp_path, capsys):
    lines = CHENG0.read_text(encoding="utf-8").splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines[:8] + ["6,,abc,-165,0,1.2"]) + "\n", encoding="utf-8")
    _fails(["flatness", str(bad)], capsys, "bad.csv:9", "x_mm", "'abc' is not a number")


def test_report_on_a_folder_that_is_not_a_run(tmp_path, capsys):
    _fails(["report", str(tmp_path)], capsys, "result.json: missing")


def test_the_installed_command_keeps_stdout_clean_and_debug_shows_the_traceback(tmp_path):
    exe = [sys.executable, "-m", "adaptive_cal.cli"]
    missing = str(tmp_path / "missing.csv")
    p = subprocess.run(exe + ["flatness", missing], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.strip() == f"adaptive-cal flatness: error: {missing}: no such file"
    p = subprocess.run(exe + ["--debug", "flatness", missing], capture_output=True, text=True, timeout=120)
    assert p.returncode != 0 and "Traceback" in p.stderr
    # after the command too, as the error message's "run again with --debug" invites
    p = subprocess.run(exe + ["flatness", missing, "--debug"], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode != 0 and "Traceback" in p.stderr and "unrecognized" not in p.stderr
    p = subprocess.run(exe + ["bogus"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "invalid choice" in p.stderr and p.stdout == ""


# --help must not load the engine: each command module imports only the standard library at its
# top level and the dispatcher loads only the command named. Checked in a fresh interpreter, so
# what the test session already imported does not hide anything.
HEAVY = ("jax", "numpy", "scipy", "matplotlib", "pydantic", "filterpy")
_PROBE = """
import json, sys
from adaptive_cal.cli import main
try:
    main({argv!r})
except SystemExit:
    pass
print(json.dumps(sorted(m for m in {heavy!r} if m in sys.modules)), file=sys.stderr)
"""
# commands whose module still imports the engine at its top level on this branch
STILL_HEAVY: dict[str, str] = {}


def _heavy_after(argv: list[str]) -> list[str]:
    p = subprocess.run([sys.executable, "-c", _PROBE.format(argv=argv, heavy=HEAVY)],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stderr.strip().splitlines()[-1])


@pytest.mark.parametrize("name", [""] + [
    pytest.param(n, marks=pytest.mark.xfail(strict=False, reason=STILL_HEAVY[n]))
    if n in STILL_HEAVY else n for n in sorted(SUBCOMMANDS)])
def test_help_imports_no_heavy_module(name):
    argv = ([name] if name else []) + ["--help"]
    assert _heavy_after(argv) == [], f"adaptive-cal {' '.join(argv)} loads the engine"


def test_top_level_help_loads_no_command_module():
    probe = _PROBE.format(argv=["--help"], heavy=tuple(m for _, (m, _) in SUBCOMMANDS.items()))
    p = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert json.loads(p.stderr.strip().splitlines()[-1]) == []


def test_required_options_show_no_default(capsys):
    text = _help(["emulate"], capsys)
    assert "(default: None)" not in text
    assert "(default: 0.02)" in text  # a real default is still shown
    assert "--robot CELL.yaml cell file" in text


def test_defaults_formatter_shows_only_real_defaults():
    from adaptive_cal.cli.common import DefaultsShown

    p = argparse.ArgumentParser(formatter_class=DefaultsShown)
    p.add_argument("--need", required=True, help="needed")
    p.add_argument("--maybe", help="optional, no default")
    p.add_argument("--flag", action="store_true", help="a flag")
    p.add_argument("--n", type=int, default=3, help="count")
    p.add_argument("--zero", type=float, default=0.0, help="zero")
    text = " ".join(p.format_help().split())
    assert "needed (default" not in text and "no default (default" not in text
    assert "a flag (default" not in text
    assert "count (default: 3)" in text and "zero (default: 0.0)" in text


def test_the_dispatcher_finds_the_command_after_global_options():
    from adaptive_cal.cli import _chosen

    assert _chosen(["--debug", "flatness", "x.csv"]) == "flatness"
    assert _chosen(["--help"]) == ""
    assert _chosen([]) == ""


def test_an_option_given_twice_is_refused_not_the_last_taken(capsys):
    with pytest.raises(SystemExit) as e:
        main(["run", "--robot", "a.yaml", "--out", "x", "--robot", "b.yaml"])
    assert e.value.code == 2
    assert "--robot given twice (a.yaml, then b.yaml): give it once" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["flatness", "r.csv", "--samples", "10", "--samples=20"])
    assert "--samples given twice (10, then 20)" in capsys.readouterr().err


def test_an_os_error_is_an_error_with_the_systems_words_not_an_internal_error(monkeypatch,
                                                                              capsys):
    import errno

    import adaptive_cal.cli.flatness as flatness

    def full(args):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(flatness, "command", full)
    assert main(["flatness", "r.csv"]) == 2
    err = capsys.readouterr().err
    assert err == "adaptive-cal flatness: error: [Errno 28] No space left on device\n"
