"""The fast paths of explain's speed work (issue 15, item 8) give the numbers of the
straightforward code they replace, to the last bit: oracles, not timings (the timings:
benchmarks/bench_explain_speed.py)."""
import numpy as np
import pytest
from scipy.special import logsumexp

from adaptive_cal.analysis.explain import evidence, evidence1
from adaptive_cal.analysis.explain.evidence import (log_evidence_columns_mixture,
                                                    log_evidence_spectral, log_evidence_spectral1)


def _models(rng, L, T=13):
    """L one-column models with T prior scales each: lam spanning 1e-12 to 1e6 of the noise,
    c2 from 0 to above |y|^2 (its clamp), ties of lam = 0 (a column the projection removed)."""
    s = rng.uniform(0.0, 5.0, L) ** 6
    s[:3] = 0.0
    lam = s[:, None] * np.geomspace(1e-4, 1.0, T)[None, :] ** 2
    c2 = rng.uniform(0.0, 3.0, L) ** 4
    c2[3] = 1e4  # above yy: rest clamped at 1e-12 yy
    return lam, np.broadcast_to(c2[:, None], lam.shape)


@pytest.mark.parametrize("L,m", [(5, 3), (7, 40), (600, 4000), (1500, 100_000)])
def test_spectral1_is_the_spectral_evidence(L, m):
    rng = np.random.default_rng(L)
    lam, c2 = _models(rng, L)
    yy = float(rng.uniform(1.0, 100.0))
    want_z, want_w = log_evidence_spectral(lam[..., None], c2[..., None], yy, m)
    got_z, got_w = log_evidence_spectral1(lam, c2, yy, m)
    assert got_z.shape == want_z.shape == lam.shape
    # the same to round-off: only Newton's start differs (``_start1``), and both stop within
    # NEWTON_TOL of the mode (to ~1e-8 in w)
    np.testing.assert_allclose(got_z, want_z, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(got_w, want_w, rtol=0, atol=1e-7)


def test_spectral1_chunks_change_nothing(monkeypatch):
    rng = np.random.default_rng(3)
    lam, c2 = _models(rng, 90)
    whole = log_evidence_spectral1(lam, c2, 20.0, 500)
    monkeypatch.setattr(evidence1, "CHUNK", 7)  # 1170 models in 168 chunks, the last one short
    parts = log_evidence_spectral1(lam, c2, 20.0, 500)
    for a, b in zip(whole, parts):
        np.testing.assert_array_equal(a, b)
    empty = log_evidence_spectral1(np.zeros((0, 13)), np.zeros((0, 13)), 20.0, 500)
    assert empty[0].shape == (0, 13)


def test_columns_mixture_is_the_per_model_evidence():
    """The bump search's evidence of many one-column models, against each model scored alone
    with the general k-column evidence (``log_evidence_mixture`` at one tau each)."""
    rng = np.random.default_rng(11)
    n, L = 60, 25
    Xt, yt = rng.normal(size=(n, L)), rng.normal(size=n)
    Xt[:, 0] = 0.0
    taus = np.geomspace(0.01, 10.0, 9)
    lz, best = log_evidence_columns_mixture(Xt, yt, taus, n - 3)
    for j in range(L):
        per_tau = [evidence.log_evidence(Xt[:, [j]], yt, np.array([t * t]), n - 3)[0]
                   for t in taus]
        assert lz[j] == pytest.approx(logsumexp(per_tau) - np.log(taus.size), rel=1e-12, abs=1e-9)
        if j:  # the zero column: every tau ties
            assert best[j] == int(np.argmax(per_tau))


@pytest.mark.parametrize("m", [2, 5, 60, 4000])
def test_coarse_window_finds_the_whole_grids_argmax(m):
    """``_start1`` evaluates a window of 8 grid points where its slope bounds confine the
    argmax (c2 small against the rest) and the whole grid elsewhere: both give the argmax of
    the whole grid, evaluated the straightforward way (``_spectral`` with its k axis). Where
    the bounds are tighter than ``TIGHT`` it starts between them, within TIGHT / 2 of the
    mode, and the grid is not evaluated."""
    rng = np.random.default_rng(m)
    L = 400
    lam = rng.uniform(0.0, 3.0, L) ** 6
    yy = 10.0
    c2 = np.concatenate([rng.uniform(0.0, 1e-3, L // 2), rng.uniform(0.0, 12.0, L // 2)])
    rest = np.maximum(yy - c2, 1e-12 * yy)
    coarse = np.log(yy / m) + np.linspace(-14.0, 4.0, 61)
    g = evidence._spectral(lam[:, None], c2[:, None], yy, m,
                           np.broadcast_to(coarse, (L, coarse.size)))
    want = coarse[np.argmax(g, axis=-1)]
    got = evidence1._start1(lam, c2, rest, m, coarse, np.exp(coarse))
    w_lo, w_hi = np.log(rest / m), np.log((rest + c2) / (m - 1))
    tight = w_hi - w_lo < evidence1.TIGHT
    # never at a handful of rows: the bounds are log(m / (m - 1)) apart even where c2 = 0
    assert np.count_nonzero(tight) < L and (np.any(tight) if m >= 20 else not np.any(tight))
    np.testing.assert_array_equal(got[~tight], want[~tight])
    mode, _ = evidence1._newton1(lam, c2, rest, m, want)  # from the grid's best point
    assert np.all(np.abs(got[tight] - mode[tight]) <= 0.5 * evidence1.TIGHT)
    np.testing.assert_allclose(evidence1._newton1(lam, c2, rest, m, got)[0], mode, rtol=0,
                               atol=1e-7)  # the same mode from either start
    assert len(np.unique(np.argmax(g, axis=-1))) > 3  # the argmax moves about the grid


def _student_t_recording(n=300, seed=1):
    """n touches at random positions on the generator's plain cell, 5 um Student-t (3 dof)
    noise: suspects set aside in passes, and a bump judged with and without a reading (the
    speed bench's ``student_t`` kind, smaller)."""
    from adaptive_cal.formats.recording import Recording
    from adaptive_cal.simulation.concealed import WORKPLANE, ZERO_MM, generator_cell

    rng = np.random.default_rng(seed)
    x, y = rng.uniform(*WORKPLANE["x_mm"], n), rng.uniform(*WORKPLANE["y_mm"], n)
    noise = rng.standard_t(3, n) / np.sqrt(3.0)
    reading = np.round((ZERO_MM + 0.003 * x - 0.002 * y + 0.1 + 0.005 * noise) / 1e-4) * 1e-4
    return Recording(np.arange(n), 4.0 * np.arange(n), x, y, np.zeros(n), reading,
                     path="student-t"), generator_cell()


def test_kept_bells_are_the_bells_of_the_rows_kept():
    from adaptive_cal.analysis.explain.design import build_design
    from adaptive_cal.analysis.explain.suspects import kept_bells
    from adaptive_cal.effects.plate import defect_regressor_sparse

    rec, cell = _student_t_recording()
    design = build_design([rec], cell)
    keep = np.random.default_rng(2).random(design.n) > 0.1
    built = {}
    for radius in (10.0, 40.0):
        got = kept_bells(design, keep, built)(radius)
        want = defect_regressor_sparse(design.select(keep).features, design.geometry, radius)
        assert got.shape == want.shape
        for a in ("row", "col", "data"):  # entry for entry, in the same order
            np.testing.assert_array_equal(getattr(got, a), getattr(want, a))
    assert set(built) == {10.0, 40.0}
    whole = kept_bells(design, np.ones(design.n, bool), built)(40.0)  # the first pass: no cut
    want = defect_regressor_sparse(design.features, design.geometry, 40.0)
    for a in ("row", "col", "data"):
        np.testing.assert_array_equal(getattr(whole, a), getattr(want, a))


def _straight_spectral1(lam, c2, yy, m):
    """The straightforward evaluation the fast one replaces: ``log_evidence_spectral`` with its
    k axis, in the blocks of 256 bump centres the search used."""
    lam, c2 = np.broadcast_arrays(np.asarray(lam, float), np.asarray(c2, float))
    parts = [log_evidence_spectral(lam[j:j + 256, ..., None], c2[j:j + 256, ..., None], yy, m)
             for j in range(0, max(len(lam), 1), 256)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def test_explain_fast_paths_give_the_straightforward_answer(monkeypatch):
    """explain end to end on a Student-t recording (suspects, a judged bump): the fast one-column
    evidence and the bells cut from the whole design's give every number of the findings that
    the straightforward evidence and bells built per scoring give, bit for bit."""
    import json

    from adaptive_cal.analysis.explain import explain, suspects

    rec, cell = _student_t_recording()
    fast = explain([rec], cell).findings
    assert fast["suspect_readings"]  # the passes and the judgement ran
    monkeypatch.setattr(evidence, "log_evidence_spectral1", _straight_spectral1)
    monkeypatch.setattr(suspects, "kept_bells", lambda design, keep, built: None)
    straight = explain([rec], cell).findings
    assert json.dumps(fast, sort_keys=True, default=float) == json.dumps(
        straight, sort_keys=True, default=float)


@pytest.mark.parametrize("layout", ["random", "grid", "two"])
def test_nearest_other_is_the_dense_minimum(layout):
    """``locate``'s bandwidth: the k-d tree's candidates give the dense hypot matrix's row
    minima bit for bit, on random positions and on a grid (4 neighbours tie at one distance)."""
    from adaptive_cal.analysis.explain.locate import nearest_other

    rng = np.random.default_rng(4)
    if layout == "random":
        xy = rng.uniform(0.0, 300.0, (2000, 2))
    elif layout == "grid":
        gx, gy = np.meshgrid(np.arange(30) * 10.0 + 3.3, np.arange(20) * 10.0 - 1.7)
        xy = np.stack([gx.ravel(), gy.ravel()], 1)
    else:
        xy = np.array([[0.0, 0.0], [3.0, 4.0]])
    xy = np.unique(xy, axis=0)
    dense = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    np.fill_diagonal(dense, np.inf)
    np.testing.assert_array_equal(nearest_other(xy), dense.min(1))
