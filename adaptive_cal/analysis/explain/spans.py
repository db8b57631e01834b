"""Directional identifiability: how much of effect A's signature effect B's span explains.

Aliasing is not mutual: after the tilt, arm_sag's one column (r^p, nearly a bow) lies inside
form's four-column span, but a twist does not lie in sag's. For A (columns E) and B (columns F),
both after the nuisance, with orthonormal bases Q_A (k_A columns) and Q_B:

    cosines c_1..c_kA of the principal angles, padded with zeros where k_B < k_A,
    share(A in B) = |Q_B^T Q_A|_F^2 / k_A   (mean squared cosine: the part of a unit signature
                                            of A, averaged over its directions, that B explains),
    A inside B  <=>  min_j c_j > ALIAS_CC   (every direction of A is nearly in B's span).

share(A in B) and share(B in A) are reported separately. ``covering`` names the candidates whose
span holds the verdict's signature and whose extra directions the data do not support (F-test):
the data fit them as well, the verdict is preferred for its fewer parameters only, so they are
``ambiguous_with``.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.analysis.explain.evidence import Projector

ALIAS_CC = 0.99
EXTRA_P = 0.05  # the covering span's extra directions are supported by the data below this p


def orth(X: np.ndarray) -> np.ndarray:
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > 1e-9 * max(s.max(initial=0.0), 1e-300)]


def cosines(E: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Cosines of the principal angles of span(E) to span(F), one per direction of E
    (zeros where span(F) has fewer directions), largest first."""
    QE, QF = orth(E), orth(F)
    if QE.shape[1] == 0:
        return np.ones(1)  # an all-zero regressor is invisible: fully aliased
    c = np.zeros(QE.shape[1])
    if QF.shape[1]:
        s = np.clip(np.linalg.svd(QF.T @ QE, compute_uv=False), 0.0, 1.0)
        c[:s.size] = s
    return c


def share(E: np.ndarray, F: np.ndarray) -> float:
    """Mean squared cosine: the share of A's (unit, direction-averaged) signature B explains."""
    return float(np.mean(cosines(E, F) ** 2))


def inside(E: np.ndarray, F: np.ndarray) -> bool:
    return bool(cosines(E, F).min() > ALIAS_CC)


def covering(ctx, winner, cands, threshold: float) -> list[str]:
    """Candidates above the threshold whose span holds the winner's signature and whose extra
    directions (beyond the winner) the data do not support at ``EXTRA_P``."""
    if winner is None:
        return []
    from scipy import stats  # here, not at the top: loading it is half of explain's start-up

    W = ctx.project(winner.columns)
    out = []
    for c in cands:
        if c is winner or c.log_bf <= threshold:
            continue
        F = ctx.project(c.columns)
        if not inside(W, F):
            continue
        P = Projector.of(np.hstack([ctx.nuisance, winner.columns]))
        r = P(ctx.design.target)
        extra = orth(P(c.columns))
        q = extra.shape[1]
        m = ctx.design.n - P.rank
        if q == 0 or m - q < 2:
            out.append(c.effect)
            continue
        a = extra.T @ r
        expl = float(a @ a)
        F_stat = (expl / q) / (max(float(r @ r) - expl, 1e-300) / (m - q))
        if stats.f.sf(F_stat, q, m - q) >= EXTRA_P:
            out.append(c.effect)
    return out
