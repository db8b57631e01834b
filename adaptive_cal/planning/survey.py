"""The survey state of one workplane and the pure functions that return it new.

A reading (mm) becomes the surface height y = reading - probe zero + z (DESIGN.md: reading =
surface - z + zero + noise). At a refit the belief is the posterior of every fused reading
mixed over the hyper-parameter points (moment-matched); between refits a reading is fused into
it under the last refit's noise (exact for one point; against the mixture an outside check put
the RMS std up to 10 % low at 10 readings, 2 % later). No files or hardware here. ``tell`` is
``judge`` (the gate: flags, changes nothing) then ``fuse`` (counts the touch, fuses a reading
the gate let through, refits on schedule); a loop writes the reading to the recording between.

>>> import adaptive_cal
>>> adaptive_cal.use_float64()
>>> from adaptive_cal.cell.build import survey_plan
>>> from adaptive_cal.cell.schema import load_cell
>>> from adaptive_cal.planning import survey
>>> from adaptive_cal.planning.ask import ask
>>> cell = load_cell("configs/sim-cell.yaml")
>>> plan = survey_plan(cell)                      # the cell file, read once
>>> state = survey.start(plan)
>>> target = ask(plan, state)[0]                  # where to touch, at which approach height
>>> reading = target.expected_reading_mm + 0.001  # a robot, an operator or a simulator reads
>>> state, told = survey.tell(plan, state, target.x_mm, target.y_mm, target.z_mm, reading)
>>> told.fused, state.touches, survey.stop_reason(plan, state)
(True, 1, None)
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from adaptive_cal.formats.recording import surface_height_mm
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import Hyper, learned_belief, require_float64
from adaptive_cal.planning.adequacy import Adequacy, assess
from adaptive_cal.planning.closure import Closure
from adaptive_cal.planning.gate import (FLAG_P, Retake, Told, flagged_weight, judge as gate_judge,
                                        pending_after)
from adaptive_cal.planning.robust import (W_MIN, InvalidReading, check_touch, settled,  # noqa: F401
                                          confirmed_against, loo_outlier_probability,
                                          predictive, replayed_weights)
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.gap import largest_gap
from adaptive_cal.planning import repeats
from adaptive_cal.planning.stopping import Status, near
from adaptive_cal.planning.unmask import unmasked


@dataclass(frozen=True, eq=False)
class SurveyState:
    """What a survey knows after its touches (immutable; the functions below return a new one).

    ``belief``: over the spline coefficients; ``hyper``: the hyper-parameters later fusions
    use (the MAP of the last refit); ``hyper_points``: the weighted hyper-parameter points the
    belief mixes (empty before the first refit); ``rows``/``heights_mm``: every fused reading
    (basis rows (n, K), heights (n,)); ``touches``: touches made, fused or not;
    ``touched_xy_mm``: where each touch went, in order; ``retake``: a gated reading that owes
    a second touch, or None; ``fitted_at``: fused readings at the last refit; ``prior``: a
    belief carried over from an earlier run (``--prior-from``), or None; ``weights``: each fused
    reading's share w = 1 - p of the noise precision (p its flagged outlier probability: its
    noise variance is r / w in every fusion and refit)."""

    belief: bl.Belief
    hyper: Hyper
    hyper_points: tuple = ()
    rows: np.ndarray | None = None
    heights_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    touches: int = 0
    touched_xy_mm: tuple[tuple[float, float], ...] = ()
    retake: Retake | None = None
    fitted_at: int = 0
    prior: bl.Belief | None = None
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    adequacy: Adequacy | None = None
    grown_mm2: np.ndarray | None = None
    closure: Closure | None = None  # the closure touch's verdict (``planning.closure``)

    @property
    def fused_weights(self) -> np.ndarray:
        """w_i of each fused reading (1 for readings fused without one, e.g. a state built by
        hand from rows and heights)."""
        w = np.ones(self.fused)
        w[:min(len(self.weights), self.fused)] = self.weights[:self.fused]
        return w

    @property
    def fused(self) -> int:
        """Number of fused readings."""
        return len(self.heights_mm)

    @property
    def noise_var(self) -> float:
        """r = noise_std^2 (mm^2) of the current hyper-parameters."""
        return self.hyper.noise_std_mm**2


def start(plan: SurveyPlan, *, prior: bl.Belief | None = None,
          hyper: Hyper | None = None) -> SurveyState:
    """The state before any touch: the prior belief under ``hyper`` (default: the model's first
    guess), or ``prior`` from an earlier run (``informed_prior=True``: nothing learned)."""
    if plan.learn:  # before any robot moves, not at the first refit some touches in
        require_float64("a survey that learns its hyper-parameters")
    hyper = hyper or plan.model.hyper0
    belief = prior if prior is not None else plan.model.belief(hyper)
    if belief.mean.shape[0] != plan.coefficients:
        raise ValueError(f"the earlier belief has {belief.mean.shape[0]} coefficients, this "
                         f"cell's spline has {plan.coefficients}: use the same knots")
    return SurveyState(belief, hyper, rows=np.zeros((0, plan.coefficients)), prior=prior)


def status(plan: SurveyPlan, state: SurveyState, cov: np.ndarray | None = None,
           touches: int | None = None, unresolved_mm2: np.ndarray | None = None) -> Status:
    """Touches, RMS std sqrt(trace(Q C) / area + mean s_u^2) and the largest std on the grid
    (mm) of the TRUE plate (s_u^2: the unresolved structure the checks found); ``adequate``:
    the checks pass (not before a learning survey's first); ``cov``/``touches``: what a batch
    planned ahead would reach, under the checks as they stand; ``unresolved_mm2``:
    ``unresolved_var_mm2`` on ``plan.eval_xy`` when at hand."""
    c = state.belief.cov if cov is None else cov
    var = np.einsum("nk,nk->n", plan.eval_rows @ c, plan.eval_rows)
    j_area = float(bl.integrated_variance(c, plan.gram)) / plan.model.surface.area_mm2
    u = (unresolved_var_mm2(plan, state, plan.eval_xy) if unresolved_mm2 is None
         else unresolved_mm2)
    adequate = state.adequacy.adequate if state.adequacy is not None else not learns(plan, state)
    gap = (largest_gap(plan.candidates.xy_mm, state.touched_xy_mm)[0]
           if plan.max_gap_mm is not None else 0.0)  # of the touches made, not a batch's picks
    return Status(state.touches if touches is None else touches,
                  float(np.sqrt(max(j_area, 0.0) + u.mean())),
                  float(np.sqrt(max((var + u).max(), 0.0))), adequate,
                  float(np.sqrt(u.mean())), gap, repeats.owed(plan, state))


def unresolved_var_mm2(plan: SurveyPlan, state: SurveyState, xy) -> np.ndarray:
    """s_u^2 (mm^2) at points ``xy`` (N, 2): variance of the plate the spline cannot represent
    (``planning.adequacy``: the form finer than the knots, the readings' excess where a check
    fails or the model grew), plus d^2 of a drift a failed closure touch found. Add it to the
    spline's variance for bands of the plate."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    drift = state.closure.drift_var_mm2 if state.closure is not None else 0.0
    if state.adequacy is None:
        return np.full(len(xy), drift)
    return state.adequacy.unresolved_var_mm2(xy[:, 0], xy[:, 1]) + drift


def check(plan: SurveyPlan, state: SurveyState, *, coarse: bool = False) -> Adequacy | None:
    """The model's self-checks on every fused reading (``planning.adequacy.assess``) under the
    current hyper-parameters (``coarse``: against the model before it grew), or None with
    fewer than 3 readings."""
    if state.fused < 3:
        return None
    extra = None if coarse else extra_cov(plan, state)
    prior = state.prior if state.prior is not None else plan.model.belief(state.hyper, extra)
    form = plan.model.form_surface if extra is None else plan.model.surface
    return assess(plan.model.surface, plan.plate_mm, state.rows, state.heights_mm, prior,
                  state.hyper, plan.noise_range_mm, plan.adequacy_regions, form_surface=form,
                  suspect=extra is not None, reach_mm=plan.bounds_mm,
                  weights=state.fused_weights, repeats=repeats.judged(plan, state))


def stop_reason(plan: SurveyPlan, state: SurveyState) -> str | None:
    """Why the survey's own stopping rule stops now (e.g. ``mean_std_bound``), or None."""
    return plan.stop(status(plan, state))


def _row(plan: SurveyPlan, x_mm: float, y_mm: float) -> np.ndarray:
    return plan.model.surface.basis(np.array([x_mm]), np.array([y_mm]))[0]


def judge(plan: SurveyPlan, state: SurveyState, x_mm: float, y_mm: float, z_mm: float,
          reading_mm: float) -> Told:
    """The gate's decision on a reading that was taken (flags for the recording); pure.

    Raises ``InvalidReading`` (a ValueError naming the value) for a NaN or infinite reading or
    position, a position off the workplane or inside a keep-out: such a reading is never fused
    (a loop records it flagged ``invalid`` and counts it with ``skip``). Before the first refit
    the reading is judged against the hyper-prior's mixture (``robust.predictive``)."""
    check_touch(plan, x_mm, y_mm, z_mm, reading_mm)
    x_mm, y_mm, z_mm, reading_mm = map(float, (x_mm, y_mm, z_mm, reading_mm))  # a Decimal too
    height = surface_height_mm(reading_mm, z_mm, plan.zero_mm)
    row = _row(plan, x_mm, y_mm)
    unlearned = learns(plan, state) and not state.hyper_points
    pred = predictive(plan, state.belief, state.hyper, state.rows, state.heights_mm,
                      state.fused_weights, row, unlearned)
    lo, hi = plan.usable_mm
    owed = state.retake if state.retake is not None and state.retake.at(x_mm, y_mm) else None
    return gate_judge(pred, height, state.noise_var, plan.gate_sigma, owed, x_mm, y_mm,
                      z_mm, stroke_mm=hi - lo)


def fuse(plan: SurveyPlan, state: SurveyState, told: Told) -> SurveyState:
    """The state after a judged reading: the touch counted, the retake owed (if any), and the
    reading fused when the gate let it through -- with a refit when the schedule says so."""
    gated = state.retake if state.retake and state.retake.at(told.x_mm, told.y_mm) else None
    state = replace(state, touches=state.touches + 1, retake=pending_after(told, state.retake),
                    touched_xy_mm=state.touched_xy_mm + ((told.x_mm, told.y_mm),))
    if not told.fused:
        return state
    h = _row(plan, told.x_mm, told.y_mm)
    state = replace(state, rows=np.vstack([state.rows, h[None]]),
                    heights_mm=np.append(state.heights_mm, told.height_mm),
                    weights=np.append(state.fused_weights, told.weight))
    w = (confirmed_against(plan, state.rows, state.heights_mm, state.fused_weights, gated)
         if "surprise" in told.flags and gated is not None and learns(plan, state)
         and not state.hyper_points else None)  # a map of few readings, not yet learned
    if w is not None:  # the map the gate judged by rested on a reading now judged wrong
        state = replace(state, weights=w)
    learning = learns(plan, state) and state.fused >= plan.hyper_after
    if learning and state.fused - state.fitted_at >= plan.hyper_every:
        return refit(plan, state)
    state = batch_posterior(plan, state) if w is not None else replace(state, belief=bl.fuse(
        state.belief, h, told.height_mm, state.noise_var / told.weight)[0])
    # a stop rests on checks of every fused reading, not on the last refit's (a bump a retake
    # confirmed between two refits read 1.1 um RMS std there, 11 um refitted); near a bound too
    if learning and near(plan.stop, status(plan, state)):
        return refit(plan, state)
    return carried_checked(plan, state)


def carried_checked(plan: SurveyPlan, state: SurveyState) -> SurveyState:
    """From an earlier belief nothing is learned, but it is checked on every reading (a re-check
    of a plate whose form changed stopped on the old bound, true error 21.8 um: an audit)."""
    return replace(state, adequacy=check(plan, state)) if state.prior is not None else state


def batch_posterior(plan: SurveyPlan, state: SurveyState) -> SurveyState:
    """Every fused reading at its weight again, under the current hyper-parameters (or the
    earlier run's belief): the batch posterior."""
    base = state.prior if state.prior is not None else plan.model.belief(
        state.hyper, extra_cov(plan, state))
    return replace(state, belief=bl.condition(base, state.rows, state.heights_mm,
                                              state.noise_var / state.fused_weights))


def tell(plan: SurveyPlan, state: SurveyState, x_mm: float, y_mm: float, z_mm: float,
         reading_mm: float) -> tuple[SurveyState, Told]:
    """``judge`` then ``fuse``: the new state and the judgement (flags for the recording).
    An invalid reading raises ``InvalidReading`` and changes nothing."""
    told = judge(plan, state, x_mm, y_mm, z_mm, reading_mm)
    return fuse(plan, state, told), told


def skip(plan: SurveyPlan, state: SurveyState, x_mm: float, y_mm: float) -> SurveyState:
    """Count a touch whose reading the probe cycle rejected (not fused; a retake owed stays)."""
    return replace(state, touches=state.touches + 1,
                   touched_xy_mm=state.touched_xy_mm + ((float(x_mm), float(y_mm)),))


def learns(plan: SurveyPlan, state: SurveyState) -> bool:
    """True when the hyper-parameters are refitted: the plan learns and no earlier belief
    (which already carries them) was given."""
    return plan.learn and state.prior is None


def extra_cov(plan: SurveyPlan, state: SurveyState) -> np.ndarray | None:
    """D U D: the grown model's prior covariance of structure finer than the coarse knots,
    U = ``plan.growth`` (unit amplitude on the fine knots), D = diag(amplitude of the region
    of each coefficient); None before the model grew."""
    if plan.growth is None or state.grown_mm2 is None or not state.grown_mm2.any():
        return None
    gx, gy = plan.model.surface.knot_grid()
    (x0, x1), (y0, y1) = plan.plate_mm
    rx, ry = plan.adequacy_regions
    i = np.clip(((gx - x0) / (x1 - x0) * rx).astype(int), 0, rx - 1)
    j = np.clip(((gy - y0) / (y1 - y0) * ry).astype(int), 0, ry - 1)
    d = np.sqrt(state.grown_mm2[i, j])
    return d[:, None] * plan.growth * d[None, :]


def refit(plan: SurveyPlan, state: SurveyState) -> SurveyState:
    """Re-fit the hyper-parameters to every fused reading and rebuild the belief: the
    posterior under each weighted hyper-parameter point, moment-matched (so the belief
    carries the hyper-parameter uncertainty); the MAP's noise serves later fusions. Then the
    self-checks (``check``). A plan that can grow (``plan.growth``) checks the coarse model
    first: where it is inadequate, the prior takes the unresolved variance found there as
    finer structure on the refined knots, and the belief is rebuilt from the fused readings
    (exact: the batch posterior under the grown prior); where it is adequate, that is 0."""
    def fitted(state):
        belief, points = learned_belief(plan.model, state.rows, state.heights_mm, start=state.hyper,
                                        weights=state.fused_weights, extra=extra_cov(plan, state))
        return replace(state, belief=belief, hyper=points[0][0], hyper_points=tuple(points),
                       fitted_at=state.fused)

    state = settled(fitted(state), lambda s: reweighed(plan, s),
                    lambda s, w: fitted(replace(s, weights=w)))  # gross errors weighted out
    if plan.growth is not None and state.prior is None and state.fused >= 3:
        coarse = check(plan, state, coarse=True)
        grown = np.zeros(plan.adequacy_regions) if coarse.adequate else \
            coarse.region_var_mm2 + coarse.form_var_mm2
        old = state.grown_mm2 if state.grown_mm2 is not None else np.zeros_like(grown)
        if not np.allclose(grown, old):
            state = fitted(replace(state, grown_mm2=grown))
    return replace(state, adequacy=check(plan, state))


def reweighed(plan: SurveyPlan, state: SurveyState) -> np.ndarray | None:
    """Each fused reading judged at a refit: p under its leave-one-out predictive (the learned
    noise), weight lowered to 1 - p where p >= ``FLAG_P``; one weighted out (w <= 0.5) takes
    1 - p or 1, raised: a genuine one condemned among the first (an audit: two beside a 0.2 mm
    error held at 0 to the end) is not lost; one still in is never raised (a noise it
    inflated can hide it). Where none changes, ``unmask``. None when none changes."""
    if state.fused < 3 or not learns(plan, state):
        return None
    w, r, stroke = state.fused_weights, state.hyper.noise_std_mm**2, np.ptp(plan.usable_mm)
    prior = plan.model.belief(state.hyper, extra_cov(plan, state))
    p = loo_outlier_probability(prior, state.rows, state.heights_mm, r / w, r, stroke)
    judged = np.where(p >= FLAG_P, np.maximum(1.0 - p, W_MIN), 1.0)  # 1 - p = 0: NaN
    new = np.where(w <= 0.5, judged, np.minimum(w, judged))
    return new if np.any(np.abs(new - w) > 1e-12) else unmasked(
        plan.model, prior, state.rows, state.heights_mm, w, state.hyper, extra_cov(plan, state),
        stroke)


def replay(plan: SurveyPlan, state: SurveyState, recording) -> SurveyState:
    """The state after a recording's touches, from a fresh ``state``: fused rows by their
    flags (and their outlier weights, ``outlier=p``), the touch count and positions, the
    hyper-parameters, a retake still owed."""
    rec, fused = recording, recording.fused
    if fused.any():
        rows = plan.model.surface.basis(rec.x_mm[fused], rec.y_mm[fused])
        heights = surface_height_mm(rec.reading_mm[fused], rec.z_mm[fused], plan.zero_mm)
        flags = [f for f, keep in zip(rec.flags, fused) if keep] if rec.flags else []
        weights = np.array([flagged_weight(f) for f in flags]) if flags else np.ones(len(rows))
        first_fit = max(plan.hyper_after, plan.hyper_every) if learns(plan, state) else 0
        weights = replayed_weights(plan, rec, fused, rows, heights, weights, first_fit)
        state = replace(state, rows=rows, heights_mm=heights, weights=weights)
        state = refit(plan, state) if learns(plan, state) and len(heights) >= plan.hyper_after \
            else carried_checked(plan, batch_posterior(plan, state))
    retake = None
    if len(rec) and rec.flags and "gated" in rec.flags[-1]:
        i = len(rec) - 1
        retake = Retake(rec.x_mm[i], rec.y_mm[i], rec.z_mm[i],
                        surface_height_mm(rec.reading_mm[i], rec.z_mm[i], plan.zero_mm))
    return replace(state, touches=len(rec), retake=retake,
                   touched_xy_mm=tuple(zip(rec.x_mm.tolist(), rec.y_mm.tolist())))


def grid(plan: SurveyPlan, belief: bl.Belief, n: int = 61, state: SurveyState | None = None,
         extra_var=None):
    """(gx, gy, mean, std): posterior mean and std (mm) on an n x n grid over the whole plate;
    with ``state`` the std includes its unresolved-structure variance (bands of the plate);
    ``extra_var(x, y)``: a variance added on top (confirmed local features)."""
    (x0, x1), (y0, y1) = plan.plate_mm
    gx, gy = np.linspace(x0, x1, n), np.linspace(y0, y1, n)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    rows = plan.model.surface.basis(xx.ravel(), yy.ravel())
    mean, var = bl.predict(belief, rows)
    if state is not None:
        var = var + unresolved_var_mm2(plan, state, np.stack([xx.ravel(), yy.ravel()], 1))
    if extra_var is not None:
        var = var + extra_var(xx.ravel(), yy.ravel())
    return gx, gy, mean.reshape(n, n), np.sqrt(var).reshape(n, n)
