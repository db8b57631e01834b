"""`study --json / --doc` never overwrite the study's inputs: the study file, its cell file, the
checkpoint (plates.jsonl), a file that is not an earlier --json. An outside audit (2026-11-24)
found `--doc out/plates.jsonl` replacing the per-plate records with the page, `--json
study.yaml` destroying the study file, each with exit 0. Refused now before any plate runs."""
import contextlib
import io
import shutil

import pytest

from adaptive_cal.cli import main
from conftest import ROOT


@pytest.fixture
def study(tmp_path):
    text = (ROOT / "configs" / "study-smoke.yaml").read_text()
    shutil.copy(ROOT / "configs" / "sim-cell.yaml", tmp_path / "sim-cell.yaml")
    path = tmp_path / "study.yaml"
    path.write_text(text)
    return path


def _run(*args):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["study", *map(str, args), "--quiet"])
    return code, err.getvalue()


@pytest.mark.parametrize("what", ["study", "cell", "checkpoint", "notes"])
def test_an_output_that_is_an_input_is_refused_before_any_plate(study, tmp_path, what):
    target = {"study": study, "cell": tmp_path / "sim-cell.yaml",
              "checkpoint": tmp_path / "out" / "plates.jsonl", "notes": tmp_path / "notes.txt"}[what]
    (tmp_path / "notes.txt").write_text("my notes\n")
    before = target.read_text() if target.exists() else None
    for option in ("--json", "--doc"):
        args = (["--json", tmp_path / "o.json", "--doc", target] if option == "--doc"
                else ["--json", target])
        if what == "notes" and option == "--doc":
            continue  # a page may replace a page; --json guards its own
        code, err = _run(study, *args, "--out", tmp_path / "out")
        assert code == 2, err
        assert option in err and ("itself" in err or "not an earlier study" in err)
        assert (target.read_text() if target.exists() else None) == before
        assert not (tmp_path / "out" / "plates.jsonl").exists() or what == "checkpoint"


def test_an_output_that_cannot_be_written_or_a_page_without_its_folder_is_refused_first(
        study, tmp_path):
    """--json and --doc are written after the whole study: a place that cannot take them, or a
    page whose links would point at nothing (--doc without --out), is refused before any plate
    runs (an outside audit: --json /proc/x.json failed after every run, naming a temp file)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        probe = ro / "probe"
        try:
            probe.write_text("")
            root = True  # root writes anyway: the read-only folder cannot be tested here
        except PermissionError:
            root = False
        cases = [(["--json", "/proc/x.json", "--out", tmp_path / "out"], "--json /proc/x.json"),
                 (["--json", tmp_path / "o.json", "--doc", tmp_path / "page.md"],
                  "needs --out DIR")]
        if not root:
            cases.append((["--json", tmp_path / "o.json", "--out", tmp_path / "out", "--doc",
                           ro / "page.md"], "cannot write in"))
        for args, words in cases:
            code, err = _run(study, *args)
            assert code == 2 and words in err, err
            assert not (tmp_path / "out" / "plates.jsonl").exists()
    finally:
        ro.chmod(0o700)


def test_a_second_study_on_the_same_checkpoint_is_refused_while_the_first_holds_it(
        study, tmp_path):
    """Two studies on one --out: the second used to replace plates.jsonl under the first, whose
    later records then went to the replaced file (an outside audit: 8 of 12 lost)."""
    from adaptive_cal.study.checkpoint import Checkpoint

    held = Checkpoint(tmp_path / "out" / "plates.jsonl", "k")
    try:
        code, err = _run(study, "--json", tmp_path / "o.json", "--out", tmp_path / "out")
        assert code == 2 and "another study is writing to it now" in err, err
    finally:
        held.close()
    again = Checkpoint(tmp_path / "out" / "plates.jsonl", "k")  # free once the first is done
    again.close()
