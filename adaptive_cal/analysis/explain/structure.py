"""Structure the library does not explain: the ``unexplained`` verdict (issue 15, items 3 and 6).

After the library's best explanation L (the verdict and every other candidate above the
threshold, at their best nonlinear parameters) is removed with the calibrated nuisance, the
residual is tested for structure that is left:

- along an axis: the bases of ``locate`` (position, time, direction of arrival along x, reach,
  indication) and three finer ones the library has no effect for -- a function of x alone, a
  function of y alone (a ripple, one offset per column or row), and the direction of arrival
  along y (a backlash in y) -- each by the nested-model F-test given N and L;
- against the probe's stated noise (``probe.noise_range_mm``'s upper end, else
  ``probe.noise_std_mm`` where the cell file states it): RSS / sigma_stated^2 against
  chi-square(m) -- readings scattered at twice the stated noise are structure, not noise;
- serial correlation (``serial_test``): the residual's lag-1 correlation in the order taken,
  against its exact mean and variance under independent noise -- a disturbance lasting from
  one touch to the next.

The tests are Bonferroni-corrected to a family-wise ``ALPHA``. The verdict is ``unexplained``
when the most significant corrected test passes and the structure left (its energy beyond what
noise gives: explained - q s^2 for an axis, RSS - m sigma_stated^2 for the noise) is larger than
the energy the library explains (|M y|^2 - |r_L|^2): the library then names less than half of
what is there, and the nearest library name would be a guess. Where the library explains most of
it (the reference plate: form takes 150 -> 31 um, 10 um stated) the verdict stands and the
structure left is still reported (``structure_after_model``). Serial correlation is not weighed
that way: where it is real, the disturbance's rho (``ar1_rho``) scales every log BF
(``core.serially_deflated``), and the verdict is ``unexplained`` where no library effect keeps
its name through that.
"""
from __future__ import annotations

import numpy as np
from scipy import special

from adaptive_cal.analysis.explain.candidates import Candidate, Context
from adaptive_cal.analysis.explain.evidence import Projector
from adaptive_cal.analysis.explain.locate import (MIN_GROUP, ROUNDOFF, axis_bases, column_norm,
                                                  direction_columns, where)

MAX_COLUMNS = 48  # of a one-coordinate basis (memory: n x 48 floats)
ALPHA = 0.01  # family-wise false-alarm rate of the structure tests on a recording of noise only
SERIAL = "serial correlation"
AXIS_OF = {"position along x": "position", "position along y": "position",
           "direction along y": "direction", SERIAL: "time"}


def arrival(v: np.ndarray, round_index: np.ndarray) -> np.ndarray:
    """+1 / -1 moving +v / -v into the point, per round in touch order (0 before any move)."""
    out = np.zeros(v.size)
    for r in np.unique(round_index):
        idx = np.flatnonzero(round_index == r)
        last = 0.0
        for k in range(1, idx.size):
            step = v[idx[k]] - v[idx[k - 1]]
            last = 1.0 if step > 1e-9 else (-1.0 if step < -1e-9 else last)
            out[idx[k]] = last
    return out


def one_coordinate(v: np.ndarray, span: tuple[float, float], n: int) -> np.ndarray:
    """A function of one coordinate: one offset per distinct value on a grid design, else a
    Fourier series down to twice the median spacing (at most n / 3 and ``MAX_COLUMNS``
    columns)."""
    keys = np.round(v, 1)
    levels = np.unique(keys)
    cap = max(min(n // 3, MAX_COLUMNS), 2)
    if 2 <= levels.size <= cap:
        return (keys[:, None] == levels[None, 1:]).astype(float)
    width = max(span[1] - span[0], 1e-9)
    gaps = np.diff(np.sort(v))
    gaps = gaps[gaps > 1e-9]
    finest = 2.0 * float(np.median(gaps)) if gaps.size else width
    k = int(np.clip(width / max(finest, 1e-9), 1, cap // 2))
    w = 2.0 * np.pi * np.arange(1, k + 1)[None, :] * (v[:, None] - span[0]) / (2.0 * width)
    return np.hstack([np.sin(w), np.cos(w)])


def _bases(ctx: Context) -> dict[str, np.ndarray]:
    d = ctx.design
    f = d.features
    out = {k: v for k, v in axis_bases(ctx).items() if not isinstance(v, str)}
    out["position along x"] = one_coordinate(f.x_mm, d.geometry.x_range_mm, d.n)
    out["position along y"] = one_coordinate(f.y_mm, d.geometry.y_range_mm, d.n)
    dy = arrival(f.y_mm, d.round_index)
    out["direction along y"] = direction_columns(dy)
    return out


def _axis_test(P: Projector, r: np.ndarray, m: int, X: np.ndarray) -> dict:
    Xt = P(X)
    U, s, _ = np.linalg.svd(Xt, full_matrices=False)
    # a column the nuisance spans leaves round-off (1e-13 of its norm), not variation to test
    keep = (s > 1e-8 * max(s.max(initial=0.0), 1e-300)) & (s > ROUNDOFF * column_norm(X))
    q = int(min(keep.sum(), max(m - 3, 0)))
    if q == 0:
        return {"p_value": 1.0, "excess_mm2": 0.0, "q": 0}
    proj = U[:, keep][:, :q].T @ r
    explained = float(proj @ proj)
    rss1 = max(float(r @ r) - explained, 1e-300)
    s2 = rss1 / (m - q)
    F = (explained / q) / s2
    return {"p_value": float(special.fdtrc(q, m - q, max(F, 0.0))), "excess_mm2": max(explained - q * s2, 0.0),
            "q": q}


def touch_pairs(d) -> tuple[np.ndarray, np.ndarray]:
    """Rows (i, j) of every pair of touches taken one after the other in the same round."""
    order = np.lexsort((d.seq, d.round_index))
    same = d.round_index[order[1:]] == d.round_index[order[:-1]]
    return order[:-1][same], order[1:][same]


def _lag1_terms(Q: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """A Q and Q^T A Q for A with 1/2 at (i, j) and (j, i) of every pair: O(n rank), A sparse."""
    i, j = pairs
    AQ = np.zeros_like(Q)
    np.add.at(AQ, i, 0.5 * Q[j])
    np.add.at(AQ, j, 0.5 * Q[i])
    return AQ, Q.T @ AQ


def serial_test(P: Projector, r: np.ndarray, m: int, pairs) -> dict:
    """Readings correlated from one touch to the next (vibration, a wandering temperature, a
    gauge that settles): the lag-1 autocorrelation R = r^T A r / r^T r of the residual in the
    order taken (A: 1/2 on each pair of consecutive touches of a round), one-sided.

    Under independent Gaussian noise r = M e with M the residual projector, and R is a ratio of
    quadratic forms in e independent of its denominator, so its mean and variance are exact
    (Durbin & Watson 1950, "Testing for serial correlation in least squares regression I",
    Biometrika 37, 409-428): E R = tr(M A) / m, Var R = 2 (tr((M A)^2) - (tr(M A))^2 / m) /
    (m (m + 2)); the p-value is the normal tail of (R - E R) / sd R. The traces take the basis Q
    of span(M)'s complement only (O(n rank), no n x n matrix): A is sparse."""
    i, j = pairs
    q, rr = int(i.size), float(r @ r)
    if q < 8 or m < 8 or rr <= 0.0:
        return {"p_value": 1.0, "excess_mm2": 0.0, "q": 0}
    AQ, QAQ = _lag1_terms(P.basis, pairs)
    tr_ma = -float(np.trace(QAQ))  # tr(A) = 0
    # tr(MAMA) = tr(A^2) - 2 tr(Q^T A^2 Q) + tr((Q^T A Q)^2)
    tr_a2 = 0.5 * q  # each pair gives (1/2)^2 at (i, j) and (j, i), twice in the trace
    tr_mama = tr_a2 - 2.0 * float(np.sum(AQ * AQ)) + float(np.sum(QAQ * QAQ))
    mean = tr_ma / m
    var = 2.0 * (tr_mama - tr_ma ** 2 / m) / (m * (m + 2.0))
    R = float(r[i] @ r[j]) / rr
    z = (R - mean) / np.sqrt(max(var, 1e-300))
    # its size: the share rho^2 of the residual that the previous reading predicts
    return {"p_value": float(special.ndtr(-z)), "excess_mm2": max(R - mean, 0.0) ** 2 * rr,
            "q": 1, "lag1_correlation": R, "excess_rho": max(R - mean, 0.0)}


def _ar1_cov_times(Q: np.ndarray, segments: list[np.ndarray], rho: float) -> np.ndarray:
    """Sigma Q for Sigma_ij = rho^|i - j| between touches of one round in the order taken (0
    across rounds): per round a forward and a backward exponential filter, less the diagonal
    counted twice."""
    from scipy.signal import lfilter

    out = np.zeros_like(Q)
    for idx in segments:
        x = Q[idx]
        f = lfilter([1.0], [1.0, -rho], x, axis=0)
        b = lfilter([1.0], [1.0, -rho], x[::-1], axis=0)[::-1]
        out[idx] = f + b - x
    return out


def ar1_rho(P: Projector, R: float, d) -> float:
    """The lag-1 correlation rho of an AR(1) disturbance (within each round, in the order taken)
    whose residual after the same fit shows the lag-1 correlation R: the fit takes up part of
    the disturbance, so R understates rho. Solves g(rho) = R by bisection on [0, 0.95], with
    g(rho) = E[r^T A r] / E[r^T r] = tr(M A M S) / tr(M S), S the AR(1) correlation; the traces
    from the basis Q of the fit (M = I - Q Q^T) and S Q (``_ar1_cov_times``), O(n rank) each."""
    order = np.lexsort((d.seq, d.round_index))
    segments = [order[d.round_index[order] == k] for k in np.unique(d.round_index)]
    pairs = touch_pairs(d)
    Q = P.basis
    AQ, QAQ = _lag1_terms(Q, pairs)

    def g(rho: float) -> float:
        SQ = _ar1_cov_times(Q, segments, rho)
        QSQ = Q.T @ SQ
        num = pairs[0].size * rho - 2.0 * float(np.sum(AQ * SQ)) + float(np.sum(QAQ * QSQ))
        return num / max(d.n - float(np.trace(QSQ)), 1e-300)

    lo, hi = 0.0, 0.95
    if R <= g(lo):
        return 0.0
    if R >= g(hi):
        return hi
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) < R else (lo, mid)
    return 0.5 * (lo + hi)


def residual_structure(ctx: Context, cands: list[Candidate], winner: Candidate | None,
                       threshold: float, noise_mm: float, tested: bool = True) -> dict:
    """The ``structure_after_model`` block, and whether the verdict is ``unexplained``.
    ``tested`` False (a mismatch below the probe's readout step): the residual's size, no tests."""
    d = ctx.design
    lib = [c for c in cands if c.log_bf > threshold]
    G = np.hstack([ctx.nuisance] + [c.columns for c in lib])
    P = Projector.of(G)
    r = P(d.target)
    m = d.n - P.rank
    if m < 4:
        return {"unexplained": False, "tests": {}, "note": "too few readings to test"}
    if not tested:
        rss = float(r @ r)
        return {"library": [c.effect for c in lib], "residual_rms_mm": float(np.sqrt(rss / d.n)),
                "library_rms_mm": 0.0, "tests": {}, "alpha": ALPHA, "unexplained": False,
                "note": "not tested: the residual is below the probe's readout step (rounding)"}
    tests = {name: _axis_test(P, r, m, X) for name, X in _bases(ctx).items()}
    tests[SERIAL] = serial_test(P, r, m, touch_pairs(d))
    rss = float(r @ r)
    if noise_mm > 0:
        tests["noise"] = {"p_value": float(special.chdtrc(m, max(rss / noise_mm ** 2, 0.0))),
                          "excess_mm2": max(rss - m * noise_mm ** 2, 0.0), "q": 0,
                          "stated_noise_mm": noise_mm,
                          "residual_rms_mm": float(np.sqrt(rss / m))}
    k = len(tests)
    for t in tests.values():
        t["p_value_corrected"] = min(1.0, t["p_value"] * k)
        t["structure_rms_mm"] = float(np.sqrt(t.pop("excess_mm2") / d.n))
        t["real"] = bool(t["p_value_corrected"] < ALPHA)
    if tests[SERIAL]["real"]:  # the disturbance's own rho, for scaling the evidence
        tests[SERIAL]["rho"] = ar1_rho(P, tests[SERIAL]["lag1_correlation"], d)
    library_mm2 = float(ctx.yt @ ctx.yt) - rss if lib else 0.0
    real = {n: t for n, t in tests.items() if t["real"]}
    out = {"library": [c.effect for c in lib], "residual_rms_mm": float(np.sqrt(rss / d.n)),
           "library_rms_mm": float(np.sqrt(max(library_mm2, 0.0) / d.n)),
           "tests": tests, "alpha": ALPHA, "unexplained": False}
    if not real:
        return out
    # serial correlation is answered by scaling the evidence (``core.serially_deflated``): it
    # makes the verdict unexplained where no library effect survives the scaling, not by
    # weighing its energy against the library's here
    others = {n: t for n, t in real.items() if n != SERIAL}
    pool = others or real
    axes = [n for n in pool if n != "noise"] or ["noise"]  # the most specific axis that shows it
    name = max(axes, key=lambda n: (pool[n]["structure_rms_mm"], -pool[n]["p_value"]))
    t = pool[name]
    left_mm2 = max(u["structure_rms_mm"] for u in pool.values()) ** 2 * d.n
    out["unexplained"] = bool(others) and bool(left_mm2 > library_mm2)
    sigma = float(np.sqrt(rss / m))
    out["finding"] = {
        "axis": AXIS_OF.get(name, name), "test": name, "p_value": t["p_value_corrected"],
        "structure_rms_mm": t["structure_rms_mm"],
        "library_share": float(library_mm2 / (library_mm2 + left_mm2)) if lib else 0.0,
        "nearest_library_effect": winner.effect if winner else None,
        "where": where(ctx, r, sigma), "detail": _detail(name, t, r, ctx)}
    return out


def structure_probability(p_value: float) -> float:
    """How probable the structure is, given the test's (corrected) p-value: an upper bound, not
    1 - p. Sellke, Bayarri & Berger (2001, "Calibration of p values for testing precise null
    hypotheses", The American Statistician 55, 62-71): over a broad class of alternatives the
    Bayes factor of the null is at least B = -e p ln p for p < 1/e, so with prior odds 1 the
    posterior probability of structure is at most 1 / (1 + B). p = 0.01 (the test's level) gives
    0.889, p = 1e-3 0.981, p = 1e-4 0.9975. 1 - p put every ``unexplained`` verdict at >= 0.99,
    and 1.5 % of those were wrong on the independent benchmark (docs/explain-benchmark.md)."""
    p = float(p_value)
    if not p > 0.0:
        return 1.0
    if p >= 1.0 / np.e:
        return 0.5
    return float(1.0 / (1.0 - np.e * p * np.log(p)))


def _detail(name: str, t: dict, r: np.ndarray, ctx: Context) -> str:
    d = ctx.design
    what = (f"{1e3 * t['structure_rms_mm']:.1f} um rms of structure (p = {t['p_value_corrected']:.2g}"
            ", corrected for the tests made)")
    if name == "noise":
        return (f"readings scatter {1e3 * t['residual_rms_mm']:.1f} um rms about the best library "
                f"model, the probe's stated noise is {1e3 * t['stated_noise_mm']:.1f} um: {what}")
    if name == "direction along y":
        dy = arrival(d.features.y_mm, d.round_index)
        said = ", ".join(f"{1e3 * r[m].mean():+.1f} um arriving {label}"
                         for label, m in (("moving +y", dy > 0), ("moving -y", dy < 0),
                                          ("without moving along y", dy == 0))
                         if m.sum() >= MIN_GROUP)  # a raster never arrives moving -y
        return (f"the residual averages {said} (no library effect acts along y's direction): "
                f"{what}")
    if name == "serial correlation":
        return (f"consecutive readings are correlated (lag-1 correlation "
                f"{t['lag1_correlation']:+.2f} of the residual in the order taken; independent "
                f"readings give about 0): a disturbance that lasts from one touch to the next "
                f"(vibration, a wandering temperature, a gauge that settles), not an effect of the "
                f"library, and evidence that takes the readings as independent is overstated: {what}")
    if name.startswith("position along"):
        return f"a function of {name[-1]} alone, finer than the library's form: {what}"
    return f"along {name}, beyond every library effect: {what}"
