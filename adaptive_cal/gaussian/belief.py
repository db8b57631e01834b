"""The belief over the spline coefficients: a Gaussian N(mean, cov). All covariance algebra lives
here. Static state, scalar measurements y = h^T a + v, v ~ N(0, r).

* ``fuse``: one reading with filterpy's KalmanFilter update (Joseph form, symmetrised):
      K = C h / (h^T C h + r),  m' = m + K (y - h^T m),
      C' = (I - K h^T) C (I - K h^T)^T + K r K^T.
* ``fuse_step``: the same update for one reading in plain array operations (numpy arrays, or
  JAX arrays under jit, ``lax.scan`` and ``vmap``), in the gain form
      k = w C h / (h^T C h + r),  m' = m + k (y - h^T m),  C' = C - k (C h)^T, symmetrised,
  with a weight w in {0, 1} that masks padded readings (w = 0 leaves the belief as it is).
* ``condition``: many readings at once (batch posterior by Cholesky solves, never inv):
      S = H C H^T + R,  m' = m + C H^T S^-1 (y - H m),  C' = C - C H^T S^-1 H C.
  Equal to fusing the rows one by one, in any order.
* ``information_cov``: the same covariance in information form, (C^-1 + H^T R^-1 H)^-1, for
  designs given as weights rather than rows.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
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
    # here, not at the top: filterpy loads scipy.stats (1.5-3 s), which the commands that only
    # condition and sample a belief (flatness, report, compensate) do not need
    from filterpy.kalman import KalmanFilter

    k = belief.mean.shape[0]
    _check_reading(row, reading, noise_var, k)
    kf = KalmanFilter(dim_x=k, dim_z=1)
    kf.x = belief.mean.reshape(k, 1).astype(float)
    kf.P = np.array(belief.cov, float)
    inn = innovation(belief, row, reading, noise_var)
    kf.update(np.array([[reading]], float), R=np.array([[noise_var]], float),
              H=np.asarray(row, float).reshape(1, k))
    return Belief(kf.x.ravel(), symmetrise(kf.P)), inn


def _check_reading(row, reading, noise_var, k: int) -> None:
    """ValueError naming what cannot be fused: a row that is not K finite numbers, a reading
    that is not finite, a noise variance that is not positive and finite (mm^2). A NaN fused
    turns the whole belief to NaN."""
    row = np.asarray(row, float)
    if row.shape != (k,) or not np.all(np.isfinite(row)):
        raise ValueError(f"row: {k} finite numbers (the belief's coefficients) needed, got "
                         f"shape {row.shape}" + ("" if row.shape != (k,) else " with a non-finite value"))
    if not np.isfinite(reading):
        raise ValueError(f"reading = {reading!r}: not a finite number (mm); nothing fused")
    if not (np.isfinite(noise_var) and noise_var > 0):
        raise ValueError(f"noise_var = {noise_var!r}: a variance must be positive and finite (mm^2)")


def fuse_step(belief: Belief, row, reading, noise_var, weight=1.0) -> Belief:
    """Fuse one reading y at row h with noise variance r (the one-reading step of a scan):

        k = w C h / (h^T C h + r),  m' = m + k (y - h^T m),  C' = C - k (C h)^T, symmetrised.

    Written with operators only, so it runs on numpy arrays and traces under ``jax.jit``,
    ``lax.scan`` (a ``Belief`` of JAX arrays is a valid carry) and ``jax.vmap``. ``weight`` w = 1
    fuses, w = 0 skips (static shapes: a mask instead of a branch). The gain form costs one
    K x K outer product; ``fuse`` (Joseph form) is the robust choice for a long-lived belief.
    """
    ch = belief.cov @ row
    gain = weight * ch / (row @ ch + noise_var)
    mean = belief.mean + gain * (reading - row @ belief.mean)
    cov = belief.cov - gain[:, None] * ch[None, :]
    return Belief(mean, 0.5 * (cov + cov.T))


def condition(belief: Belief, rows: np.ndarray, readings: np.ndarray, noise_var) -> Belief:
    """Batch posterior given readings y = H a + v, v ~ N(0, diag(noise_var)) (Cholesky)."""
    rows = np.atleast_2d(np.asarray(rows, float))
    if rows.shape[0] == 0:
        return belief
    r = np.broadcast_to(np.asarray(noise_var, float), (rows.shape[0],))
    y = np.asarray(readings, float)
    if rows.shape[1] != belief.mean.shape[0] or y.shape != (rows.shape[0],):
        raise ValueError(f"rows {rows.shape} and readings {y.shape}: need (n, "
                         f"{belief.mean.shape[0]}) and (n,)")
    if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(y)) and np.all(r > 0)
            and np.all(np.isfinite(r))):
        raise ValueError("rows, readings and noise_var must be finite (noise_var > 0): "
                         "a NaN conditioned on turns the whole belief to NaN")
    if coefficient_form(rows.shape):
        return _condition_coefficients(belief, rows, np.asarray(readings, float), r)
    hc = rows @ belief.cov  # (n, K)
    s = hc @ rows.T + np.diag(r)
    factor = cho_factor(s, lower=True)
    gain_t = cho_solve(factor, hc)  # S^-1 H C
    mean = belief.mean + gain_t.T @ (np.asarray(readings, float) - rows @ belief.mean)
    return Belief(mean, symmetrise(belief.cov - hc.T @ gain_t))


# readings at once above which the batch posterior (``condition``), the hyper-parameter
# evidence (``prior``) and the self-checks (``checks``) work in the coefficients' dimension K
# instead of the readings' n: a long recording given to flatness or report; a run stays below
COEFFICIENT_FORM_ROWS = 1024


def coefficient_form(shape: tuple[int, int]) -> bool:
    """Whether n readings on K coefficients (``shape`` (n, K) of the rows) take the
    coefficients' form: n above COEFFICIENT_FORM_ROWS and above K."""
    n, k = shape
    return n > max(COEFFICIENT_FORM_ROWS, k)


def woodbury(cov: np.ndarray, rows: np.ndarray, r: np.ndarray):
    """The K x K pieces of S = H C H^T + R (R = diag(r)) that stand for its n x n inverse: with
    C = B B^T (B from the eigen-decomposition, so a nearly singular C is no obstacle), G = H B,

        S^-1 = R^-1 - R^-1 G A^-1 G^T R^-1,   A = I + G^T R^-1 G (>= I, well conditioned).

    Returns (B, R^-1 G, the Cholesky factor of A), O(n K^2) time and n K memory."""
    w, v = np.linalg.eigh(symmetrise(cov))
    b = v * np.sqrt(np.clip(w, 0.0, None))
    g = rows @ b
    gr = g / r[:, None]
    return b, gr, cho_factor(np.eye(b.shape[1]) + g.T @ gr, lower=True)


def _condition_coefficients(belief: Belief, rows, readings, r) -> Belief:
    """``condition`` for many readings (n >> K), with ``woodbury``'s pieces:

        C' = B A^-1 B^T,   m' = m + B A^-1 G^T R^-1 (y - H m),

    where the readings' form takes O(n^3) and n^2 (20,000 readings: 65 s in the n x n
    Cholesky)."""
    b, gr, factor = woodbury(belief.cov, rows, r)
    ainv_bt = cho_solve(factor, b.T)  # A^-1 B^T
    mean = belief.mean + ainv_bt.T @ (gr.T @ (readings - rows @ belief.mean))
    return Belief(mean, symmetrise(b @ ainv_bt))


def covariance_after(cov: np.ndarray, rows: np.ndarray, noise_var) -> np.ndarray:
    """C' after readings at ``rows`` -- it does not depend on the reading values (plans ahead)."""
    return condition(Belief(np.zeros(cov.shape[0]), cov), rows, np.zeros(len(rows)), noise_var).cov


def precision(cov: np.ndarray) -> np.ndarray:
    """C^-1 by Cholesky solves (symmetrised): the information form's prior term."""
    p = cho_solve(cho_factor(cov, lower=True), np.eye(cov.shape[0]))
    return symmetrise(p)


def information_cov(prior_precision: np.ndarray, information: np.ndarray) -> np.ndarray:
    """C' = (C^-1 + H^T R^-1 H)^-1 by Cholesky solves, given C^-1 and the information
    H^T R^-1 H of the readings (weighted designs in studies); equals ``covariance_after``."""
    k = prior_precision.shape[0]
    return cho_solve(cho_factor(prior_precision + information, lower=True), np.eye(k))


def integrated_variance(cov, gram, xp=np):
    """J(C) = trace(Q C) (mm^2 mm^2), both symmetric: the sum of their elementwise product."""
    return xp.sum(gram * cov)


def rms_std(cov, gram, area_mm2: float, xp=np):
    """RMS posterior std over the plate, sqrt(J(C) / area) (mm): what the variance bound reads.
    ``xp`` is numpy or jax.numpy (the study's vmapped evaluator traces it)."""
    return rms_std_from_integrated_variance(integrated_variance(cov, gram, xp), area_mm2, xp)


def rms_std_from_integrated_variance(j, area_mm2: float, xp=np):
    """sqrt(max(J, 0) / area) (mm), for a J known without its covariance (a design bound)."""
    return xp.sqrt(xp.maximum(j, 0.0) / area_mm2)


def predict(belief: Belief, rows, xp=np) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and variance of the surface at the points of ``rows`` (N, K):
    H m and diag(H C H^T), clipped at 0. ``xp`` is numpy or jax.numpy (traced in studies)."""
    rows = xp.asarray(rows, float)
    return rows @ belief.mean, xp.maximum(xp.einsum("nk,nk->n", rows @ belief.cov, rows), 0.0)


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
