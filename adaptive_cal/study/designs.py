"""Fixed designs (the paper's procedure, serpentine grids, uniform random touches) and the
estimators that turn a design's readings into a belief.

Every strategy is judged by the same spline model, so the comparison is between designs, not
estimators. With fixed hyper-parameters the covariance after a design does not depend on the
readings: the sequential posterior along a design is a ``lax.scan`` of the one-reading step
``belief.fuse_step``

    k = C h / (h^T C h + r),  m' = m + k (y - h^T m),  C' = C - k h^T C,

and a study runs it for all plates at once with ``jax.vmap``. ``evaluate_loop`` is the same
computation as a plain Python loop (the reference in tests and benchmarks).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.cell.schema import Cell
from adaptive_cal.gaussian.prior import Hyper, PriorModel
from adaptive_cal.gaussian.prior import learned_belief as posterior_with_learned_hyper
from adaptive_cal.study.config import Paper


# -- designs ----------------------------------------------------------------------------------
def _inner(cell: Cell):
    wp, m = cell.workplane, cell.workplane.edge_margin_mm
    return (wp.x_mm[0] + m, wp.x_mm[1] - m), (wp.y_mm[0] + m, wp.y_mm[1] - m)


def serpentine(xs, ys, cell: Cell) -> np.ndarray:
    """Points of the grid xs x ys row by row in y, alternating direction in x (S-shaped),
    without those the workplane does not allow (keep-outs)."""
    pts = []
    for j, y in enumerate(ys):
        for x in (xs if j % 2 == 0 else xs[::-1]):
            if cell.workplane.allows(x, y):
                pts.append((x, y))
    return np.asarray(pts, float).reshape(-1, 2)


def paper_points(cell: Cell, paper: Paper) -> tuple[np.ndarray, np.ndarray]:
    """The reference procedure's touches: 5 levelling points (centre, 4 corners of the path) and
    the nx x ny S-shaped path (x pitch = plate length / nx, as 45 mm on the 450 mm plate; y rows
    inset like the paper's -165 .. 165 mm on 370 mm)."""
    wp = cell.workplane
    (ix0, ix1), (iy0, iy1) = _inner(cell)
    lx, ly = wp.x_mm[1] - wp.x_mm[0], wp.y_mm[1] - wp.y_mm[0]
    dx = lx / paper.nx
    xs = np.clip(np.linspace(wp.x_mm[0] + dx / 2, wp.x_mm[1] - dx / 2, paper.nx), ix0, ix1)
    inset = ly * 20.0 / 370.0
    ys = np.clip(np.linspace(wp.y_mm[0] + inset, wp.y_mm[1] - inset, paper.ny), iy0, iy1)
    cx, cy = 0.5 * sum(wp.x_mm), 0.5 * sum(wp.y_mm)
    level = np.array([(cx, cy), (xs[0], ys[0]), (xs[-1], ys[0]), (xs[-1], ys[-1]),
                      (xs[0], ys[-1])])
    # those a keep-out covers are left out, as the path's are (an outside audit: the paper
    # strategy touched the centre under a keep-out); the plane needs three
    level = level[wp.allowed(level[:, 0], level[:, 1])]
    if len(level) < 3:
        raise ValueError(f"the reference procedure's levelling points: only {len(level)} of 5 "
                         "lie outside the keep-outs and inside the edge margin; a plane needs 3")
    return level, serpentine(xs, ys, cell)


def grid_sizes(cell: Cell, max_touches: int) -> list[tuple[int, int]]:
    """Grid shapes (nx, ny) of growing size with the plate's aspect ratio, up to max_touches."""
    (x0, x1), (y0, y1) = _inner(cell)
    aspect = (x1 - x0) / (y1 - y0)
    sizes = set()
    for ny in range(2, 64):
        for nx in {max(2, int(np.floor(ny * aspect))), max(2, int(np.ceil(ny * aspect)))}:
            if nx * ny <= max_touches:
                sizes.add((nx, ny))
    return sorted(sizes, key=lambda s: (s[0] * s[1], s))


def grid_points(cell: Cell, nx: int, ny: int) -> np.ndarray:
    (x0, x1), (y0, y1) = _inner(cell)
    return serpentine(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny), cell)


def random_points(cell: Cell, n: int, rng: np.random.Generator) -> np.ndarray:
    """n uniform random allowed points, in the order drawn."""
    (x0, x1), (y0, y1) = _inner(cell)
    out = []
    while len(out) < n:
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if cell.workplane.allows(x, y):
            out.append((x, y))
    return np.asarray(out, float)


def level_tilt_mm(xy: np.ndarray, heights: np.ndarray, span_mm: tuple[float, float]) -> float:
    """Height change across the plate of the least-squares plane's tilt (the paper's levelling
    check): |a| Lx + |b| Ly for the plane a x + b y + c fitted to the readings."""
    a = np.column_stack([xy[:, 0], xy[:, 1], np.ones(len(xy))])
    coef = np.linalg.lstsq(a, heights, rcond=None)[0]
    return float(abs(coef[0]) * span_mm[0] + abs(coef[1]) * span_mm[1])


# -- estimators -------------------------------------------------------------------------------
def learned_belief(model: PriorModel, rows, heights, start: Hyper) -> tuple[bl.Belief, Hyper]:
    """The adaptive planner's estimator (``prior.learned_belief``) and its MAP point."""
    belief, points = posterior_with_learned_hyper(model, rows, heights, start)
    return belief, points[0][0]


@dataclass(frozen=True)
class Evaluator:
    """The plate-wide figures of a belief on the survey plan's evaluation grid."""

    eval_rows: np.ndarray  # (E, K)
    gram: np.ndarray
    area_mm2: float

    def __call__(self, belief: bl.Belief, truth_eval: np.ndarray) -> dict:
        mean, var = bl.predict(belief, self.eval_rows)
        err = mean - truth_eval
        return {"mean_std_mm": float(bl.rms_std(belief.cov, self.gram, self.area_mm2)),
                "true_rms_mm": float(np.sqrt(np.mean(err**2))),
                "true_max_mm": float(np.abs(err).max()),
                "coverage95": float(np.mean(np.abs(err) <= bl.Z95 * np.sqrt(var)))}


# -- fixed hyper-parameters: vmap over plates --------------------------------------------------
def _figures(belief: bl.Belief, gram, eval_rows, truth_eval, area):
    """RMS posterior std, true RMS and true max error of a belief (traced by JAX)."""
    err = eval_rows @ belief.mean - truth_eval
    return (bl.rms_std(belief.cov, gram, area, jnp), jnp.sqrt(jnp.mean(err**2)),
            jnp.max(jnp.abs(err)))


def _trajectory(rows, heights, truth_eval, touches, prior_mean, prior_cov, gram, eval_rows,
                noise_var, area):
    """One plate: RMS posterior std, true RMS and max error after each touch; and all four
    figures (with the 95 % coverage) after the first ``touches`` touches."""
    on = (jnp.arange(rows.shape[0]) < touches).astype(rows.dtype)

    def step(belief, inp):
        row, reading, weight = inp
        belief = bl.fuse_step(belief, row, reading, noise_var, weight)
        return belief, _figures(belief, gram, eval_rows, truth_eval, area)

    prior = bl.Belief(prior_mean, prior_cov)
    _, per_touch = jax.lax.scan(step, prior, (rows, heights, jnp.ones(rows.shape[0], rows.dtype)))
    final, _ = jax.lax.scan(step, prior, (rows, heights, on))
    mean_std, true_rms, true_max = _figures(final, gram, eval_rows, truth_eval, area)
    mean, var = bl.predict(final, eval_rows, jnp)
    err = mean - truth_eval
    cover = jnp.mean((jnp.abs(err) <= bl.Z95 * jnp.sqrt(var)).astype(err.dtype))
    return per_touch, (mean_std, true_rms, true_max, cover)


@partial(jax.jit, static_argnames=("shared",))
def _vmapped(rows, heights, truth_eval, touches, prior_mean, prior_cov, gram, eval_rows,
             noise_var, area, shared):
    axes = (None if shared else 0, 0, 0, 0, None, None, None, None, None, None)
    return jax.vmap(_trajectory, in_axes=axes)(rows, heights, truth_eval, touches, prior_mean,
                                               prior_cov, gram, eval_rows, noise_var, area)


FIGURES = ("mean_std_mm", "true_rms_mm", "true_max_mm", "coverage95")


def evaluate_vmap(prior: bl.Belief, noise_var: float, ev: Evaluator, rows, heights, truth_eval,
                  touches):
    """All plates at once (jax.vmap over plates, lax.scan over touches). ``rows``: (n, K) shared
    by every plate or (P, n, K); heights (P, n); truth_eval (P, E); touches (P,): where to take
    the final figures. Returns (per_touch, final): per_touch = three (P, n) arrays (mean_std,
    true RMS, true max after each touch), final = dict of FIGURES -> (P,) after ``touches``."""
    rows = jnp.asarray(rows)
    per, fin = _vmapped(rows, jnp.asarray(heights), jnp.asarray(truth_eval),
                        jnp.asarray(touches), jnp.asarray(prior.mean), jnp.asarray(prior.cov),
                        jnp.asarray(ev.gram), jnp.asarray(ev.eval_rows), float(noise_var),
                        float(ev.area_mm2), shared=rows.ndim == 2)
    return tuple(np.asarray(a) for a in per), {k: np.asarray(v) for k, v in zip(FIGURES, fin)}


def evaluate_loop(prior: bl.Belief, noise_var: float, ev: Evaluator, rows, heights, truth_eval,
                  touches):
    """The same, one plate and one touch at a time in numpy (the reference)."""
    rows = np.asarray(rows, float)
    plates, n = np.shape(heights)
    per = np.zeros((3, plates, n))
    fin = {k: np.zeros(plates) for k in FIGURES}
    for p in range(plates):
        r = rows if rows.ndim == 2 else rows[p]
        belief = prior
        for t in range(n):
            belief = bl.condition(belief, r[t : t + 1], heights[p, t : t + 1], noise_var)
            err = ev.eval_rows @ belief.mean - truth_eval[p]
            per[:, p, t] = (bl.rms_std(belief.cov, ev.gram, ev.area_mm2),
                            np.sqrt(np.mean(err**2)), np.abs(err).max())
            if t + 1 == touches[p]:
                for k, v in ev(belief, truth_eval[p]).items():
                    fin[k][p] = v
        if touches[p] == 0:
            for k, v in ev(prior, truth_eval[p]).items():
                fin[k][p] = v
    return tuple(per), fin
