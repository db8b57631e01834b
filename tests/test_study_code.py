"""A study's records name the code that made them, and records of other code are refused unless
kept on purpose (an outside audit, 2026-12-02: docs/study.md's own command reused records made
by the code of nine days before, and the page presented them as today's measurement)."""
import json
import shutil

import pytest

from adaptive_cal.study.checkpoint import (MEASURING, PRESENTING, code_fingerprint, fingerprint,
                                           study_key)
from adaptive_cal.study.config import load_study, parse_study
from adaptive_cal.study.runner import run_study

from conftest import ROOT

SMOKE = ROOT / "configs" / "study-smoke.yaml"
PACKAGE = ROOT / "adaptive_cal"


def _grid_study():
    study, base = load_study(SMOKE)
    data = study.model_dump(mode="json")
    data.update(plates=2, strategies=["grid"], estimator="fixed", lower_bound={"plates": 0})
    data["bound"].update(mean_std_mm=0.015, max_touches=30)
    return parse_study(data), base


def test_fingerprint_follows_the_measuring_code_only(tmp_path):
    for pattern in MEASURING:  # a renamed package would silently drop out of the fingerprint
        assert list(PACKAGE.glob(pattern)), pattern
    for rel in PRESENTING:
        assert (PACKAGE / rel).is_file(), rel
    copy = tmp_path / "adaptive_cal"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "data"))
    assert fingerprint(copy) == code_fingerprint()
    page = copy / "study" / "doc.py"
    page.write_text(page.read_text() + "\n# another wording\n")
    assert fingerprint(copy) == code_fingerprint()  # a page's wording measures nothing
    # what an editor or a checkout leaves beside the modules is not another code (an outside
    # review: a Jupyter checkpoint copy, CRLF line ends each made another fingerprint)
    (copy / "planning" / ".ipynb_checkpoints").mkdir()
    (copy / "planning" / ".ipynb_checkpoints" / "plan-checkpoint.py").write_text("x = 1\n")
    (copy / "planning" / "plan-old.py").write_text("x = 2\n")
    plan = copy / "planning" / "plan.py"
    plan.write_bytes(plan.read_bytes().replace(b"\n", b"\r\n"))
    assert fingerprint(copy) == code_fingerprint()
    # what makes records is another code: the planner, the probe cycle the run loop drives
    # (hardware/cycle.py), the study's true-error target (study/config.py), a numerics library
    for rel in ("planning/plan.py", "hardware/cycle.py", "study/config.py"):
        other = tmp_path / rel.replace("/", "_") / "adaptive_cal"
        shutil.copytree(copy, other)
        (other / rel).write_text((other / rel).read_text() + "\n# other code\n")
        assert fingerprint(other) != code_fingerprint(), rel
    assert fingerprint(copy, libraries=("numpy", "scipy", "jax", "jaxlib", "filterpy")) != \
        code_fingerprint()


def test_records_of_other_code_are_refused_unless_kept(tmp_path):
    study, base = _grid_study()
    path = tmp_path / "plates.jsonl"
    first = run_study(study, base, path)  # one fixed-design task: both plates
    assert len(first) == 2 and all(r["code"] == code_fingerprint() for r in first)
    # the same code: the finished runs are kept, nothing runs again
    calls = []
    again = run_study(study, base, path, progress=lambda d, t: calls.append((d, t)))
    assert again == first and calls == [(0, 0)]

    # a record made by other code, and one made before records carried their code
    lines = path.read_text().splitlines()
    old = [json.loads(line) for line in lines[1:]]
    old[0]["code"] = "0123456789ab"
    del old[1]["code"]
    path.write_text("\n".join([lines[0]] + [json.dumps(r) for r in old]) + "\n")
    before = path.read_text()
    with pytest.raises(ValueError) as e:
        run_study(study, base, path)
    said = str(e.value)
    assert str(path) in said and "2 of 2 finished runs made by other code" in said
    assert "0123456789ab" in said and code_fingerprint() in said
    assert "--reuse-records" in said and "Delete it" in said
    assert path.read_text() == before  # nothing lost, nothing run
    kept = run_study(study, base, path, reuse=True)
    assert [r.get("code") for r in kept] == ["0123456789ab", None]


def test_a_checkpoint_keyed_before_the_plate_count_left_the_key_is_this_studys(tmp_path):
    """An outside review: a checkpoint written before 2026-12-02 (its key with the plate count)
    was refused as "another study", and --reuse-records could not keep it."""
    from adaptive_cal.study.checkpoint import legacy_key

    study, base = _grid_study()
    path = tmp_path / "plates.jsonl"
    run_study(study, base, path)
    lines = path.read_text().splitlines()
    old = [{k: v for k, v in json.loads(line).items() if k != "code"} for line in lines[1:]]
    path.write_text("\n".join([json.dumps({"study_key": legacy_key(study, base)})]
                              + [json.dumps(r) for r in old]) + "\n")
    with pytest.raises(ValueError, match="2 of 2 finished runs made by other code") as e:
        run_study(study, base, path)
    assert "another study" not in str(e.value)
    assert run_study(study, base, path, reuse=True) == sorted(old, key=lambda r: r["plate"])
    assert json.loads(path.read_text().splitlines()[0])["study_key"] == study_key(study, base)


def test_cli_says_how_many_runs_another_code_made(tmp_path, capsys):
    from adaptive_cal.cli import main

    out, folder, page = tmp_path / "s.json", tmp_path / "dir", tmp_path / "study.md"
    argv = ["study", str(SMOKE), "--plates", "1", "--strategies", "grid", "--json", str(out),
            "--out", str(folder), "--doc", str(page), "--quiet"]
    assert main(argv) == 0
    summary = json.loads(out.read_text())
    assert summary["code"] == {"fingerprint": code_fingerprint(), "runs": 1,
                               "runs_by_other_code": 0}
    assert (f"Every run on this page (1 run) was made by the same code, {code_fingerprint()}."
            in page.read_text())
    checkpoint = folder / "plates.jsonl"
    head, rec = checkpoint.read_text().splitlines()
    checkpoint.write_text(head + "\n" + json.dumps({**json.loads(rec), "code": "feedfeedfeed"})
                          + "\n")
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "1 of 1 finished runs made by other code" in err and "--reuse-records" in err
    assert main(argv + ["--reuse-records"]) == 0
    err = capsys.readouterr().err
    assert "warning: 1 of 1 run kept from other code (--reuse-records)" in err
    assert json.loads(out.read_text())["code"]["runs_by_other_code"] == 1
    text = page.read_text()
    assert f"**Runs made by other code than {code_fingerprint()}: 1 of 1 run**" in text
    assert "--reuse-records" in next(line for line in text.splitlines()
                                     if line.startswith("OPENBLAS"))
    assert study_key  # the key itself still covers settings and maps only (test_maps_audit)


def test_records_made_by_workers_of_other_code_are_named_as_such(tmp_path, capsys,
                                                                  monkeypatch):
    """An outside review: records a remote Dask worker of other code made in this very run were
    reported as "kept from other code (--reuse-records)"."""
    import adaptive_cal.study.runner as runner
    from adaptive_cal.cli import main

    real = runner.run_study

    def remote(*args, **kw):  # as if a worker with other sources made the records
        return [{**r, "code": "0ther0code00"} for r in real(*args, **kw)]

    monkeypatch.setattr(runner, "run_study", remote)
    assert main(["study", str(SMOKE), "--plates", "1", "--strategies", "grid", "--quiet",
                 "--json", str(tmp_path / "s.json")]) == 0
    err = capsys.readouterr().err
    assert "1 of 1 run made by Dask workers running other code than this" in err
    assert "--reuse-records" not in err
