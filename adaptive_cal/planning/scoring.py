"""Scoring touches: closed-form drop of integrated variance, refinement, the stroke constraint.

One reading at p (row h = m(p), noise variance r) reduces J(C) = trace(Q C) by

    dJ(p) = (C h)^T Q (C h) / (h^T C h + r) = h^T W h / (h^T C h + r),   W = C Q C,

so scoring N candidates is one (N x K)(K x 2K) product against [W | C] (jit-compiled).
A reading at p lands inside the usable stroke [lo, hi] with probability >= 1 - 1e-6 when the
approach height puts its expected value mid-stroke and z* sqrt(h^T C h + r) <= (hi - lo) / 2,
z* = Phi^-1(1 - 0.5e-6); other points wait until the belief allows them.

Robot time prices a touch: t(p) = t_touch + |p - p_here| / v (straight travel at speed v from
where the probe is, then the touch). The time-aware choice maximises the drop per second,
dJ(p) / t(p), over the allowed candidates (``rate_choice``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize
from scipy import special  # ndtri: scipy.stats.norm.isf, without loading scipy.stats

from adaptive_cal.gaussian.spline import Spline1D, Surface

STROKE_Z = float(-special.ndtri(0.5e-6))  # two-sided 1e-6


@dataclass(frozen=True)
class Candidates:
    """Points a touch may go to (mm) and their basis rows."""

    xy_mm: np.ndarray  # (N, 2)
    rows: np.ndarray  # (N, K)


def candidate_grid(surface: Surface, allows: Callable[[float, float], bool],
                   x_range_mm, y_range_mm, count: int) -> Candidates:
    """About ``count`` grid points over [x_range] x [y_range] that ``allows`` accepts."""
    (x0, x1), (y0, y1) = x_range_mm, y_range_mm
    aspect = (x1 - x0) / (y1 - y0)
    nx = max(2, int(round(np.sqrt(count * aspect))))
    ny = max(2, int(round(count / nx)))
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny), indexing="ij")
    xy = np.stack([gx.ravel(), gy.ravel()], 1)
    keep = np.array([allows(x, y) for x, y in xy])
    if not keep.any():
        raise ValueError("no candidate point is allowed: check workplane margin and keep_outs")
    xy = xy[keep]
    return Candidates(xy, surface.basis(xy[:, 0], xy[:, 1]))


@jax.jit
def _scores(rows, cov, gram, noise_var):
    k = cov.shape[0]
    w = cov @ gram @ cov
    m = rows @ jnp.concatenate([w, cov], axis=1)
    num = jnp.sum(m[:, :k] * rows, axis=1)
    var = jnp.sum(m[:, k:] * rows, axis=1)
    return num / (var + noise_var), var


def variance_drop(rows, cov, gram, noise_var) -> tuple[np.ndarray, np.ndarray]:
    """dJ for every row and the posterior variance h^T C h at it (jit-compiled JAX)."""
    d, v = _scores(jnp.asarray(rows), jnp.asarray(cov), jnp.asarray(gram), noise_var)
    return np.asarray(d), np.maximum(np.asarray(v), 0.0)


def variance_drop_numpy(rows, cov, gram, noise_var) -> np.ndarray:
    """The same formula in plain numpy (reference for tests and benchmarks)."""
    hc = rows @ cov
    return np.einsum("nk,nk->n", hc @ gram, hc) / (np.einsum("nk,nk->n", hc, rows) + noise_var)


def stroke_ok(variance_mm2: np.ndarray, noise_var: float, usable_mm: tuple[float, float]) -> np.ndarray:
    """True where the reading lands inside the usable stroke with probability >= 1 - 1e-6."""
    half = 0.5 * (usable_mm[1] - usable_mm[0])
    return STROKE_Z * np.sqrt(variance_mm2 + noise_var) <= half


def touch_time_s(xy_mm: np.ndarray, here_xy_mm, speed_mm_per_s: float,
                 touch_time_s: float) -> np.ndarray:
    """Robot time (s) of a touch at each point from ``here_xy_mm``: straight travel at
    ``speed_mm_per_s`` plus ``touch_time_s``."""
    d = np.hypot(*(np.asarray(xy_mm, float) - np.asarray(here_xy_mm, float)).T)
    return touch_time_s + d / speed_mm_per_s


def rate_choice(drop_mm4: np.ndarray, allowed: np.ndarray, xy_mm: np.ndarray, here_xy_mm,
                speed_mm_per_s: float, touch_s: float) -> int:
    """Index of the allowed candidate of largest drop of J per second of robot time,
    dJ / (touch_s + distance / speed); -1 when none is allowed. With ``touch_s`` 0 a
    candidate at the probe's own position is priced at a tiny positive time."""
    if not allowed.any():
        return -1
    t = np.maximum(touch_time_s(xy_mm, here_xy_mm, speed_mm_per_s, touch_s), 1e-9)
    return int(np.argmax(np.where(allowed, drop_mm4 / t, -np.inf)))


def _point_score(surface: Surface):
    """The jitted value and gradient of dJ at one point, one per knot layout: a Surface compares
    by identity and every plan builds its own, so a cache keyed on the object compiled again
    for each run (1.3-1.6 s a run on the 2-core machine, hundreds of runs in the test suite)."""
    return _point_score_for(surface.sx.knots.tobytes(), surface.sx.ends,
                            surface.sy.knots.tobytes(), surface.sy.ends)


@lru_cache(maxsize=8)
def _point_score_for(kx: bytes, ex: str, ky: bytes, ey: str):
    surface = Surface(Spline1D.create(np.frombuffer(kx), ex),
                      Spline1D.create(np.frombuffer(ky), ey))

    def score(xy, cov, gram, noise_var):
        h = surface.basis(xy[0], xy[1], jnp)
        ch = cov @ h
        return (ch @ gram @ ch) / (h @ ch + noise_var)

    return jax.jit(jax.value_and_grad(score))


def refine(surface: Surface, start_xy: np.ndarray, cov, gram, noise_var, bounds,
           accept: Callable[[float, float], bool]) -> tuple[np.ndarray, float]:
    """Gradient refinement (L-BFGS-B inside ``bounds``) of dJ from a start point; the result is
    kept only if ``accept`` allows it, else the start point is returned."""
    f = _point_score(surface)
    cov_j, gram_j = jnp.asarray(cov), jnp.asarray(gram)

    def fun(p):
        v, g = f(np.asarray(p, np.float64), cov_j, gram_j, noise_var)
        return -float(v), -np.asarray(g, float)

    start_val = -fun(start_xy)[0]
    res = minimize(fun, np.asarray(start_xy, float), jac=True, method="L-BFGS-B", bounds=bounds,
                   options={"maxiter": 20})
    if np.isfinite(res.fun) and -res.fun > start_val and accept(*res.x):
        return res.x, float(-res.fun)
    return np.asarray(start_xy, float), start_val


def minimax_choice(rows, cov, noise_var, allowed: np.ndarray, *, top: int = 256,
                   watch: int = 1024) -> int:
    """Index of the candidate whose reading most lowers the largest posterior variance.

    Candidates: the ``top`` allowed rows of largest variance; the maximum is taken over the
    ``watch`` rows of largest variance (where the maximum can be after one reading)."""
    hc = rows @ cov
    var = np.einsum("nk,nk->n", hc, rows)
    order = np.argsort(-var)
    cand = [i for i in order if allowed[i]][:top]
    watch_idx = order[:watch]
    cross = hc[cand] @ rows[watch_idx].T  # (c, w): h_c^T C h_w
    after = var[watch_idx][None, :] - cross**2 / (var[cand][:, None] + noise_var)
    return int(cand[int(np.argmin(after.max(axis=1)))])
