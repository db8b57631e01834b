"""Gaussian prior over the spline coefficients, marginal likelihood and hyper-parameter fit.

Prior: a = a_tilt + a_form, independent Gaussians.

* tilt:  a_tilt = P (s_x, s_y, c), P = [x_k - x_c, y_k - y_c, 1] at the knots; slopes with
  std tan(tilt_std_deg), offset at the plate centre with std offset_std_mm. Splines reproduce a
  plane exactly, so the tilt is inside the model.
* form:  a_form ~ N(0, sigma_f^2 K_x kron K_y), K(u, v) = k(u - v) at the knots, k a squared
  exponential exp(-d^2 / (2 l^2)) or a Matern-5/2 (``kernels``): the kernel is a hyper-parameter.

Grown models (``embed``): the spline lives on refined knots and the form on the coarse ones,
a_form = E a_coarse, E = ``spline.embedding`` (exact), plus an extra covariance given by the
caller (structure finer than the coarse knots, per region, ``planning.survey``); with zero extra
the posterior equals the coarse model's.

Hyper-parameters theta = (sigma_f, l, sigma_n) are fitted by maximising the log marginal
likelihood of the readings, log N(y; H m0, H C0(theta) H^T + sigma_n^2 I), plus a weak
log-normal hyper-prior around the configured values (MAP-II), with JAX gradients, once per
kernel; the kernels are weighed by their evidence (Laplace) and the beliefs mixed.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from adaptive_cal.gaussian.belief import Belief, coefficient_form, condition, mixture
from adaptive_cal.gaussian.evidence import log_evidence, log_evidence_coefficients
from adaptive_cal.gaussian.kernels import KERNELS, knot_correlation
from adaptive_cal.gaussian.places import floor_penalty as _floor_penalty, pooled
from adaptive_cal.gaussian.spline import Surface

JITTER_MM2 = 1e-10


class Hyper(NamedTuple):
    """Form amplitude (mm), form length scale (mm), reading noise std (mm), and the form's
    correlation (``kernels.KERNELS``)."""

    form_std_mm: float
    length_scale_mm: float
    noise_std_mm: float
    kernel: str = "se"

    @property
    def theta(self) -> np.ndarray:
        """The three numbers (mm): form amplitude, length scale, noise."""
        return np.array(self[:3], float)


@dataclass(frozen=True, eq=False)  # hashed by identity: caches its compiled objective
class PriorModel:
    """What the prior needs besides the hyper-parameters."""

    surface: Surface
    slope_std: float  # mm/mm
    offset_std_mm: float
    centre_mm: tuple[float, float]
    hyper0: Hyper  # configured values: start of the fit and centre of the hyper-prior
    hyper_log_std: tuple[float, float, float] = (1.0, 0.7, 1.0)
    # the probe's stated noise span (lo, hi) mm: the noise prior is flat in log noise from its
    # middle to hi, with Gaussian shoulders of ``hyper_log_std[2]`` beyond (``_prior_box``);
    # None: log-normal about hyper0
    noise_span_mm: tuple[float, float] | None = None
    # the form kernels a learned belief weighs by their evidence (``learned_belief``)
    kernels: tuple[str, ...] = KERNELS
    embed: np.ndarray | None = None  # E (K x K_coarse): the form lives on coarser knots
    coarse: Surface | None = None  # the coarse spline E maps from

    @property
    def form_surface(self) -> Surface:
        """The spline whose knots carry the form (the coarse one of a grown model)."""
        return self.coarse if self.coarse is not None else self.surface

    def _embed(self) -> np.ndarray:
        return self.embed if self.embed is not None else np.eye(self.surface.size)

    @property
    def tilt_basis(self) -> np.ndarray:
        """P (K x 3): coefficients of the plane a (x - x_c) + b (y - y_c) + c."""
        gx, gy = self.surface.knot_grid()
        return np.stack([gx - self.centre_mm[0], gy - self.centre_mm[1], np.ones_like(gx)], 1)

    def tilt_cov(self) -> np.ndarray:
        var = np.array([self.slope_std**2, self.slope_std**2, self.offset_std_mm**2])
        p = self.tilt_basis
        return (p * var) @ p.T

    def form_cov(self, form_std_mm, length_scale_mm, xp=np, kernel: str = "se"):
        s = self.form_surface
        c = _form_cov(s.sx.knots[: s.sx.size], s.sy.knots[: s.sy.size], form_std_mm,
                      length_scale_mm, xp, kernel)
        return c if self.embed is None else self.embed @ c @ self.embed.T

    def belief(self, hyper: Hyper, extra: np.ndarray | None = None) -> Belief:
        """The prior belief N(0, C_tilt + C_form(theta) + extra)."""
        k = self.surface.size
        cov = self.tilt_cov() + self.form_cov(hyper.form_std_mm, hyper.length_scale_mm,
                                              kernel=hyper.kernel)
        if extra is not None:
            cov = cov + extra
        return Belief(np.zeros(k), cov + JITTER_MM2 * np.eye(k))


def _form_cov(knots_x, knots_y, form_std_mm, length_scale_mm, xp, kernel="se"):
    """sigma_f^2 K_x kron K_y at the knots (numpy, or traced by JAX in the objective)."""
    return form_std_mm**2 * xp.kron(knot_correlation(knots_x, length_scale_mm, kernel, xp),
                                    knot_correlation(knots_y, length_scale_mm, kernel, xp))


def log_marginal(model: PriorModel, hyper: Hyper, rows: np.ndarray, readings: np.ndarray) -> float:
    """log N(y; 0, H C0 H^T + sigma_n^2 I) -- the evidence of the readings under theta."""
    return float(log_evidence(np.asarray(rows, float), np.asarray(readings, float),
                              model.belief(hyper).cov, hyper.noise_std_mm**2))


def _neg_log_post(log_theta, rows, readings, mask, tilt_cov, knots_x, knots_y, lo, hi, sd,
                  embed, extra, weights=1.0, kernel="se"):
    """-(log N(y; 0, H C0(theta) H^T + sigma_n^2 W^-1) + log hyper-prior); padded rows masked.
    C0 = C_tilt + E C_form E^T + extra (E = I and extra = 0 unless the model grew).
    ``weights`` w_i in (0, 1]: a reading judged an outlier with probability p has w = 1 - p.
    The hyper-prior in log theta is flat on [lo, hi] with Gaussian shoulders of ``sd`` beyond
    (lo = hi: the log-normal about it)."""
    sf, ls, sn = jnp.exp(log_theta)
    cov = tilt_cov + embed @ _form_cov(knots_x, knots_y, sf, ls, jnp, kernel) @ embed.T + extra \
        + JITTER_MM2 * jnp.eye(tilt_cov.shape[0])
    # the coefficients' form for many (padded) readings: ``belief.coefficient_form``
    form = log_evidence_coefficients if coefficient_form(rows.shape) else log_evidence
    loglik = form(rows, readings, cov, sn**2 / weights, mask, jnp)
    beyond = jnp.maximum(lo - log_theta, 0.0) + jnp.maximum(log_theta - hi, 0.0)
    logprior = -0.5 * jnp.sum((beyond / sd) ** 2)
    return -(loglik + logprior)


@lru_cache(maxsize=None)
def _value_and_grad(kernel: str):
    """The objective and its gradient for one kernel, compiled once per array shape
    (coefficients, padded readings) and shared by every model."""
    return jax.jit(jax.value_and_grad(partial(_neg_log_post, kernel=kernel)))


def _model_args(model: PriorModel, extra=None) -> tuple:
    s = model.form_surface
    k = model.surface.size
    return (jnp.asarray(model.tilt_cov()), jnp.asarray(s.sx.knots[: s.sx.size]),
            jnp.asarray(s.sy.knots[: s.sy.size])) + _prior_box(model) + (
            jnp.asarray(model.hyper_log_std), jnp.asarray(model._embed()),
            jnp.asarray(extra if extra is not None else np.zeros((k, k))))


def _prior_box(model: PriorModel) -> tuple:
    """(lo, hi) in log theta where the hyper-prior is flat: the configured values (a point:
    log-normal about them); for the noise of a probe that states a span [a, b], from its
    middle sqrt(a b) up to b. A log-normal about the middle pulled a noise at the span's top
    halfway back (8 um of a 3-8 um span learned as 5.6-7.8 um at 25-36 touches: bands 1.2 x
    too narrow, coverage 0.87). Flat over the whole span let the noise fall to its bottom on
    a dozen readings where the form took part of it (3 um plates learned 2.6 um, stops at
    11-13 touches with 1.5-3 x the claimed error): a noise read too low makes the bands lie,
    one read too high costs touches, so below the middle the prior stays as it was."""
    lo = np.log(model.hyper0.theta)
    hi = lo.copy()
    if model.noise_span_mm is not None:
        a, b = model.noise_span_mm
        lo[2], hi[2] = np.log(np.sqrt(a * b)), np.log(b)
    return jnp.asarray(lo), jnp.asarray(hi)


def _padded(rows, readings):
    rows = np.asarray(rows, float)
    n = len(rows)
    size = max(16, 1 << int(np.ceil(np.log2(max(n, 1)))))  # power-of-two buckets: few compiles
    padded = np.zeros((size, rows.shape[1]))
    padded[:n] = rows
    y = np.zeros(size)
    y[:n] = readings
    mask = np.zeros(size)
    mask[:n] = 1.0
    return jnp.asarray(padded), jnp.asarray(y), jnp.asarray(mask)


def _padded_weights(size: int, weights=None):
    """Reading weights padded with 1 to the padded size (``weights`` None: all 1)."""
    w = np.ones(size)
    if weights is not None:
        w[:len(weights)] = weights
    return jnp.asarray(w)


def fit_hyper(model: PriorModel, rows: np.ndarray, readings: np.ndarray,
              start: Hyper | None = None, extra: np.ndarray | None = None) -> Hyper:
    """MAP-II hyper-parameters from the readings (L-BFGS-B on log theta, JAX gradients), for
    ``start``'s kernel (default the configured prior's)."""
    return hyper_posterior(model, rows, readings, start, points=False, extra=extra)[0][0]


def require_float64(what: str) -> None:
    """RuntimeError unless JAX runs in float64 (``adaptive_cal.use_float64``): the marginal
    likelihood's gradients are not reliable in float32."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError(f"{what} needs float64: call adaptive_cal.use_float64() first")


def hyper_posterior(model: PriorModel, rows: np.ndarray, readings: np.ndarray,
                    start: Hyper | None = None, *, points: bool = True, weights=None,
                    extra: np.ndarray | None = None, floor: tuple[float, int] | None = None,
                    kernel: str | None = None) -> list[tuple[Hyper, float]]:
    """Hyper-parameters with weights: the MAP, and with ``points`` also 2 x 3 sigma points of
    the Laplace approximation in log theta (at +-2 sd along each principal axis, unscented
    weights with kappa = 1, corrected by the true posterior density). Conditioning on each and
    mixing carries the hyper-parameter uncertainty into the belief. ``weights`` (n,), > 0:
    reading i has noise variance sigma_n^2 / w_i (outliers weighted out, a place read several
    times their sum: ``pooled``; default all 1). ``floor`` (ss, dof): the scatter of readings
    about their place's mean, which measures the probe alone (``learned_belief``). ``kernel``:
    the form's correlation (default ``start``'s, else the configured prior's)."""
    return _laplace(model, rows, readings, start, points, weights, extra, floor, kernel)[0]


def _laplace(model, rows, readings, start, points, weights, extra, floor, kernel):
    """``hyper_posterior``'s points and the log evidence of the kernel by Laplace's method,
    log p(y | kernel) ~ -f(x*) + d/2 log 2 pi - 1/2 log |H| (f the negative log posterior in
    log theta, x* its minimum, H its Hessian there; the hyper-prior's shoulders are not
    normalised, alike for every kernel). Where H is not positive definite (x* on a bound) its
    eigenvalues are floored at 1 (a width of one e-fold, the hyper-prior's own)."""
    require_float64("fit_hyper")
    kernel = kernel or (start or model.hyper0).kernel
    value_and_grad = _value_and_grad(kernel)
    padded = _padded(rows, readings)
    args = padded + _model_args(model, extra) + (_padded_weights(padded[2].shape[0], weights),)

    def fun(x):
        v, g = value_and_grad(np.asarray(x, np.float64), *args)  # numpy: jit's fast path
        v, g = float(v), np.array(g, float)
        if floor is not None:
            p, dp = _floor_penalty(x[2], *floor)
            v, g[2] = v + p, g[2] + dp
        return v, g

    x0 = np.log((start or model.hyper0).theta)
    span = model.surface.sx.period + model.surface.sy.period
    bounds = [(np.log(1e-5), np.log(10.0)), (np.log(0.02 * span), np.log(5 * span)),
              (np.log(1e-5), np.log(1.0))]
    lo, hi = np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds])
    x0 = np.clip(x0, lo, hi)
    res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds)
    best = res.x if np.isfinite(res.fun) else x0
    f0 = fun(best)[0]
    mapped = [(Hyper(*np.exp(best).tolist(), kernel=kernel), 1.0)]
    if not points:
        return mapped, -f0
    eps = 1e-4  # Hessian by central differences of the exact gradient (no extra compile)
    h = np.array([(fun(best + eps * e)[1] - fun(best - eps * e)[1]) / (2 * eps)
                  for e in np.eye(len(best))])
    n = len(best)
    if not np.all(np.isfinite(h)) or not np.isfinite(f0):
        return mapped, -f0 if np.isfinite(f0) else -np.inf
    w, v = np.linalg.eigh(0.5 * (h + h.T))
    logz = -f0 + 0.5 * n * np.log(2 * np.pi) - 0.5 * np.sum(np.log(np.maximum(w, 1.0)))
    if w.min() <= 0:
        return mapped, logz  # not a proper maximum (on a bound): keep the MAP alone
    kappa = 1.0
    nodes, wts = [best], [kappa / (n + kappa)]
    for i in range(n):
        step = np.sqrt(n + kappa) * v[:, i] / np.sqrt(w[i])
        for sign in (1.0, -1.0):
            nodes.append(np.clip(best + sign * step, lo, hi))
            wts.append(0.5 / (n + kappa))
    # density correction: true posterior over the Laplace approximation at each node
    logc = [-(fun(x)[0] - f0) + 0.5 * (x - best) @ h @ (x - best) for x in nodes]
    wts = np.asarray(wts) * np.exp(np.clip(np.asarray(logc) - max(logc), -30, 0))
    wts = wts / wts.sum()
    return [(Hyper(*np.exp(x).tolist(), kernel=kernel), float(wi))
            for x, wi in zip(nodes, wts)], logz


def kernel_weights(points) -> dict[str, float]:
    """Each kernel's share of weighted hyper-parameter points (``learned_belief``'s; none
    before the first refit)."""
    out: dict[str, float] = {}
    for h, w in points:
        out[h.kernel] = out.get(h.kernel, 0.0) + float(w)
    return out


#: Occam's window (Madigan & Raftery 1994): a kernel whose evidence is below 1/20 of the best
#: kernel's is left out of the belief's mixture. Kept at 3 % on the simulated cell's smooth bow
#: after 32 touches, a Matern-5/2 component of 0.5 mm amplitude left the saved map rough enough
#: between its touches that a re-check from it took 13 touches; with the window it takes 12
#: (10 with the squared exponential alone: the first map's touches differ). On the gentler
#: rough plates the window changed nothing measured (a 1/1000 window: the same runs)
OCCAM_RATIO = 20.0


def learned_belief(model: PriorModel, rows: np.ndarray, readings: np.ndarray,
                   start: Hyper | None = None, weights=None, extra: np.ndarray | None = None
                   ) -> tuple[Belief, list[tuple[Hyper, float]]]:
    """The belief with learned hyper-parameters: the posterior of the readings under each
    weighted point of ``hyper_posterior``, for each of ``model.kernels`` weighed by its
    evidence (Bayesian model averaging over the kernel, a_k the Laplace evidence normalised
    over the kernels within ``OCCAM_RATIO`` of the best), moment-matched into one Gaussian,

        m = sum_k a_k m_k,   C = sum_k a_k (C_k + (m_k - m)(m_k - m)^T),

    so the belief carries the hyper-parameter and kernel uncertainty. Returns it and the
    points, weights multiplied through (the MAP of the heaviest kernel first: its noise
    serves the fusions until the next refit, its form the self-checks). ``weights`` w_i:
    reading i's noise variance is sigma_n^2 / w_i in the fit and the posterior (robust:
    outliers out). ``extra``: a fixed covariance added to the prior (a grown model's finer
    structure). Each kernel's fit starts from ``start``'s numbers.

    The noise sigma_n is a nugget: the probe's noise plus the plate's structure finer than the
    spline, s^2 + p^2. Readings at one place (``places.places``: repeats, retakes, a place
    the planner picks again) differ by the probe alone, so fitted like the rest their scatter
    pulled sigma_n toward p and left the structure out of the bands; ignored, it let sigma_n
    fall below the probe's own noise where the form took part of a noisy probe's scatter (the
    study's in-family plates: runs stopped early with a true error above the bound). They enter
    as their weighted mean with the summed weight (``pooled``; for one basis row the pair is
    sufficient: the posterior is the same), and their scatter about it as a floor: the
    likelihood of the scatter, ss ~ p^2 chi2(dof), profiled over p <= sigma_n (s >= 0), is
    flat where sigma_n >= the scatter's own sd and falls off below (``places.floor_penalty``).
    A place's mean keeps noise sigma_n^2 / sum w: where the nugget holds structure, which its
    repeats do not average down, a place read many times is trusted a little too much."""
    rows, readings, w, floor = pooled(model.surface, rows, readings, weights)
    fits = [_laplace(model, rows, readings, start, True, w, extra, floor, k)
            for k in model.kernels]
    logz = np.array([z for _, z in fits])
    share = np.exp(logz - logz.max()) if np.isfinite(logz.max()) else np.ones(len(fits))
    share = np.where(share >= 1.0 / OCCAM_RATIO, share, 0.0)
    share = share / share.sum()
    order = [i for i in np.argsort(-share, kind="stable") if share[i] > 0]
    # each kernel's point weights sum to 1, the shares too: the product is normalised
    points = [(h, float(share[i] * wt)) for i in order for h, wt in fits[i][0]]
    belief = mixture([condition(model.belief(h, extra), rows, readings, h.noise_std_mm**2 / w)
                      for h, _ in points], [wt for _, wt in points])
    return belief, points


def log_evidence_kernel(model: PriorModel, rows: np.ndarray, readings: np.ndarray, start: Hyper,
                        weights=None, extra: np.ndarray | None = None) -> float:
    """log p(y | ``start``'s kernel): the hyper-parameters integrated by Laplace's method, the
    readings pooled by place, as ``learned_belief`` weighs its kernels."""
    rows, readings, w, floor = pooled(model.surface, rows, readings, weights)
    return float(_laplace(model, rows, readings, start, True, w, extra, floor, start.kernel)[1])
