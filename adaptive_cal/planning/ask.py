"""Where to touch next: the best allowed candidate by the plan's criterion, inside the stroke and
the workspace, refined by gradient steps, or a batch planned ahead and ordered for travel.

A candidate is allowed when its reading lands inside the usable stroke with probability
>= 1 - 1e-6 (``scoring.stroke_ok``) and, with a workspace box, its approach height
z = mean - (lo + hi) / 2 + zero lies inside the box's z range. The criterion ``integrated``
takes the largest drop of J = trace(Q C); ``max`` the smallest largest variance after the reading.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.route import plan_batch, travel_order
from adaptive_cal.planning.scoring import minimax_choice, refine, stroke_ok, variance_drop
from adaptive_cal.planning.survey import SurveyState


@dataclass(frozen=True)
class Target:
    """A proposed touch: position and approach height (mm), what the reading should be."""

    x_mm: float
    y_mm: float
    z_mm: float
    expected_reading_mm: float
    predicted_std_mm: float  # posterior std of the surface there
    score_mm4: float  # drop of integrated variance J (mm^2 x mm^2)
    retake: bool = False


def ask(plan: SurveyPlan, state: SurveyState, n: int | None = None, *,
        from_xy=None) -> list[Target]:
    """The next touch(es): ``n`` (default ``plan.batch``) targets, a batch ordered for travel
    from ``from_xy``; the owed retake alone when one is pending. Empty when no allowed point
    can be promised inside the stroke."""
    n = n or plan.batch
    if state.retake is not None:
        x, y, z, _ = state.retake
        return [target(plan, state, x, y, z_mm=z, retake=True)]
    rows, cov, r = plan.candidates.rows, state.belief.cov, state.noise_var
    mean = rows @ state.belief.mean
    z_ok = np.ones(len(mean), bool)
    if plan.z_range_mm is not None:
        z = plan.approach_height(mean)
        z_ok = (z >= plan.z_range_mm[0]) & (z <= plan.z_range_mm[1])

    def pick(c):
        d, var = variance_drop(rows, c, plan.gram, r)
        ok = stroke_ok(var, r, plan.usable_mm) & z_ok
        if not ok.any():
            return -1
        if plan.criterion == "max":
            return minimax_choice(rows, c, r, ok)
        return int(np.argmax(np.where(ok, d, -np.inf)))

    if n == 1:
        i = pick(cov)
        if i < 0:
            return []
        xy = plan.candidates.xy_mm[i]
        if plan.criterion == "integrated" and plan.refine:
            d, var = variance_drop(rows, cov, plan.gram, r)
            d = np.where(stroke_ok(var, r, plan.usable_mm) & z_ok, d, -np.inf)
            top = np.argsort(-d)[: plan.refine]
            xy = _refined(plan, state, plan.candidates.xy_mm[top[np.isfinite(d[top])]])
        return [target(plan, state, *xy)]
    chosen = [i for i in plan_batch(pick, rows, cov, r, n) if i >= 0]
    if not chosen:
        return []
    pts = plan.candidates.xy_mm[chosen]
    begin = from_xy if from_xy is not None else pts[0]
    return [target(plan, state, *pts[i]) for i in travel_order(begin, pts)]


def _refined(plan: SurveyPlan, state: SurveyState, starts: np.ndarray) -> np.ndarray:
    """Gradient refinement of the best few candidates; the best refined point wins."""
    r, cov = state.noise_var, state.belief.cov

    def accept(x, y):
        h = plan.model.surface.basis(np.array([x]), np.array([y]))
        var = float(h[0] @ cov @ h[0])
        return plan.allows(x, y) and bool(stroke_ok(np.array([var]), r, plan.usable_mm)[0])

    results = [refine(plan.model.surface, xy, cov, plan.gram, r, list(plan.bounds_mm), accept)
               for xy in starts]
    return max(results, key=lambda res: res[1])[0]


def target(plan: SurveyPlan, state: SurveyState, x_mm, y_mm, *, z_mm=None,
           retake: bool = False) -> Target:
    """The touch at (x, y): approach height (mid-stroke unless ``z_mm`` is given), the expected
    reading, the posterior std there and the drop of J a reading there brings."""
    h = plan.model.surface.basis(np.array([x_mm]), np.array([y_mm]))[0]
    mean = float(h @ state.belief.mean)
    ch = state.belief.cov @ h
    var = float(h @ ch)
    z = plan.approach_height(mean) if z_mm is None else z_mm
    score = float(ch @ plan.gram @ ch / (var + state.noise_var))
    return Target(float(x_mm), float(y_mm), float(z), mean - z + plan.zero_mm,
                  float(np.sqrt(max(var, 0.0))), score, retake)
