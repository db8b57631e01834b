"""The log marginal likelihood (evidence) of readings under a Gaussian prior over the spline
coefficients, in the readings' dimension or the coefficients' (numpy, or traced by JAX)."""
from __future__ import annotations

import jax
import numpy as np
from scipy.linalg import solve_triangular


def _solve_lower(lower, b, xp):
    if xp is np:
        return solve_triangular(lower, b, lower=True)
    return jax.scipy.linalg.solve_triangular(lower, b, lower=True)


def log_evidence(rows, readings, cov, noise_var, mask=None, xp=np):
    """log N(y; 0, H C0 H^T + r I): the log marginal likelihood of readings y at rows H under the
    prior covariance C0, by Cholesky (L L^T = S, z = L^-1 y):

        log p = -z^T z / 2 - sum_i log L_ii - n log(2 pi) / 2.

    ``mask`` (n,) of 0/1 marks padded rows (static shapes under jit): a padded row gets unit
    variance and zero data, so it adds nothing; n counts the unmasked rows. ``xp`` is numpy or
    jax.numpy (the hyper-parameter objective traces it)."""
    if mask is None:
        mask = xp.ones(rows.shape[0])
    s = rows @ cov @ rows.T
    s = s + xp.diag(mask * noise_var + (1.0 - mask))
    lower = xp.linalg.cholesky(s)
    z = _solve_lower(lower, readings * mask, xp)
    return -0.5 * z @ z - xp.sum(xp.log(xp.diag(lower))) - 0.5 * xp.sum(mask) * xp.log(2 * xp.pi)


def log_evidence_coefficients(rows, readings, cov, noise_var, mask=None, xp=np):
    """``log_evidence`` in the coefficients' dimension K instead of the readings' n: the same
    log N(y; 0, H C0 H^T + D), D = diag(noise variance; 1 on a padded row), by the matrix
    determinant lemma and Woodbury with C0 = L L^T, G = H L, A = I + G^T D^-1 G, b = G^T D^-1 y:

        log p = -(y^T D^-1 y - b^T A^-1 b) / 2 - log|A| / 2 - log|D| / 2 - n log(2 pi) / 2.

    O(n K^2) time and n K memory where ``log_evidence`` takes O(n^3) and n^2: a recording of
    20,000 rows asked for 34 GB there. A >= I, so its Cholesky is well conditioned even where
    C0 is nearly singular (C0 carries a jitter, ``prior.JITTER_MM2``, for its own)."""
    if mask is None:
        mask = xp.ones(rows.shape[0])
    d = mask * noise_var + (1.0 - mask)
    g = rows @ xp.linalg.cholesky(cov)
    gd = g / d[:, None]
    a = xp.eye(g.shape[1]) + g.T @ gd
    lower = xp.linalg.cholesky(a)
    yd = readings * mask / d
    c = _solve_lower(lower, g.T @ yd, xp)
    quad = (readings * mask) @ yd - c @ c
    logdet = 2.0 * xp.sum(xp.log(xp.diag(lower))) + xp.sum(xp.log(d))
    return -0.5 * quad - 0.5 * logdet - 0.5 * xp.sum(mask) * xp.log(2 * xp.pi)
