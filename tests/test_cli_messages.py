"""Messages for common mistakes, through the installed command line (a subprocess: what a user
sees, exit codes included), and flatness --compare as a readable table."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHENG = ROOT / "adaptive_cal" / "data" / "cheng2025"
CELL = ROOT / "configs" / "sim-cell.yaml"


def _cli(*args, cwd=None):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-m", "adaptive_cal.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, env=env, timeout=300)


def _fails(p, *words):
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr and "internal error" not in p.stderr, p.stderr
    for w in words:
        assert w in p.stderr, p.stderr


def test_report_on_a_recording_asks_for_its_run_folder(tmp_path):
    run = tmp_path / "runs" / "first"
    run.mkdir(parents=True)
    (run / "recording.csv").write_text((CHENG / "round0_initial.csv").read_text())
    # a folder with only a recording in it is no run folder: replay it with its cell file
    _fails(_cli("report", run / "recording.csv"), "a bare recording", "--robot CELL.yaml")
    (run / "cell.yaml").write_text((ROOT / "configs" / "cheng2025-cell.yaml").read_text())
    _fails(_cli("report", run / "recording.csv"), "is a file; report wants the run folder",
           f"adaptive-cal report {run}")


def test_a_recording_given_as_the_cell_file(tmp_path):
    rec = CHENG / "round0_initial.csv"
    _fails(_cli("run", "--robot", rec, "--out", tmp_path / "o"),
           "this is a recording, not a cell file", "--robot takes the cell's YAML file")
    assert not (tmp_path / "o").exists()
    _fails(_cli("run", "--robot", rec, "--dry-run"), "this is a recording, not a cell file")
    _fails(_cli("explain", rec, "--robot", rec), "this is a recording, not a cell file")


def test_flatness_on_another_csv_says_what_a_recording_is(tmp_path):
    mine = tmp_path / "mine.csv"
    mine.write_text("pos_a,pos_b,value\n0,0,0.01\n10,0,0.02\n")
    p = _cli("flatness", mine)
    _fails(p, "mine.csv is not an adaptive-cal recording (its first line is 'pos_a,pos_b,value')",
           "'# adaptive-cal recording v1'", "seq, t_s, x_mm, y_mm, z_mm, reading_mm",
           "a plain table whose first line names x_mm, y_mm and reading_mm or height_mm",
           "docs/recording.md")
    # a table that names x, y and a height is read as one (formats/table.py)
    mine.write_text("x,y,z\n0,0,0.01\n10,0,0.02\n")
    _fails(_cli("flatness", mine), "2 usable touches; flatness needs at least 4")
    assert (ROOT / "docs" / "recording.md").exists()
    _fails(_cli("flatness", tmp_path), "is a folder; give the recording file inside it")


@pytest.mark.slow
def test_compare_prints_a_table_with_units_and_p_worse():
    p = _cli("flatness", CHENG / "round0_initial.csv", "--compare",
             CHENG / "round1_first_correction.csv")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    head = lines.index("change from round0_initial.csv to round1_first_correction.csv "
                       "(later minus earlier; um):")
    assert "P(worse)" in lines[head + 1] and "95 % interval of change" in lines[head + 1]
    ls = lines[head + 2].split()
    assert ls[:2] == ["least", "squares"]
    assert ls[2:5] == ["541.7", "596.0", "+54.3"]  # um, as printed; the change of those
    assert ls[-4:] == ["0.90", "within", "the", "noise"]
    assert lines[head + 4].startswith("  range (tilt incl.)") and lines[head + 4].endswith("smaller")
    assert "{" not in p.stdout  # no raw dicts


def test_dry_run_prints_approach_heights_expected_touches_and_robot_time():
    p = _cli("run", "--robot", CELL, "--dry-run")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[2].split() == ["#", "x_mm", "y_mm", "approach", "z_mm"]
    assert len(lines[3].split()) == 4
    last = next(line for line in lines if line.startswith("expected: about "))
    assert "robot time about " in last and " min (" in last
    assert lines[-1].startswith("then one closure touch at the first place")
    touches = int(last.split()[2])
    assert 16 <= touches <= 120  # at least the spline's coefficients, at most the budget


@pytest.mark.parametrize("argv, words", [
    (["flatness", CHENG / "round0_initial.csv", "--samples", "-5"], "--samples: -5 is below 2"),
    (["flatness", CHENG / "round0_initial.csv", "--samples", "1"], "--samples: 1 is below 2"),
    (["flatness", CHENG / "round0_initial.csv", "--samples", "100000000"],
     "--samples: 100000000 is above 100000"),
    (["study", ROOT / "configs" / "study-smoke.yaml", "--json", "x.json", "--workers", "-2"],
     "--workers: -2 is below 0"),
    (["study", ROOT / "configs" / "study-smoke.yaml", "--json", "x.json", "--plates", "-3"],
     "--plates: -3 is below 1"),
    (["emulate", "--robot", ROOT / "configs" / "cell-modbus-emulated.yaml", "--move-s", "-1"],
     "--move-s: -1 s: must be a finite time of at least 0 s"),
    (["emulate", "--robot", ROOT / "configs" / "cell-modbus-emulated.yaml", "--seconds", "nan"],
     "--seconds: nan s: must be a finite time above 0 s"),
    (["flatness", CHENG / "round0_initial.csv", "--seed", "-1"], "--seed: -1 is below 0"),
    (["explain", CHENG / "round0_initial.csv", "--robot", ROOT / "configs" / "cheng2025-cell.yaml",
      "--seed", "-1"], "--seed: -1 is below 0"),
])
def test_numeric_options_out_of_range_are_refused_naming_the_option(argv, words, capsys,
                                                                     tmp_path, monkeypatch):
    """Before: --samples -5 failed inside numpy ("negative dimensions are not allowed"),
    --plates -3 ran a study of no plates (exit 0), --workers -2 and a negative --move-s or
    --seconds were taken as given. Refused by argparse, before anything is read or started."""
    from adaptive_cal.cli import main

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == 2 and words in err and "Traceback" not in err, err
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize("given, words", [("nope", "--resume nope: no such folder"),
                                          ("file.csv", "file.csv: a file, not a folder")])
def test_resume_of_something_that_is_not_a_run_folder(given, words, tmp_path, monkeypatch, capsys):
    """Before: "nope/cell.yaml: no such file" -- a file the user never named."""
    from adaptive_cal.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "file.csv").write_text("x")
    assert main(["run", "--resume", given]) == 2
    err = capsys.readouterr().err
    assert words in err and "adaptive-cal run --out DIR" in err and "Traceback" not in err, err


@pytest.mark.parametrize("sep, name", [(";", "semicolons"), ("\t", "tabs")])
def test_a_table_with_another_separator_is_told_to_use_commas(sep, name, tmp_path, capsys):
    """A spreadsheet's export (';' where the decimal mark is a comma, or tabs): said so, not
    "is not an adaptive-cal recording" about a first line that does name x_mm, y_mm and
    height_mm."""
    from adaptive_cal.cli import main

    f = tmp_path / "export.csv"
    f.write_text(sep.join(["y_mm", "x_mm", "height_mm"]) + "\n"
                 + sep.join(["1", "2", "0.1"]) + "\n")
    assert main(["flatness", str(f)]) == 2
    err = capsys.readouterr().err
    assert f"its columns are separated by {name}" in err and "commas" in err, err


def test_a_broken_result_json_is_named_with_its_line(tmp_path, capsys):
    """A result.json cut short or edited by hand: report and compensate said only "Expecting
    value: line 2 column 1 (char 12)", naming no file."""
    from adaptive_cal.cli import main
    from adaptive_cal.formats.jsonfile import read_json

    run = tmp_path / "run"
    assert main(["run", "--robot", str(CELL), "--out", str(run), "--no-progress"]) == 0
    capsys.readouterr()
    (run / "result.json").write_text('{"broken": \n')
    for argv in (["report", str(run)], ["compensate", "--map", str(run), "--grid",
                                         str(tmp_path / "g.csv")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{run / 'result.json'}: not valid JSON (Expecting value at line 2, column 1)" \
            in err and "Traceback" not in err, err
    (run / "result.json").write_bytes(b'{"a": "\xff"}')
    with pytest.raises(ValueError, match="result.json: not UTF-8 text"):
        read_json(run / "result.json")


def test_a_broken_belief_npz_is_named(tmp_path, capsys):
    """A belief.npz cut short or overwritten: report, compensate and flatness gave numpy's "This
    file contains pickled (object) data. If you trust the file ..." and named no file."""
    import numpy as np

    from adaptive_cal.cli import main

    run = tmp_path / "run"
    assert main(["run", "--robot", str(CELL), "--out", str(run), "--no-progress"]) == 0
    whole = (run / "belief.npz").read_bytes()
    for data, words in ((b"junk\n", "not an .npz file adaptive-cal wrote"),
                        (whole[:400], "not an .npz file adaptive-cal wrote"),
                        (None, "no array 'cov'")):
        if data is None:
            np.savez(run / "belief.npz", mean=np.zeros(3))
        else:
            (run / "belief.npz").write_bytes(data)
        capsys.readouterr()
        for argv in (["report", str(run)], ["flatness", str(run / "recording.csv")],
                     ["compensate", "--map", str(run), "--grid", str(tmp_path / "g.csv")]):
            assert main(argv) == 2, argv
            err = capsys.readouterr().err
            assert f"{run / 'belief.npz'}: {words}" in err and "Traceback" not in err, err


def test_a_file_where_a_folder_is_needed_is_said_so(tmp_path, capsys, monkeypatch):
    """--out naming a file: "[Errno 17] File exists: 'afile'"; --grid under a file: an
    'internal error: NotADirectoryError'. Now the path first, then what is wrong with it."""
    from adaptive_cal.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    run = tmp_path / "run"
    assert main(["run", "--robot", str(CELL), "--out", str(run), "--no-progress"]) == 0
    capsys.readouterr()
    for argv, words in (
            (["run", "--robot", str(CELL), "--out", "afile"],
             "afile: a file is in the way where a folder is needed"),
            (["report", str(run), "--out", "afile/x.html"],
             "afile: a file is in the way where a folder is needed"),
            (["compensate", "--map", str(run), "--grid", "afile/g.csv"],
             "afile/g.csv: part of this path is a file, not a folder"),
            (["compensate", "--map", str(run), "--grid", str(tmp_path)],
             f"{tmp_path}: Is a directory")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and "internal error" not in err and "Errno" not in err, err


def test_a_folder_or_binary_file_given_as_yaml(tmp_path, capsys):
    """Was "not a UTF-8 text file (IsADirectoryError)" for a folder."""
    from adaptive_cal.cli import main

    (tmp_path / "bad.yaml").write_bytes(b"\xff\xfe")
    (tmp_path / "latin.yaml").write_bytes(b"a: 1\nb: 2\nname: caf\xe9\n")  # its line named
    for argv, words in ((["study", str(tmp_path), "--json", str(tmp_path / "x.json")],
                         f"{tmp_path}: a folder, not a YAML file"),
                        (["emulate", "--robot", str(tmp_path)], "a folder, not a YAML file"),
                        (["run", "--robot", str(tmp_path / "bad.yaml"), "--out",
                          str(tmp_path / "o")], "bad.yaml:1: not a UTF-8 text file (invalid start"),
                        (["run", "--robot", str(tmp_path / "latin.yaml"), "--out",
                          str(tmp_path / "o")], "latin.yaml:3: not a UTF-8 text file")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, err


def test_a_check_across_a_block_is_not_echoed_whole(tmp_path, capsys):
    """Was "probe: noise_range_mm must be [low, high] with low < high, got [0.004, 0.001] (got
    {'adapter': 'sim', 'noise_range_mm': [0.004, 0.001], 'noise_std_mm': 0.005, '...)"."""
    from adaptive_cal.cli import main

    text = CELL.read_text(encoding="utf-8").replace(
        "  # noise_range_mm: [0.001, 0.004]", "  noise_range_mm: [0.004, 0.001]")
    assert "noise_range_mm: [0.004, 0.001]" in text
    (tmp_path / "cell.yaml").write_text(text, encoding="utf-8")
    assert main(["run", "--robot", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert ("  probe.noise_range_mm: must be [low, high] with low < high, got [0.004, 0.001] mm\n"
            in err), err
    assert "(got {" not in err and "'adapter'" not in err


def test_run_refuses_out_with_resume_prior_from_on_a_fresh_runs_resume_and_anothers_results(
        tmp_path, capsys):
    """Outside CLI audit: --out with --resume was silently ignored (the other folder changed);
    --resume of a run mapped from scratch took --prior-from of another run (its map then
    another plate's, exit 0); run --out into a folder holding another run's result.json and
    belief.npz (its recording moved away) overwrote them. Each refused now, exit 2, nothing
    changed."""
    import shutil

    from adaptive_cal.cli import main

    run = tmp_path / "run"
    run.mkdir()
    (run / "recording.csv").write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,"
                                       "reading_mm\n")
    shutil.copyfile(CELL, run / "cell.yaml")
    before = sorted(p.name for p in run.iterdir())
    assert main(["run", "--resume", str(run), "--out", str(tmp_path / "elsewhere")]) == 2
    assert "leave --out out" in capsys.readouterr().err
    assert not (tmp_path / "elsewhere").exists()
    assert main(["run", "--resume", str(run), "--prior-from", str(tmp_path)]) == 2
    assert "mapped from scratch (it has no prior_from.json)" in capsys.readouterr().err
    assert sorted(p.name for p in run.iterdir()) == before
    other = tmp_path / "other"
    other.mkdir()
    for name in ("result.json", "belief.npz"):
        (other / name).write_text("another run's")
    assert main(["run", "--robot", str(CELL), "--out", str(other), "--no-progress"]) == 2
    assert "holds result.json and belief.npz of another run" in capsys.readouterr().err
    assert all((other / n).read_text() == "another run's" for n in ("result.json", "belief.npz"))


def test_flatness_marks_an_unfinished_runs_figures_and_refuses_comparing_a_round_with_itself(
        tmp_path, capsys):
    """Outside CLI audit: flatness of a run folder that stopped on its budget with the bound
    unmet (run said INCOMPLETE, exit 1) printed its figures as a result; --compare of a
    recording with itself printed 'change +0.0, within the noise'. Now INCOMPLETE and
    provisional as run and report say it, and the comparison is refused."""
    import yaml

    from adaptive_cal.cli import main

    data = yaml.safe_load(CELL.read_text())
    data["plan"]["stop"]["max_touches"] = 8
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    assert main(["run", "--robot", str(tmp_path / "cell.yaml"), "--out", str(run),
                 "--no-progress"]) == 1
    capsys.readouterr()
    assert main(["flatness", str(run / "recording.csv")]) == 0
    out = capsys.readouterr().out
    assert "INCOMPLETE: touch budget spent after 8 touches" in out
    assert "flatness of the whole plate (from the map), provisional" in out
    assert main(["flatness", str(run / "recording.csv"), "--json"]) == 0
    import json
    assert json.loads(capsys.readouterr().out)["incomplete"].startswith("touch budget spent")
    copy = tmp_path / "copy.csv"
    copy.write_bytes((run / "recording.csv").read_bytes())
    for other in (run / "recording.csv", copy):
        assert main(["flatness", str(run / "recording.csv"), "--compare", str(other)]) == 2
        assert "the same recording as" in capsys.readouterr().err


def test_emulate_a_busy_port_or_a_simulated_cell_and_an_unreadable_recording_are_named(
        tmp_path, capsys, monkeypatch):
    """Outside CLI audit: a second emulator on a port in use was an 'internal error: OSError'
    (exit 1, 'please report it'); emulate of a simulated cell printed 'nothing to serve' and
    exited 2 without an error line; an unreadable recording was 'not an adaptive-cal recording
    (its first line is '')'. Each named now, exit 2."""
    import socket
    from pathlib import Path

    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.cli import main

    hses = ROOT / "configs" / "cell-hses-emulated.yaml"
    port = load_cell(hses).robot.hses.port
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("127.0.0.1", port))
    try:
        assert main(["emulate", "--robot", str(hses), "--seconds", "0.1"]) == 2
    finally:
        held.close()
    err = capsys.readouterr().err
    assert "cannot serve its devices on 127.0.0.1" in err and "internal error" not in err
    assert main(["emulate", "--robot", str(CELL), "--seconds", "0.1"]) == 2
    assert "nothing to serve -- its robot and probe are simulated" in capsys.readouterr().err
    rec = tmp_path / "r.csv"
    rec.write_text("# adaptive-cal recording v1\n")
    real = Path.open

    def refuse(self, *a, **k):
        if self == rec:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self, *a, **k)

    monkeypatch.setattr(Path, "open", refuse)
    assert main(["flatness", str(rec)]) == 2
    assert f"{rec}: cannot be read (Permission denied)" in capsys.readouterr().err


def test_a_studys_ctrl_c_says_the_finished_plates_are_kept(tmp_path, capsys, monkeypatch):
    """It said only 'interrupted' (outside CLI audit)."""
    from adaptive_cal.cli import main
    from adaptive_cal.study import runner

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_study", interrupted)
    code = main(["study", str(ROOT / "configs" / "study-smoke.yaml"), "--plates", "1",
                 "--json", str(tmp_path / "s.json")])
    assert code == 130
    err = capsys.readouterr().err
    # none had finished: it says so (it said "kept" with nothing kept, an outside audit)
    assert "no run had finished: nothing kept, the same command again starts over" in err
    # two runs in the checkpoint: it names them and where they are
    from adaptive_cal.study.checkpoint import study_key
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.overrides import apply_overrides

    study, base = load_study(ROOT / "configs" / "study-smoke.yaml")
    study = apply_overrides(study, base, plates=1, strategies=None, settings=[],
                            study_path=str(ROOT / "configs" / "study-smoke.yaml"))
    checkpoint = tmp_path / "s.json.plates.jsonl"
    checkpoint.write_text(f'{{"study_key": "{study_key(study, base)}"}}\n'
                          '{"plate": 0, "strategy": "a"}\n{"plate": 0, "strategy": "b"}\n')
    main(["study", str(ROOT / "configs" / "study-smoke.yaml"), "--plates", "1",
          "--json", str(tmp_path / "s.json")])
    assert f"2 runs finished, kept in {checkpoint}" in capsys.readouterr().err


def test_files_and_folders_given_for_each_other_are_named_as_such(tmp_path, capsys):
    """Outside CLI audit: compensate --map FILE said 'no such folder', PROGRAM FOLDER 'no such
    file', report RUN_DIR/result.json 'a bare recording'."""
    from adaptive_cal.cli import main

    run = tmp_path / "run"
    run.mkdir()
    for name in ("cell.yaml", "recording.csv", "result.json", "belief.npz"):
        (run / name).write_text("x")
    assert main(["compensate", "--map", str(run / "belief.npz"), "--grid",
                 str(tmp_path / "g.csv")]) == 2
    assert "a file, not a run folder" in capsys.readouterr().err
    assert main(["compensate", str(run), "--map", str(run), "--out", str(tmp_path / "o")]) == 2
    assert "a folder, not a toolpath file" in capsys.readouterr().err
    assert main(["report", str(run / "result.json")]) == 2
    assert f"a file of the run folder {run}: adaptive-cal report {run}" in capsys.readouterr().err


def test_a_folder_without_its_results_points_to_resume(tmp_path, capsys):
    """A run stopped before writing its results (a double Ctrl-C then): report and compensate
    said only 'result.json: missing' (outside CLI audit); they point to --resume now."""
    import shutil

    from adaptive_cal.cli import main

    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(CELL, run / "cell.yaml")
    (run / "recording.csv").write_text("# adaptive-cal recording v1\n")
    assert main(["report", str(run)]) == 2
    assert f"adaptive-cal run --resume {run} writes them" in capsys.readouterr().err
    assert main(["compensate", "--map", str(run), "--grid", str(tmp_path / "g.csv")]) == 2
    assert f"adaptive-cal run --resume {run} writes them" in capsys.readouterr().err


def test_a_probe_noise_given_in_um_is_refused_at_load_naming_the_key(tmp_path, capsys):
    """noise_std_mm: 5 (um typed as mm) was accepted and the run stopped on 'no allowed point
    ... narrow model.offset_std_mm / tilt_std_deg' (outside CLI audit): refused at load."""
    import yaml

    from adaptive_cal.cli import main

    for key, value in (("noise_std_mm", 5.0), ("noise_range_mm", [0.002, 2.0])):
        data = yaml.safe_load(CELL.read_text())
        data["probe"][key] = value
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(data))
        assert main(["run", "--robot", str(tmp_path / "c.yaml"), "--out",
                     str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert key in err and "of the usable stroke" in err and "um given as mm?" in err
        hint = {"noise_std_mm": "(5 um is 0.005)", "noise_range_mm": "(2 um is 0.002)"}[key]
        assert hint in err  # the value's own (it said 5 um for every value)
        assert not (tmp_path / "o").exists()


def test_a_study_set_of_its_base_cell_is_refused_not_ignored(tmp_path, capsys):
    """--set cell=nope.yaml ran to exit 0 with the file's cell (outside CLI audit)."""
    from adaptive_cal.cli import main

    assert main(["study", str(ROOT / "configs" / "study-smoke.yaml"), "--plates", "1",
                 "--set", "cell=nope.yaml", "--json", str(tmp_path / "s.json")]) == 2
    assert "--set cell=nope.yaml: the base cell is the study file's" in capsys.readouterr().err


def test_compensate_step_without_grid_is_refused(tmp_path, capsys):
    """--step-mm without --grid was ignored without a word (outside CLI audit)."""
    from adaptive_cal.cli import main

    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90\nG1 X0 Y0 Z0\n")
    assert main(["compensate", str(prog), "--map", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--step-mm", "7"]) == 2
    assert "--step-mm sets the --grid file's spacing" in capsys.readouterr().err


def test_a_ctrl_c_python_wrapped_in_another_error_is_an_interruption(tmp_path, capsys,
                                                                    monkeypatch):
    """A Ctrl-C while matplotlib was imported (0.5 s into `report`) came out as "internal error:
    RuntimeError: Error calling __set_name__ ... please report it": Python wraps a
    KeyboardInterrupt raised in a class body's __set_name__. It is an interruption (exit 130);
    a bug with no Ctrl-C behind it is still an internal error."""
    from adaptive_cal.cli import main
    from adaptive_cal.cli import report

    def wrapped(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError("Error calling __set_name__ on '_axis_method_wrapper'") from e

    monkeypatch.setattr(report, "command", wrapped)
    assert main(["report", str(tmp_path)]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "adaptive-cal report: interrupted" and "internal error" not in err

    def bug(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(report, "command", bug)
    assert main(["report", str(tmp_path)]) == 1
    assert "internal error: RuntimeError: a bug" in capsys.readouterr().err


def test_a_ctrl_c_lost_in_a_gc_callback_still_stops_the_command(tmp_path, capsys, monkeypatch):
    """A Ctrl-C that landed in XLA's garbage-collector callback was printed as "Exception
    ignored ... KeyboardInterrupt" and lost: `report` went on and wrote its page, exit 0. It is
    delivered again to the main thread and stops the command (exit 130)."""
    import gc
    import signal
    import time

    from adaptive_cal.cli import main
    from adaptive_cal.cli import report

    def swallowed(args):
        def callback(phase, info):
            raise KeyboardInterrupt  # as a Ctrl-C landing here is: Python cannot raise it
        gc.callbacks.append(callback)
        try:
            gc.collect()
        finally:
            gc.callbacks.remove(callback)
        for _ in range(200):  # the rest of the command
            time.sleep(0.005)
        return 0

    monkeypatch.setattr(report, "command", swallowed)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # xdist's workers ignore it
    try:
        assert main(["report", str(tmp_path)]) == 130
    finally:
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err
    # stopped while it ran (or, were the delivery lost too, at its end): exit 130 either way
    assert "adaptive-cal report: interrupted" in err and "Exception ignored" not in err


def test_a_ctrl_c_before_the_command_starts_is_an_interruption_not_a_traceback(monkeypatch,
                                                                               capsys):
    """A Ctrl-C in the first quarter second (the parser, the imports before the command) ended
    in a traceback of the import it interrupted."""
    import adaptive_cal.cli as cli

    def slow_imports(only=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", slow_imports)
    assert cli.main(["flatness", "x.csv"]) == 130
    assert capsys.readouterr().err.strip() == "adaptive-cal: interrupted"


def test_a_ctrl_c_during_the_jax_import_arrives_after_it(tmp_path, monkeypatch):
    """A Ctrl-C inside jaxlib's native import aborted the process (status -6, a C++ terminate):
    the commands that load JAX import it with SIGINT held back, so it arrives once the import is
    done, as a KeyboardInterrupt the command line turns into 'interrupted'."""
    import signal
    import sys
    import threading

    from adaptive_cal.cli import _import_ctrl_c_held

    (tmp_path / "slow_native.py").write_text(
        "import signal, threading\n"
        "signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)  # a Ctrl-C, mid-import\n"
        "done = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # xdist's workers ignore it
    try:
        assert threading.current_thread() is threading.main_thread()
        with pytest.raises(KeyboardInterrupt):
            _import_ctrl_c_held("slow_native")
    finally:
        signal.signal(signal.SIGINT, previous)
        module = sys.modules.pop("slow_native", None)
    assert module is not None and module.done  # the import ran to its end first


def test_an_interrupted_command_line_ends_without_the_teardown(monkeypatch, capsys):
    """XLA's threads, stopped mid-work by a Ctrl-C, crashed the interpreter's teardown after a
    run said 'interrupted' (status -11, 2 of 40 Ctrl-Cs on a loaded machine): the process's own
    command line leaves at once with 130, its output flushed; a caller's main([...]) returns."""
    import sys

    import adaptive_cal.cli as cli
    from adaptive_cal.cli import report

    def interrupted(args):
        raise KeyboardInterrupt

    left = []
    monkeypatch.setattr(report, "command", interrupted)
    monkeypatch.setattr(cli.os, "_exit", lambda code: left.append(code))
    assert cli.main(["report", "x"]) == 130 and left == []  # called with a list: returns
    monkeypatch.setattr(sys, "argv", ["adaptive-cal", "report", "x"])
    cli.main()
    assert left == [130]
    assert capsys.readouterr().err.count("adaptive-cal report: interrupted") == 2
