"""The recording fuzzer (issue 16, deliver 6): seeded mutants of a real recording (one the
simulated cell made) through ``flatness``, ``explain``, ``report`` (a run folder holding the
mutant) and ``run --resume`` (a run folder with the mutant recording), in-process through
``adaptive_cal.cli.main``. Each must end in a clean refusal (exit 2, a message naming the line,
the column or what is missing) or a valid result: no traceback or internal error, no hang, no
NaN in JSON, no row of the recording lost by a resume, no target outside the workplane, its
keep-outs and the workspace. ``pytest -s`` prints the audit table."""
import contextlib
import io
import json
import random
import re
import shutil
import signal
import time
from collections import Counter
from functools import partial

import numpy as np
import pytest
import yaml

from adaptive_cal.cli import main
from adaptive_cal.formats.recording import RecordingError, read_recording
from adaptive_cal.formats.writing import repair_cut_row
from adaptive_cal.run import session

from helpers import SIM_CELL
from recording_mutants import FAMILIES, mutant

SEED, MUTANTS, SECONDS_EACH = 16, 200, 60
# a refusal names where: path:line, a column, the header, the first line, or what is missing
NAMES_WHERE = re.compile(r"\.csv:\d+|column|header|first line|not an adaptive-cal recording|"
                         r"touch(es)?\b|rows?\b|not UTF-8|no such file|recording version", re.I)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def _strict_json(text):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def _cli(argv):
    out, err = io.StringIO(), io.StringIO()
    signal.alarm(SECONDS_EACH)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
    except _Timeout:
        rc = "hang"
    except SystemExit as e:  # argparse
        rc = e.code
    finally:
        signal.alarm(0)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A finished 16-touch run of the simulated cell (candidates kept few for speed), and a cell
    with a larger budget for the resumes."""
    root = tmp_path_factory.mktemp("fuzz")
    cell = yaml.safe_load(SIM_CELL.read_text())
    cell["plan"] = {"stop": {"mean_std_mm": 0.004, "max_touches": 16}, "candidates": 400,
                    "refine": 0}
    (root / "cell16.yaml").write_text(yaml.safe_dump(cell))
    cell["plan"]["stop"]["max_touches"] = 40
    (root / "cell40.yaml").write_text(yaml.safe_dump(cell))
    assert _cli(["run", "--robot", str(root / "cell16.yaml"), "--out", str(root / "run"),
                 "--no-progress"])[0] == 1  # 16 touches, the bound unmet: not a result
    return root, cell


def _classify(what, rc, err, tally):
    assert "Traceback" not in err and "internal error" not in err, f"{what}: {err[-600:]}"
    if rc == "hang":
        tally["hangs"] += 1
        pytest.fail(f"{what}: no answer within {SECONDS_EACH} s")
    if rc == 2:
        message = err.strip()
        assert message.count("\n") < 6 and len(message) < 1500, f"{what}: {message[:300]}"
        assert NAMES_WHERE.search(message), f"{what}: {message!r}"
        tally["refused"] += 1
        return False
    assert rc in (0, 130), f"{what}: exit {rc}: {err[-600:]}"
    tally["valid"] += 1
    return True


def _safe(rows, cell):
    wp, ws = cell["workplane"], cell["workspace"]
    m = wp["edge_margin_mm"]
    for x, y, z in rows:
        assert wp["x_mm"][0] + m - 1e-6 <= x <= wp["x_mm"][1] - m + 1e-6
        assert wp["y_mm"][0] + m - 1e-6 <= y <= wp["y_mm"][1] - m + 1e-6
        assert ws["z_mm"][0] <= z <= ws["z_mm"][1]
        for k in wp.get("keep_outs", []):
            assert not (k["x_mm"][0] < x < k["x_mm"][1] and k["y_mm"][0] < y < k["y_mm"][1])


def _readable(path):
    try:
        return read_recording(path)
    except RecordingError:
        return None


def _run_folder(root, name, data, cell_file):
    d = root / name
    shutil.rmtree(d, ignore_errors=True)
    shutil.copytree(root / "run", d, ignore=shutil.ignore_patterns(".run.lock", "report.html"))
    shutil.copyfile(cell_file, d / "cell.yaml")
    (d / "recording.csv").write_bytes(data)
    return d


def check_mutant(root, cell, n, family, data, tally):
    """The four commands on one mutant; ``tally`` counts outcomes per command."""
    m = root / "m"
    m.mkdir(exist_ok=True)
    rec = m / "recording.csv"
    rec.write_bytes(data)
    what = f"mutant {n} ({family})"
    # flatness
    rc, out, err = _cli(["flatness", str(rec), "--json", "--samples", "8"])
    if _classify(what + " flatness", rc, err, tally["flatness"]):
        _strict_json(out)
        # touches on one line or at one point: no tilt or flatness (issue 16, defect 9)
        assert family != "geometry", f"{what}: {out[:200]}"
    # explain
    target = m / "explain.json"
    target.unlink(missing_ok=True)
    rc, out, err = _cli(["explain", str(rec), "--robot", str(root / "cell16.yaml"),
                         "--json", str(target)])
    if _classify(what + " explain", rc, err, tally["explain"]):
        assert family != "geometry", f"{what}: explain gave a result"
        _strict_json(target.read_text(encoding="utf-8"))
    # report of a run folder holding the mutant
    d = _run_folder(root, "rep", data, root / "cell16.yaml")
    rc, out, err = _cli(["report", str(d)])
    if _classify(what + " report", rc, err, tally["report"]):
        assert (d / "report.html").stat().st_size > 1000
    # run --resume on a run folder with the mutant recording (one new touch at most)
    d = _run_folder(root, "res", data, root / "cell40.yaml")
    shutil.copyfile(d / "recording.csv", m / "before.csv")
    repair_cut_row(m / "before.csv")
    # the rows a reader accepts in the file as given must survive (the cut-row repair included)
    before = _readable(d / "recording.csv") or _readable(m / "before.csv")
    rc, out, err = _cli(["run", "--resume", str(d), "--no-progress"])
    ok = _classify(what + " resume", rc, err, tally["resume"])
    after = _readable(d / "recording.csv")
    if not data.lstrip(b"\xef\xbb\xbf").startswith(b"# adaptive-cal recording v1"):
        assert (d / "recording.csv").read_bytes() == data, f"{what}: resume changed a non-recording"
    if before is not None:  # every row the recording held is still there, unchanged
        assert after is not None, f"{what}: resume left an unreadable recording"
        k = len(before)
        for col in ("seq", "x_mm", "y_mm", "z_mm", "reading_mm"):
            if not np.array_equal(getattr(after, col)[:k], getattr(before, col)):
                tally["resume"]["rows lost"] += 1
                pytest.fail(f"{what}: resume changed or lost rows ({col})")
    if ok:
        _strict_json((d / "result.json").read_text(encoding="utf-8"))
        k = len(before) if before is not None else 0
        new = list(zip(after.x_mm[k:], after.y_mm[k:], after.z_mm[k:]))
        _safe(new, cell)
        tally["resume"]["new touches"] += len(new)


@pytest.mark.slow  # about 2 min alone, 7 min on a loaded 2-core machine: 200 mutants x 4 commands
def test_every_recording_mutant_is_refused_cleanly_or_gives_a_valid_result(base, monkeypatch):
    root, cell = base
    monkeypatch.setattr(session, "run", partial(session.run, max_new_touches=1))
    monkeypatch.setattr("adaptive_cal.run.results.SAMPLES", 16)
    # the resume's figures show the cell, not the mutant (report draws the mutant's touches)
    monkeypatch.setattr("adaptive_cal.run.results.write_figures", lambda *a, **k: None)
    text = (root / "run" / "recording.csv").read_text(encoding="utf-8")
    rng = random.Random(SEED)
    tally = {c: Counter() for c in ("flatness", "explain", "report", "resume")}
    families, t0 = Counter(), time.monotonic()
    per_family = {f: Counter() for f in FAMILIES}  # outcomes over the four commands
    old = signal.signal(signal.SIGALRM, _alarm)
    try:
        for n in range(MUTANTS):
            family, data = mutant(rng, text)
            families[family] += 1
            before = {k: sum(c[k] for c in tally.values()) for k in ("refused", "valid")}
            check_mutant(root, cell, n, family, data, tally)
            for k in before:
                per_family[family][k] += sum(c[k] for c in tally.values()) - before[k]
    finally:
        signal.signal(signal.SIGALRM, old)
    print(f"\n{MUTANTS} mutants x 4 commands in {time.monotonic() - t0:.0f} s")
    print(f"  {'family':18s} mutants  refused  valid   (runs: mutants x 4)")
    for f in sorted(FAMILIES):
        print(f"  {f:18s} {families[f]:7d} {per_family[f]['refused']:8d} {per_family[f]['valid']:6d}")
    for command, c in tally.items():
        print(f"  {command:9s} refused {c['refused']:4d}  valid {c['valid']:4d}  hangs "
              f"{c['hangs']}  rows lost {c['rows lost']}  new touches {c['new touches']}")
    assert set(families) == set(FAMILIES) and MUTANTS >= 200
    for c in tally.values():
        assert c["refused"] + c["valid"] == MUTANTS and c["refused"] > 0 and c["valid"] > 0


@pytest.mark.slow  # about 10 s alone (writing the 40 MB file is most of it); 38 s under load
def test_a_million_rows_get_a_clear_message_not_an_out_of_memory_kill(tmp_path, capsys):
    """Issue 15/16: a recording of 10**6 rows (about 40 MB) given to ``flatness``. The reader
    streams the file and stops at MAX_ROWS + 1 with the line, before anything grows with it."""
    from adaptive_cal.formats.recording import MAX_ROWS

    n = 10**6
    i = np.arange(n)
    x, y = (i % 1000) * 0.4 - 200.0, (i // 1000) * 0.3 - 150.0
    body = "\n".join(f"{k},,{a:.1f},{b:.1f},0,{1e-4 * (k % 97):.4f}" for k, a, b in zip(i, x, y))
    path = tmp_path / "million.csv"
    path.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n" + body + "\n")
    t0 = time.monotonic()
    assert main(["flatness", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"million.csv:{MAX_ROWS + 3}: more than {MAX_ROWS} rows" in err
    assert time.monotonic() - t0 < 10


def test_output_cut_short_by_head_is_not_an_internal_error(cheng_round0):
    """``adaptive-cal flatness REC | head -1``: the pipe closes early (issue 16, defect 11)."""
    import subprocess
    import sys

    from helpers import ROOT

    cmd = (f"{sys.executable} -m adaptive_cal.cli flatness {cheng_round0} --samples 20 | head -1;"
           " exit ${PIPESTATUS[0]}")
    done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, cwd=ROOT,
                          timeout=120)
    assert done.stdout.startswith(str(cheng_round0)) and done.stdout.count("\n") == 1
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr
    assert done.returncode == 0, done.stderr[-500:]
