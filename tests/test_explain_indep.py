"""The independent explain benchmark (issue 15, item 7): its generator shares nothing with
adaptive_cal, writes recordings the ordinary reader takes, sizes patterns as documented, and two
seeded cases give the expected verdicts."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from explain_indep import cases, generate as gen  # noqa: E402

from adaptive_cal.analysis.explain import explain  # noqa: E402
from adaptive_cal.cell.schema import load_cell  # noqa: E402
from adaptive_cal.formats.recording import read_recording  # noqa: E402


def test_generator_imports_nothing_from_adaptive_cal():
    files = sorted((ROOT / "benchmarks" / "explain_indep").glob("*.py"))
    assert len(files) >= 3
    files.append(ROOT / "benchmarks" / "explain_ceiling.py")  # the generator's ideal observer
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            assert not any(n.split(".")[0] == "adaptive_cal" for n in names), (path, names)
    gen_imports = {n.split(".")[0] for node in ast.walk(ast.parse(
        (ROOT / "benchmarks" / "explain_indep" / "generate.py").read_text(encoding="utf-8")))
        if isinstance(node, (ast.Import, ast.ImportFrom))
        for n in ([a.name for a in node.names] if isinstance(node, ast.Import)
                  else [node.module or ""])}
    assert gen_imports <= {"__future__", "dataclasses", "pathlib", "numpy"}, gen_imports


def test_recordings_load_and_the_table_is_complete(tmp_path):
    specs = cases.table(10)
    assert 900 <= len(specs) <= 1000
    spec = next(s for s in specs if s["family"] == "null_rounds")
    case = cases.build(spec, 0)
    cell, recs = gen.write(case, tmp_path)
    loaded = [read_recording(p) for p in recs]
    assert len(loaded) == len(case.rounds) >= 2
    for rec, r in zip(loaded, case.rounds):
        assert len(rec) == r["x"].size
        np.testing.assert_allclose(rec.reading_mm, r["reading"], atol=1e-6)
        np.testing.assert_allclose(rec.t_s, r["t"])
    assert load_cell(cell).probe.noise_std_mm == round(case.noise_mm, 6)


def test_k_sigma_pattern_has_the_stated_size_and_form_pv():
    # a twist u v (u, v in [-1, 1] over the workplane) at 6 sigma on an S-path, noise set to 0
    rng = np.random.default_rng(3)
    case = gen.generate("single", ("form:twist",), 6.0, "s_path", rng)
    truth = case.truth["effects"][0]
    r = case.rounds[0]
    (x0, x1), (y0, y1) = gen.PLATES["standard"]
    u, v = (2 * r["x"] - x0 - x1) / (x1 - x0), (2 * r["y"] - y0 - y1) / (y1 - y0)
    w = truth["weights_mm"]
    assert w[0] == 0 and w[1] == 0
    g = w[2] * u * v
    A = np.stack([r["x"], r["y"], np.ones_like(u)], 1)
    resid = g - A @ np.linalg.lstsq(A, g, rcond=None)[0]
    assert abs(np.linalg.norm(resid) / case.noise_mm - 6.0) < 1e-9
    # pv of w u v over [-1, 1]^2 is 2 |w|
    assert abs(truth["pv_mm"] - 2 * abs(w[2])) < 1e-12
    # the readings minus the pattern are a plane plus noise of the stated sd (72 touches)
    rest = r["reading"] - g
    e = rest - A @ np.linalg.lstsq(A, rest, rcond=None)[0]
    assert 0.6 < np.sqrt(e @ e / (e.size - 3)) / case.noise_mm < 1.4


def _verdict(case, tmp_path):
    cell, recs = gen.write(case, tmp_path)
    return explain([read_recording(p) for p in recs], load_cell(cell)).findings


def test_seeded_null_and_ten_sigma_twist(tmp_path):
    null = gen.generate("null_gauss", (), 0.0, "s_path", np.random.default_rng(11))
    f = _verdict(null, tmp_path / "null")
    assert f["verdict"] == "none", f["verdict"]
    twist = gen.generate("single", ("form:twist",), 10.0, "random", np.random.default_rng(12))
    f = _verdict(twist, tmp_path / "twist")
    assert f["verdict"] == "form", f["verdict"]
    entry = next(e for e in f["left_out"] if e["effect"] == "form")
    pv = twist.truth["effects"][0]["pv_mm"]
    assert abs(entry["params"]["pv_mm"] - pv) < 0.5 * pv


def test_the_ideal_observer_names_a_clear_effect_and_averages_exactly():
    """benchmarks/explain_ceiling.py: at 10 sigma a reversal on the S-path is unmistakable to the
    generator's own Bayes classifier; its log-mean-exp agrees with the direct mean."""
    import explain_ceiling as ceiling
    from explain_indep import cases
    v = np.array([-3.0, 0.5, 2.0, 700.0])
    assert ceiling._logmeanexp(v[:3]) == pytest.approx(np.log(np.mean(np.exp(v[:3]))), rel=1e-12)
    assert np.isfinite(ceiling._logmeanexp(v))  # no overflow at exp(700)
    spec = next(s for s in cases.table(1) if s["family"] == "single" and
                s["effects"] == ["reversal"] and s["sigma"] == 10.0 and s["design"] == "s_path")
    case = cases.build(spec, 0)
    lm = ceiling.log_marginals(case, 10.0, np.random.default_rng(0), 200)
    names = list(lm)
    post = np.exp(np.array([lm[n] for n in names]) - max(lm.values()))
    post /= post.sum()
    assert names[int(np.argmax(post))] == "reversal" and post.max() > 0.99
