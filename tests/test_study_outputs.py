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
