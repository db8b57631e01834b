"""Gaussian prior over the spline coefficients, marginal likelihood and hyper-parameter fit.

Prior: a = a_tilt + a_form, independent Gaussians.

* tilt:  a_tilt = P (s_x, s_y, c), P = [x_k - x_c, y_k - y_c, 1] at the knots; slopes with
  std tan(tilt_std_deg), offset at the plate centre with std offset_std_mm. Splines reproduce a
  plane exactly, so the tilt is inside the model.
* form:  a_form ~ N(0, sigma_f^2 K_x kron K_y), K(u, v) = exp(-(u - v)^2 / (2 l^2)) at the knots.

Hyper-parameters theta = (sigma_f, l, sigma_n) are fitted by maximising the log marginal
likelihood of the readings, log N(y; H m0, H C0(theta) H^T + sigma_n^2 I), plus a weak
log-normal hyper-prior around the configured values (MAP-II), with JAX gradients.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from .belief import Belief
from .spline import Surface

JITTER_MM2 = 1e-10


class Hyper(NamedTuple):
    """Form amplitude (mm), form length scale (mm), reading noise std (mm)."""

    form_std_mm: float
    length_scale_mm: float
    noise_std_mm: float


@dataclass(frozen=True, eq=False)  # hashed by identity: caches its compiled objective
class PriorModel:
    """What the prior needs besides the hyper-parameters."""

    surface: Surface
    slope_std: float  # mm/mm
    offset_std_mm: float
    centre_mm: tuple[float, float]
    hyper0: Hyper  # configured values: start of the fit and centre of the hyper-prior
    hyper_log_std: tuple[float, float, float] = (1.0, 0.7, 1.0)

    @property
    def tilt_basis(self) -> np.ndarray:
        """P (K x 3): coefficients of the plane a (x - x_c) + b (y - y_c) + c."""
        gx, gy = self.surface.knot_grid()
        return np.stack([gx - self.centre_mm[0], gy - self.centre_mm[1], np.ones_like(gx)], 1)

    def tilt_cov(self) -> np.ndarray:
        var = np.array([self.slope_std**2, self.slope_std**2, self.offset_std_mm**2])
        p = self.tilt_basis
        return (p * var) @ p.T

    def form_cov(self, form_std_mm, length_scale_mm, xp=np):
        kx = _se(self.surface.sx.knots[: self.surface.sx.size], length_scale_mm, xp)
        ky = _se(self.surface.sy.knots[: self.surface.sy.size], length_scale_mm, xp)
        return form_std_mm**2 * xp.kron(kx, ky)

    def belief(self, hyper: Hyper) -> Belief:
        """The prior belief N(0, C_tilt + C_form(theta))."""
        k = self.surface.size
        cov = self.tilt_cov() + self.form_cov(hyper.form_std_mm, hyper.length_scale_mm)
        return Belief(np.zeros(k), cov + JITTER_MM2 * np.eye(k))


def _se(knots: np.ndarray, length, xp):
    d = np.subtract.outer(knots, knots)
    return xp.exp(-0.5 * (d / length) ** 2)


def log_marginal(model: PriorModel, hyper: Hyper, rows: np.ndarray, readings: np.ndarray) -> float:
    """log N(y; 0, H C0 H^T + sigma_n^2 I) -- the evidence of the readings under theta."""
    rows = np.asarray(rows, float)
    prior = model.belief(hyper)
    s = rows @ prior.cov @ rows.T + hyper.noise_std_mm**2 * np.eye(len(rows))
    lower = np.linalg.cholesky(s)
    z = np.linalg.solve(lower, np.asarray(readings, float))
    return float(-0.5 * z @ z - np.log(np.diag(lower)).sum() - 0.5 * len(z) * np.log(2 * np.pi))


@lru_cache(maxsize=32)
def _objective(model: PriorModel):
    """Negative log posterior of log-theta, jit-compiled once per model (rows padded)."""
    ht = jnp.asarray(model.tilt_cov())
    mu = jnp.log(jnp.asarray(model.hyper0))
    sd = jnp.asarray(model.hyper_log_std)

    def neg_log_post(log_theta, rows, readings, mask):
        sf, ls, sn = jnp.exp(log_theta)
        cov = ht + model.form_cov(sf, ls, jnp) + JITTER_MM2 * jnp.eye(ht.shape[0])
        s = rows @ cov @ rows.T
        s = s + jnp.diag(mask * sn**2 + (1.0 - mask))  # padded rows: unit variance, zero data
        lower = jnp.linalg.cholesky(s)
        z = jax.scipy.linalg.solve_triangular(lower, readings * mask, lower=True)
        loglik = -0.5 * z @ z - jnp.sum(jnp.log(jnp.diag(lower))) \
            - 0.5 * jnp.sum(mask) * jnp.log(2 * jnp.pi)
        logprior = -0.5 * jnp.sum(((log_theta - mu) / sd) ** 2)
        return -(loglik + logprior)

    return jax.jit(jax.value_and_grad(neg_log_post))


def fit_hyper(model: PriorModel, rows: np.ndarray, readings: np.ndarray,
              start: Hyper | None = None) -> Hyper:
    """MAP-II hyper-parameters from the readings (L-BFGS-B on log theta, JAX gradients)."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError("fit_hyper needs float64: call adaptive_cal.use_float64() first")
    rows = np.asarray(rows, float)
    n = len(rows)
    size = max(16, int(np.ceil(n / 16) * 16))  # pad to a bucket: few recompilations
    padded = np.zeros((size, rows.shape[1]))
    padded[:n] = rows
    y = np.zeros(size)
    y[:n] = readings
    mask = np.zeros(size)
    mask[:n] = 1.0
    f = _objective(model)
    args = (jnp.asarray(padded), jnp.asarray(y), jnp.asarray(mask))

    def fun(x):
        v, g = f(jnp.asarray(x), *args)
        return float(v), np.asarray(g, float)

    h0 = model.hyper0
    x0 = np.log(np.asarray(start or h0, float))
    span = model.surface.sx.period + model.surface.sy.period
    bounds = [(np.log(1e-5), np.log(10.0)), (np.log(0.02 * span), np.log(5 * span)),
              (np.log(1e-5), np.log(1.0))]
    x0 = np.clip(x0, [b[0] for b in bounds], [b[1] for b in bounds])
    res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds)
    best = res.x if np.isfinite(res.fun) else x0
    return Hyper(*np.exp(best).tolist())
