"""Readings correlated from one touch to the next are structure, not physics (issue 15 item 3):
``structure.serial_test`` against a dense reference and Monte Carlo, and explain on a recording
whose noise is an AR(1) process (the independent generator tests/open_world_generator.py draws
the plate; the noise is replaced here)."""
import numpy as np

import open_world_generator as gen
from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.evidence import Projector
from adaptive_cal.analysis.explain.structure import serial_test
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.formats.recording import read_recording


def _ar1(e: np.ndarray, rho: float) -> np.ndarray:
    """AR(1) with lag-1 correlation ``rho`` and unit marginal sd, driven by the N(0, 1) ``e``."""
    ar = np.empty(e.size)
    ar[0] = e[0]
    for k in range(1, e.size):
        ar[k] = rho * ar[k - 1] + np.sqrt(1.0 - rho * rho) * e[k]
    return ar


def _design(n=60, seed=0):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-200, 200, n), rng.uniform(-150, 150, n)
    N = np.stack([x, y, np.ones(n), x * y / 1e3], 1)  # a tilt and one more nuisance column
    P = Projector.of(N)
    i = np.arange(n - 1)
    keep = i != n // 2  # two rounds: no pair across the boundary
    return P, (i[keep], i[keep] + 1), n - P.rank


def _dense_moments(P, pairs, m, n):
    M = np.eye(n) - P.basis @ P.basis.T
    A = np.zeros((n, n))
    A[pairs[0], pairs[1]] = A[pairs[1], pairs[0]] = 0.5
    B = M @ A @ M
    tr = np.trace(B)
    return tr / m, 2.0 * (np.trace(B @ B) - tr ** 2 / m) / (m * (m + 2.0))


def test_serial_test_null_moments_match_a_dense_reference_and_monte_carlo():
    P, pairs, m = _design()
    n = P.basis.shape[0]
    mean, var = _dense_moments(P, pairs, m, n)
    rng = np.random.default_rng(1)
    E = P(rng.standard_normal((n, 20000)))  # residuals of independent Gaussian noise
    R = np.einsum("ij,ij->j", E[pairs[0]], E[pairs[1]]) / np.einsum("ij,ij->j", E, E)
    # the O(n rank) traces equal the dense ones: the p-value of a residual is that of
    # the normal tail of (R - mean) / sd with the dense moments
    r = E[:, 0]
    z = (float(r[pairs[0]] @ r[pairs[1]]) / float(r @ r) - mean) / np.sqrt(var)
    from scipy.special import ndtr
    assert abs(serial_test(P, r, m, pairs)["p_value"] - ndtr(-z)) < 1e-12
    # Monte Carlo: mean within 4 standard errors; variance within 4 x its relative error sqrt(2/N)
    se = np.sqrt(var / R.size)
    assert abs(R.mean() - mean) < 4 * se, (R.mean(), mean, se)
    assert abs(R.var() / var - 1.0) < 4 * np.sqrt(2.0 / R.size) + 0.01, (R.var(), var)
    # and the test's false-alarm rate at 1 % is about 1 % (normal approximation, n = 60)
    p = np.array([serial_test(P, E[:, k], m, pairs)["p_value"] for k in range(2000)])
    assert 0.002 <= np.mean(p < 0.01) <= 0.025


def test_serial_test_sees_correlated_noise_and_not_independent_noise():
    P, pairs, m = _design(n=120, seed=2)
    n = P.basis.shape[0]
    rng = np.random.default_rng(3)
    e = rng.standard_normal(n)
    ar = _ar1(e, 0.6)
    hit = serial_test(P, P(ar), m, pairs)
    assert hit["p_value"] < 1e-3 and hit["lag1_correlation"] > 0.3  # 1e-3: the level after
    # the Bonferroni correction over the eleven structure tests (ALPHA = 0.01)
    assert serial_test(P, P(e), m, pairs)["p_value"] > 1e-3


def test_ar1_noise_is_unexplained_along_time_not_a_library_effect(tmp_path):
    """A null plate read through a disturbance that lasts from touch to touch (AR(1), rho 0.6,
    the stated 5 um marginal sd): the verdict is ``unexplained`` (the serial-correlation test
    real), not the library effect the wander resembles."""
    for seed in range(3):
        rng = np.random.default_rng([11, seed])
        case = gen.recording("null", rng)
        n = case["x"].size
        ar = _ar1(rng.standard_normal(n), 0.6)
        plane = rng.normal(0, 1e-4) * case["x"] + rng.normal(0, 1e-4) * case["y"] + 0.1
        case["reading"] = plane + gen.NOISE_MM * ar  # in place of the generator's white noise
        cell, rec = gen.write(tmp_path, case)
        f = explain([read_recording(rec)], load_cell(cell)).findings
        assert f["verdict"] == "unexplained", (seed, f["candidates"], f["structure_after_model"])
        assert f["structure_after_model"]["tests"]["serial correlation"]["real"]
        assert f["readings"]["noise"]["serial"]["lag1_correlation"] > 0.2
        if f["unexplained"]["test"] == "serial correlation":  # else the wander along the path
            assert f["unexplained"]["axis"] == "time"  # shows as position structure first
            assert "consecutive readings are correlated" in f["unexplained"]["detail"]


def test_a_named_effect_under_correlated_noise_has_its_evidence_scaled(tmp_path, monkeypatch):
    """A 15 sigma form read through white noise plus an AR(1) disturbance (rho 0.8, each 5 um;
    the cell states their 7.1 um together): form is still named, every log BF is scaled by the
    effective share, and the JSON and the terminal say so."""
    from adaptive_cal.report.explain_text import readings_lines

    rng = np.random.default_rng(5)
    case = gen.recording("form", rng, 15.0)
    n = case["x"].size
    ar = _ar1(rng.standard_normal(n), 0.8)
    case["reading"] = case["reading"] + gen.NOISE_MM * ar
    cell, rec = gen.write(tmp_path, case, stated_noise_mm=gen.NOISE_MM * np.sqrt(2.0))
    plain = explain([read_recording(rec)], load_cell(cell)).findings
    serial = plain["readings"]["noise"]["serial"]
    test = plain["structure_after_model"]["tests"]["serial correlation"]
    assert test["real"] and serial["lag1_correlation"] == test["lag1_correlation"]
    rho = test["rho"]  # the disturbance's, from the residual's R: the fit took up part of it
    assert test["excess_rho"] < rho < 0.95
    assert serial["evidence_factor"] == (1.0 - rho) / (1.0 + rho)
    assert plain["verdict"] == "form"
    assert any("consecutive readings correlated" in line for line in readings_lines(plain))
    # against the same analysis without the scaling: every positive log BF times the factor
    from adaptive_cal.analysis.explain import core
    monkeypatch.setattr(core, "serially_deflated", lambda cands, structure: (cands, None))
    raw = explain([read_recording(rec)], load_cell(cell)).findings
    assert "serial" not in raw["readings"]["noise"]
    was = {c["effect"]: c["log_bayes_factor"] for c in raw["candidates"]}
    for c in plain["candidates"]:
        want = was[c["effect"]] * (serial["evidence_factor"] if was[c["effect"]] > 0 else 1.0)
        assert abs(c["log_bayes_factor"] - want) < 1e-9 * max(1.0, abs(want)), c


def test_ar1_rho_undoes_what_the_fit_takes_up():
    """``ar1_rho`` against a dense reference: g(rho) = tr(M A M S) / tr(M S) from n x n matrices
    equals the R it inverts, and on AR(1) draws (rho 0.5) after a tilt-and-more fit the solved
    rho averages 0.5 within Monte Carlo error (and a ratio-of-means bias of 0.01) where the raw
    R averages less."""
    from types import SimpleNamespace

    from adaptive_cal.analysis.explain.structure import ar1_rho

    rng = np.random.default_rng(4)
    n = 90
    x, y = rng.uniform(-200, 200, n), rng.uniform(-150, 150, n)
    N = np.stack([x, y, np.ones(n), x * x / 1e4, np.sin(x / 40.0)], 1)
    P = Projector.of(N)
    d = SimpleNamespace(seq=np.arange(n) % 45, round_index=(np.arange(n) >= 45).astype(int), n=n)
    M = np.eye(n) - P.basis @ P.basis.T
    A = np.zeros((n, n))
    for a in range(n - 1):
        if d.round_index[a] == d.round_index[a + 1]:
            A[a, a + 1] = A[a + 1, a] = 0.5
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    same = np.equal.outer(d.round_index, d.round_index)
    for rho in (0.2, 0.5, 0.8):
        S = np.where(same, rho ** lag, 0.0)
        R = np.trace(M @ A @ M @ S) / np.trace(M @ S)
        assert abs(ar1_rho(P, R, d) - rho) < 1e-6
    got, raw = [], []
    for _ in range(300):
        e = np.concatenate([_ar1(rng.standard_normal(45), 0.5), _ar1(rng.standard_normal(45), 0.5)])
        r = P(e)
        R = float(r @ A @ r) / float(r @ r)
        raw.append(R)
        got.append(ar1_rho(P, R, d))
    se = np.std(got) / np.sqrt(len(got))
    assert np.mean(raw) < 0.5 - 4 * se  # the fit took up part of the disturbance ...
    assert abs(np.mean(got) - 0.5) < 4 * se + 0.01  # ... and the solved rho puts it back
