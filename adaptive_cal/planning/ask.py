"""Where to touch next: the best allowed candidate by the plan's criterion, inside the stroke and
the workspace, refined by gradient steps, or a batch planned ahead and ordered for travel.

A candidate is allowed when its reading lands inside the usable stroke with probability
>= 1 - 1e-6 (``scoring.stroke_ok``) and, with a workspace box, its approach height
z = mean - (lo + hi) / 2 + zero lies inside the box's z range. The criterion ``integrated``
takes the largest drop of J = trace(Q C) per second of robot time (``plan.time_aware``: travel
at ``plan.speed_mm_per_s`` from where the probe is, plus ``plan.touch_time_s``), or the largest
drop alone; ``max`` the smallest largest variance after the reading.

A batch is the greedy set by the drop of J (the covariance after a reading does not depend on its
value), ended early where those picks would already stop the survey -- by the survey's own status
(``survey.status``), the unresolved variance the checks found included, as if they then pass (they
are judged again as the readings come): a status of the spline alone ended every batch after one
touch once the checks found structure (rough plates: the last 64 touches each a lone untimed pick,
100-380 mm apart) -- then ordered for travel from where the probe is. Asked for no count with
``plan.batch`` 1, a time-aware planner plans ``plan.lookahead`` touches ahead (at most twice the
touches made, so the hyper-parameters being learned rest on a third of the readings a batch ends
with) once the stroke no longer steers the choice (at least ``FREE`` of the candidates promised
inside it): the touches one at a time would take, in a shorter path. Where the bound is out of
reach (the unresolved variance alone misses it, ``out_of_reach``) and the rest of the touch
budget is at most twice the touches made, the batch is the rest of the budget
(``stopping.touches_left``): a plate the budget ends is finished in one tour.

Once the self-checks found structure finer than the knots (``kept_apart``), no touch is planned
within ``plan.min_spacing_mm`` of an earlier one (nor of another in its batch) while points
further away are allowed; on a plate too full for it the spacing is halved until one is
(``cell.build.min_spacing``: why, and what it changed).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from adaptive_cal.planning import repeats
from adaptive_cal.planning.gap import largest_gap
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.route import plan_batch, travel_order
from adaptive_cal.planning.scoring import (minimax_choice, rate_choice, refine, stroke_ok,
                                           touch_time_s, variance_drop)
from adaptive_cal.planning.stopping import touches_left, waits_for_repeats
from adaptive_cal.planning.survey import SurveyState, status, unresolved_var_mm2


#: share of the candidates promised inside the stroke from which the planner plans ahead
FREE = 0.95


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
    if state.retake is not None:
        x, y, z, _ = state.retake
        return [target(plan, state, x, y, z_mm=z, retake=True)]
    now = status(plan, state) if repeats.suspected(plan, state) else None
    if now is not None and waits_for_repeats(plan.stop, now):
        # the bound waits for the probe's own noise (``planning.repeats``): the last place
        # again while it holds fewer than PER_PLACE repeats, else one touch the criterion picks
        p = repeats.place(plan, state)
        if p is not None:
            return [target(plan, state, *p)]
        n = 1
    rows, cov, r = plan.candidates.rows, state.belief.cov, state.noise_var
    xy = plan.candidates.xy_mm
    here = None if from_xy is None else np.asarray(from_xy, float)[:2]
    if here is None or not np.all(np.isfinite(here)):  # an adapter that cannot read its position
        here = plan.here_xy_mm(state.touched_xy_mm)
    timed = plan.time_aware and plan.criterion == "integrated"
    mean = rows @ state.belief.mean
    z_ok = plan.z_allowed(plan.approach_height(mean))

    d0, var0 = variance_drop(rows, cov, plan.gram, r)
    # approach heights come from the belief now, so every touch of a batch must be promised
    # inside the stroke under it (variance only falls with readings: then also after them)
    ok = stroke_ok(var0, r, plan.usable_mm) & z_ok
    free = ok.mean()  # the share the stroke and the workspace allow (spacing aside)
    spacing = kept_apart(plan, state)  # halved while no allowed point keeps it (a full plate)
    while spacing > 0:
        spaced = ok & apart(xy, state.touched_xy_mm, spacing)
        if spaced.any():
            ok = spaced
            break
        spacing = spacing / 2 if spacing > 1.0 else 0.0

    fill = gap_fill(plan, state, xy, ok, here)
    if fill is not None:
        return [target(plan, state, *p) for p in fill]

    def pick(c, timed_here=False):
        d = d0 if c is cov else variance_drop(rows, c, plan.gram, r)[0]
        if not ok.any():
            return -1
        if plan.criterion == "max":
            return minimax_choice(rows, c, r, ok)
        if timed_here:
            return rate_choice(d, ok, xy, here, plan.speed_mm_per_s, plan.touch_time_s)
        return int(np.argmax(np.where(ok, d, -np.inf)))

    def per_second(p_xy, drop):
        """The objective at points (N, 2): dJ per second of robot time, or dJ."""
        if not timed:
            return drop
        t = touch_time_s(np.reshape(p_xy, (-1, 2)), here, plan.speed_mm_per_s, plan.touch_time_s)
        return drop / np.maximum(t, 1e-9)

    u = None  # unresolved variance on plan.eval_xy: the state's, computed once where needed
    if n is None and plan.batch == 1 and timed and plan.lookahead > 1 and free >= FREE:
        # the stroke no longer steers the choice: plan ahead and order for travel, at most twice
        # the touches made (batches swept in travel order from the start left the
        # hyper-parameters learned from one side of the plate)
        n = max(1, min(plan.lookahead, 2 * state.touches))
        left = touches_left(plan.stop, state.touches)
        if left is not None and n < left <= 2 * state.touches:
            u = unresolved_var_mm2(plan, state, plan.eval_xy)  # the batch's cut uses it too
            if out_of_reach(plan, state, left, u):
                # the budget ends this plate: the rest of it in one tour (rough plates ran to it
                # in two tours of 64 and 57 spread over the plate, 44-47 mm a step; one of 121
                # steps about 33 mm: 10 s of 675 s a plate). Not while the bound is in reach: a
                # long batch planned under early hyper-parameters and taken in travel order
                # meets it later than batches planned again (4 of 40 study plates: 4-32 more)
                n = left
    n = n or plan.batch
    if n == 1:
        i = pick(cov, timed)
        if i < 0:
            return []
        p = xy[i]
        if plan.criterion == "integrated" and plan.refine:
            score = np.where(ok, per_second(xy, d0), -np.inf)
            top = np.argsort(-score)[: plan.refine]
            p = _refined(plan, state, xy[top[np.isfinite(score[top])]], per_second, spacing)
        return [target(plan, state, *p)]
    # a batch: the greedy set by the drop of J (the touches the one-at-a-time rule would take
    # while the hyper-parameters stay), then ordered for travel from where the probe is
    def pick_apart(c):  # a batch's touches keep their spacing among themselves too
        i = pick(c)
        if i >= 0 and spacing > 0:
            far = apart(xy, [xy[i]], spacing)
            if (ok & far).any():
                ok[:] = ok & far
        return i

    if u is None:  # the state's, the same for every pick
        u = unresolved_var_mm2(plan, state, plan.eval_xy)

    def enough(c, k):  # the picks so far would meet the bound, the unresolved variance in
        # (the checks are judged again as the readings come, and the loop's stop sees them; cut
        # only where they pass, a batch planned while one fails ran its whole length in travel
        # order, where the greedy order would have met the bound touches sooner)
        now = status(plan, state, c, state.touches + k, unresolved_mm2=u)
        return bool(plan.stop(replace(now, adequate=True, repeats_owed=0)))

    chosen = plan_batch(pick_apart, rows, cov, r, n, enough=enough)
    if not chosen:
        return []
    pts = xy[chosen]
    return [target(plan, state, *pts[i]) for i in travel_order(here, pts)]


def gap_fill(plan: SurveyPlan, state: SurveyState, xy, ok, here) -> np.ndarray | None:
    """Where only ``plan.max_gap_mm`` holds the stop back (the variance bounds met): the allowed
    points that close the gaps, farthest point first (each the allowed candidate farthest from
    every touch and earlier pick, until none is farther than the radius or the budget ends),
    ordered for travel from ``here``; None otherwise (the variance still decides)."""
    if plan.max_gap_mm is None:
        return None
    now = status(plan, state)
    if now.gap_mm <= plan.max_gap_mm or not plan.stop(replace(now, gap_mm=0.0)):
        return None
    left = touches_left(plan.stop, state.touches)
    cand = xy[ok]
    picks: list[np.ndarray] = []
    touched = np.asarray(state.touched_xy_mm, float).reshape(-1, 2)
    while left is None or len(picks) < left:
        radius, i = largest_gap(cand, np.vstack([touched, *picks]) if picks else touched)
        if i < 0 or radius <= plan.max_gap_mm:
            break
        picks.append(cand[i][None, :])
    if not picks:
        return None  # no allowed point is farther: the rest lies where the stroke forbids
    pts = np.vstack(picks)
    return pts[travel_order(here, pts)]


def out_of_reach(plan: SurveyPlan, state: SurveyState, left: int | None = None,
                 unresolved_mm2: np.ndarray | None = None) -> bool:
    """The stop's bound cannot be met before the touch budget, however many touches the spline
    gets: the unresolved variance the checks found (which touches do not shrink) alone misses
    it -- the status of a spline known exactly, one touch before the budget. ``left``
    (``stopping.touches_left``) and ``unresolved_mm2`` (``survey.status``) when at hand."""
    left = touches_left(plan.stop, state.touches) if left is None else left
    if not left:
        return False
    exact = status(plan, state, np.zeros_like(state.belief.cov), state.touches + left - 1,
                   unresolved_mm2=unresolved_mm2)
    return not plan.stop(replace(exact, adequate=True, repeats_owed=0))


def kept_apart(plan: SurveyPlan, state: SurveyState) -> float:
    """The spacing (mm) touches keep now: ``plan.min_spacing_mm`` once the self-checks found
    structure finer than the knots (the model grew, or it is inadequate), else 0 -- until
    then the learned noise is taken for the probe's, and touches side by side average it."""
    grown = state.grown_mm2 is not None and bool(np.any(state.grown_mm2 > 0))
    inadequate = state.adequacy is not None and not state.adequacy.adequate
    return plan.min_spacing_mm if grown or inadequate else 0.0


def apart(xy: np.ndarray, touched_xy, spacing_mm: float) -> np.ndarray:
    """Mask of the points ``xy`` (N, 2) at least ``spacing_mm`` from every touched point."""
    if spacing_mm <= 0 or not len(touched_xy):
        return np.ones(len(xy), bool)
    t = np.asarray(touched_xy, float).reshape(-1, 2)
    if len(t) <= 8:  # a batch's pick, the first touches: direct
        d2 = ((xy[:, None, :] - t[None]) ** 2).sum(-1).min(1)
        return d2 >= spacing_mm**2
    from scipy.spatial import cKDTree

    return cKDTree(t).query(xy)[0] >= spacing_mm


def _refined(plan: SurveyPlan, state: SurveyState, starts: np.ndarray, value,
             spacing: float = 0.0) -> np.ndarray:
    """Gradient refinement (of dJ) of the best few candidates, kept ``spacing`` from every
    touch; the refined point of largest ``value(xy, dJ)`` (the plan's objective) wins."""
    r, cov = state.noise_var, state.belief.cov

    def accept(x, y):
        if not apart(np.array([[x, y]]), state.touched_xy_mm, spacing)[0]:
            return False
        h = plan.model.surface.basis(np.array([x]), np.array([y]))
        var = float(h[0] @ cov @ h[0])
        if not plan.z_allowed(plan.approach_height(float(h[0] @ state.belief.mean))):
            return False  # its approach height inside the box, as a candidate's
        return plan.allows(x, y) and bool(stroke_ok(np.array([var]), r, plan.usable_mm)[0])

    results = [refine(plan.model.surface, xy, cov, plan.gram, r, list(plan.bounds_mm), accept)
               for xy in starts]
    return max(results, key=lambda res: float(np.ravel(value(res[0], res[1]))[0]))[0]


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
