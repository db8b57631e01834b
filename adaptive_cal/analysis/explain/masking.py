"""Gross errors that hide each other: a second start for the suspect screen.

``suspects.suspect_probability`` judges each reading against the others, starting with every
reading good. Two large gross errors on a short recording then mask each other: each inflates
the noise the other is judged against, so neither is set aside (an outside audit, 2026-11-30:
two +0.5 mm misreads among 12 readings of 2 um noise came out "unexplained structure along
noise" at p 1.00). A robust fit sees them: least absolute deviations of the nuisance model
(``robust_start``) flags the readings far outside its residuals' robust scale. The screen is
then run a second time from those, and of the two fixed points the one of larger joint
posterior (``log_joint``: the kept readings' Gaussian likelihood at their own noise, each
suspect a gross error of prior ``RATE``, averaged over the models as the screen weighs them)
is kept. A burr that two touches carry is not lost that way: under the local_defect model
that explains it, setting its touches aside costs their likelihood and two gross errors'
prior, so the first fixed point wins.
"""
from __future__ import annotations

import numpy as np
from scipy import special

#: a reading this many robust sds from the least-absolute-deviations fit starts as a suspect
ROBUST_Z = 6.0
IRLS_STEPS = 30


def robust_start(D: np.ndarray, y: np.ndarray, floor_mm: float, most: int) -> np.ndarray:
    """Readings whose residual from the least-absolute-deviations fit of ``D`` (iteratively
    reweighted least squares) exceeds ``ROBUST_Z`` robust sds (1.4826 x the median absolute
    residual, scaled up for the p residuals such a fit sets to zero), never below the probe's
    stated noise ``floor_mm``: at most ``most`` of them, the largest."""
    n, k = D.shape
    if n <= k + 2:
        return np.zeros(n, bool)
    coef = np.linalg.lstsq(D, y, rcond=None)[0]
    scale = max(float(np.median(np.abs(y - D @ coef))), floor_mm, 1e-12)
    for _ in range(IRLS_STEPS):
        r = y - D @ coef
        sw = 1.0 / np.sqrt(np.maximum(np.abs(r), 1e-6 * scale))
        coef = np.linalg.lstsq(D * sw[:, None], y * sw, rcond=None)[0]
    r = np.abs(y - D @ coef)
    sd = max(1.4826 * float(np.median(r)) * np.sqrt(n / (n - k)), floor_mm, 1e-12)
    out = np.zeros(n, bool)
    far = np.flatnonzero(r > ROBUST_Z * sd)
    out[far[np.argsort(-r[far])][:max(most, 0)]] = True
    return out


def penalised_fit(D: np.ndarray, y: np.ndarray, penalty: np.ndarray, keep: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The penalised least-squares fit y ~ D coef on the rows ``keep`` (``penalty``: k x k, zero
    rows for the flat-prior nuisance): (residual e of every reading, q_i = d_i^T A^-1 d_i of
    every row), A = D_k^T D_k + penalty, symmetrised, with a ridge of 1e-12 of its mean
    diagonal. Shared by ``suspects.predictive`` and ``log_joint``."""
    Dk = D[keep]
    A = Dk.T @ Dk + penalty
    A = 0.5 * (A + A.T) + 1e-12 * np.trace(A) / A.shape[0] * np.eye(A.shape[0])
    L = np.linalg.cholesky(A)
    W = np.linalg.solve(L, D.T)
    e = y - D @ np.linalg.solve(L.T, np.linalg.solve(L, Dk.T @ y[keep]))
    return e, np.einsum("ij,ij->j", W, W)


def log_joint(models, y: np.ndarray, logw: np.ndarray, suspect: np.ndarray, floor_mm: float,
              rate: float, gross_logpdf, scale: float) -> float:
    """log p(y, these suspects) averaged over the models (weights exp(``logw``)): per model the
    penalised least-squares fit of the kept readings, their Gaussian likelihood at the noise
    they leave (never below ``floor_mm``), each kept reading good with prior 1 - ``rate`` and
    each suspect a gross error with prior ``rate`` and density ``gross_logpdf`` at its
    predictive residual (of scale sqrt((1 + q) v + ``scale``^2 v)). -inf where too few
    readings are kept to fit a model."""
    keep = ~suspect
    n_k = int(np.count_nonzero(keep))
    out = []
    for D, pen in models:
        if n_k <= D.shape[1] + 1:
            return -np.inf
        e, q = penalised_fit(D, y, pen, keep)
        rss = float(np.sum(e[keep] ** 2))
        v = max(rss / n_k, floor_mm ** 2, 1e-30)
        ll = -0.5 * (n_k * np.log(2.0 * np.pi * v) + rss / v) + n_k * np.log1p(-rate)
        if suspect.any():
            ll += float(np.sum(np.log(rate) + gross_logpdf(
                e[suspect], np.sqrt((1.0 + q[suspect]) * v + scale ** 2 * v))))
        out.append(ll)
    return float(special.logsumexp(np.asarray(out) + np.ravel(logw)))
