"""The fast paths of explain's speed work (issue 15, item 8) give the numbers of the
straightforward code they replace, to the last bit: oracles, not timings (the timings:
benchmarks/bench_explain_speed.py)."""
import numpy as np
import pytest
from scipy.special import logsumexp

from adaptive_cal.analysis.explain import evidence
from adaptive_cal.analysis.explain.evidence import (_logsumexp_last, log_evidence_columns_mixture,
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
def test_spectral1_is_the_spectral_evidence_bit_for_bit(L, m):
    rng = np.random.default_rng(L)
    lam, c2 = _models(rng, L)
    yy = float(rng.uniform(1.0, 100.0))
    want_z, want_w = log_evidence_spectral(lam[..., None], c2[..., None], yy, m)
    got_z, got_w = log_evidence_spectral1(lam, c2, yy, m)
    assert got_z.shape == want_z.shape == lam.shape
    np.testing.assert_array_equal(got_z, want_z)
    np.testing.assert_array_equal(got_w, want_w)


def test_spectral1_chunks_change_nothing(monkeypatch):
    rng = np.random.default_rng(3)
    lam, c2 = _models(rng, 90)
    whole = log_evidence_spectral1(lam, c2, 20.0, 500)
    monkeypatch.setattr(evidence, "CHUNK", 7)  # 1170 models in 168 chunks, the last one short
    parts = log_evidence_spectral1(lam, c2, 20.0, 500)
    for a, b in zip(whole, parts):
        np.testing.assert_array_equal(a, b)
    empty = log_evidence_spectral1(np.zeros((0, 13)), np.zeros((0, 13)), 20.0, 500)
    assert empty[0].shape == (0, 13)


def test_logsumexp_last_is_scipys():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(40, 13, 73)) * 50.0
    a[0, 0, :4] = a[0, 0].max()  # tied maxima: counted apart, as scipy does
    a[1, 2] = -3.0  # all equal
    a[2, 5, 7] = 700.0  # one term dominating by e^700
    np.testing.assert_array_equal(_logsumexp_last(a), logsumexp(a, axis=-1))


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
    """``_coarse_start1`` evaluates a window of 8 grid points where its slope bounds confine the
    argmax (c2 small against the rest) and the whole grid elsewhere: both give the argmax of
    the whole grid, evaluated the straightforward way (``_spectral`` with its k axis)."""
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
    got = evidence._coarse_start1(lam, c2, rest, m, coarse, np.exp(coarse))
    np.testing.assert_array_equal(got, want)
    assert len(np.unique(np.argmax(g, axis=-1))) > 3  # the argmax moves about the grid
