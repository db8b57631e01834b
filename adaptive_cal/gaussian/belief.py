"""The belief over the spline coefficients: a Gaussian N(mean, cov). All covariance algebra lives
here. Static state, scalar measurements y = h^T a + v, v ~ N(0, r).

* ``fuse``: one reading with filterpy's KalmanFilter update (Joseph form, symmetrised):
      K = C h / (h^T C h + r),  m' = m + K (y - h^T m),
      C' = (I - K h^T) C (I - K h^T)^T + K r K^T.
* ``condition``: many readings at once (batch posterior by Cholesky solves, never inv):
      S = H C H^T + R,  m' = m + C H^T S^-1 (y - H m),  C' = C - C H^T S^-1 H C.
  Equal to fusing the rows one by one, in any order.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.linalg import cho_factor, cho_solve, cholesky


#: two-sided 95 % quantile of the standard normal, Phi^-1(0.975): bands are mean +- Z95 std
Z95 = 1.959963984540054


class Belief(NamedTuple):
    """Gaussian belief over the coefficients (mm): mean (K,), cov (K, K)."""

    mean: np.ndarray
    cov: np.ndarray


class Innovation(NamedTuple):
    """Diagnostics of one fused reading (filterpy's names in comments)."""

    residual_mm: float  # y
    variance_mm2: float  # S = h^T C h + r
    mahalanobis: float  # |y| / sqrt(S)
    log_likelihood: float


def symmetrise(c: np.ndarray) -> np.ndarray:
    return 0.5 * (c + c.T)


def innovation(belief: Belief, row: np.ndarray, reading: float, noise_var: float) -> Innovation:
    """Residual of a reading against the belief and its predictive variance."""
    y = float(reading - row @ belief.mean)
    s = float(row @ belief.cov @ row + noise_var)
    return Innovation(y, s, abs(y) / np.sqrt(s), -0.5 * (np.log(2 * np.pi * s) + y * y / s))


def fuse(belief: Belief, row: np.ndarray, reading: float, noise_var: float) -> tuple[Belief, Innovation]:
    """Fuse one reading with filterpy's KalmanFilter.update (Joseph form, then symmetrised).

    The Joseph form keeps C' symmetric positive semi-definite under round-off, and stays valid
    for a sub-optimal gain; it costs two K x K products per reading.
    """
    k = belief.mean.shape[0]
    kf = KalmanFilter(dim_x=k, dim_z=1)
    kf.x = belief.mean.reshape(k, 1).astype(float)
    kf.P = np.array(belief.cov, float)
    inn = innovation(belief, row, reading, noise_var)
    kf.update(np.array([[reading]], float), R=np.array([[noise_var]], float),
              H=np.asarray(row, float).reshape(1, k))
    return Belief(kf.x.ravel(), symmetrise(kf.P)), inn


def condition(belief: Belief, rows: np.ndarray, readings: np.ndarray, noise_var) -> Belief:
    """Batch posterior given readings y = H a + v, v ~ N(0, diag(noise_var)) (Cholesky)."""
    rows = np.atleast_2d(np.asarray(rows, float))
    if rows.shape[0] == 0:
        return belief
    r = np.broadcast_to(np.asarray(noise_var, float), (rows.shape[0],))
    hc = rows @ belief.cov  # (n, K)
    s = hc @ rows.T + np.diag(r)
    factor = cho_factor(s, lower=True)
    gain_t = cho_solve(factor, hc)  # S^-1 H C
    mean = belief.mean + gain_t.T @ (np.asarray(readings, float) - rows @ belief.mean)
    return Belief(mean, symmetrise(belief.cov - hc.T @ gain_t))


def covariance_after(cov: np.ndarray, rows: np.ndarray, noise_var) -> np.ndarray:
    """C' after readings at ``rows`` -- it does not depend on the reading values (plans ahead)."""
    return condition(Belief(np.zeros(cov.shape[0]), cov), rows, np.zeros(len(rows)), noise_var).cov


def integrated_variance(cov, gram, xp=np):
    """J(C) = trace(Q C) (mm^2 mm^2), both symmetric: the sum of their elementwise product."""
    return xp.sum(gram * cov)


def rms_std(cov, gram, area_mm2: float, xp=np):
    """RMS posterior std over the plate, sqrt(J(C) / area) (mm): what the variance bound reads.
    ``xp`` is numpy or jax.numpy (the study's vmapped evaluator traces it)."""
    return xp.sqrt(xp.maximum(integrated_variance(cov, gram, xp), 0.0) / area_mm2)


def predict(belief: Belief, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and variance of the surface at the points of ``rows`` (N, K)."""
    rows = np.asarray(rows, float)
    return rows @ belief.mean, np.maximum(np.einsum("nk,nk->n", rows @ belief.cov, rows), 0.0)


def sample(belief: Belief, rng: np.random.Generator, n: int) -> np.ndarray:
    """n coefficient vectors drawn from the belief, (n, K). Randomness is passed in."""
    k = belief.mean.shape[0]
    jitter = 1e-12 * max(float(np.trace(belief.cov)) / k, 1e-30)
    try:
        lower = cholesky(belief.cov + jitter * np.eye(k), lower=True)
    except np.linalg.LinAlgError:  # semi-definite: fall back to the symmetric square root
        w, v = np.linalg.eigh(belief.cov)
        lower = v * np.sqrt(np.clip(w, 0.0, None))
    return belief.mean + rng.standard_normal((n, k)) @ lower.T


def mixture(beliefs: list[Belief], weights) -> Belief:
    """Moment-matched Gaussian of a mixture: m = sum w_i m_i, C = sum w_i (C_i + d_i d_i^T)."""
    w = np.asarray(weights, float) / np.sum(weights)
    mean = sum(wi * b.mean for wi, b in zip(w, beliefs))
    cov = sum(wi * (b.cov + np.outer(b.mean - mean, b.mean - mean)) for wi, b in zip(w, beliefs))
    return Belief(mean, symmetrise(cov))


def widen(belief: Belief, extra_cov: np.ndarray) -> Belief:
    """Add process noise (e.g. the drift allowed since an earlier run)."""
    return Belief(belief.mean, symmetrise(belief.cov + extra_cov))
