"""The strategies of a study on one plate, each returning a record (a JSON-able dict).

* ``adaptive`` / ``greedy_fixed`` (per plate): the engine's ask/tell loop on the simulated cell,
  through the probe cycle (stroke checks, gating, retakes), with and without hyper-parameter
  learning. The run goes on past its own stop until the true error also meets the target, so
  "touches to reach an accuracy" can be read off its trajectory.
* ``paper`` / ``grid`` / ``random``: fixed designs judged by the same model (``estimator``:
  learned like the planner, or fixed and vectorised over plates in ``batch.py``). Their
  readings are taken as if every touch landed inside the stroke (a levelled frame or a jogging
  operator), which favours them.

Robot time = straight xy travel from the plate centre through every touch at
robot.speed_mm_per_s + touch_time_s per touch (``planning.route.robot_time_s``, as result.json);
each record has the touches, robot time and travel at the strategy's own stop side by side.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.cell.schema import Cell
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import PriorModel
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.route import robot_time_s
from adaptive_cal.planning.stopping import Status
from adaptive_cal.run.devices import open_cell
from adaptive_cal.run.loop import CLOSING, NO_ADMISSIBLE_POINT, run_loop
from adaptive_cal.run.truth import state_truth_error
from adaptive_cal.study.config import Study
from adaptive_cal.study.designs import (Evaluator, grid_points, grid_sizes, level_tilt_mm,
                      paper_points, random_points)
from adaptive_cal.study.plates import Plate, heights_at, truth


@dataclass
class Context:
    """What every strategy needs to know about one plate."""

    study: Study
    plate: Plate
    cell: Cell
    model: PriorModel
    evaluator: Evaluator
    truth_eval: np.ndarray
    eval_xy: np.ndarray
    plan: SurveyPlan  # the cell's survey plan (the fixed designs' estimator, ``_Learner``)
    truth_mm: Callable  # the plate's true height (mm) at x, y (mm)

    @classmethod
    def create(cls, study: Study, plate: Plate, cell: Cell) -> "Context":
        plan = survey_plan(cell)
        ev = Evaluator(plan.eval_rows, plan.gram, plan.model.surface.area_mm2)
        truth_mm = truth(cell)
        t = truth_mm(plan.eval_xy[:, 0], plan.eval_xy[:, 1])
        return cls(study, plate, cell, plan.model, ev, t, plan.eval_xy, plan, truth_mm)

    def robot(self, xy) -> tuple[float, float]:
        """(robot time in s, travel in mm) of touching ``xy`` in order from the plate centre."""
        wp, robot = self.cell.workplane, self.cell.robot
        start = (0.5 * sum(wp.x_mm), 0.5 * sum(wp.y_mm))
        return robot_time_s(start, xy, robot.speed_mm_per_s, robot.touch_time_s)

    def robot_time_s(self, xy) -> float:
        return self.robot(xy)[0]


def record(ctx: Context, strategy: str, trajectory: list, stop: int, final: dict, xy,
           stop_reason: str, target_true: float, **extra) -> dict:
    """A strategy's result on one plate. ``trajectory``: [touches, mean_std_mm, true_rms_mm] at
    each point the strategy could stop; ``stop``: touches at its own stop; ``final``: the four
    figures there; ``xy``: every touch sent, in order.

    A stop on a variance bound pays the closure touch a run makes there (``plan.closure``,
    ``run.loop``): one touch more and the trip back to the first touch, in ``touches`` and the
    robot time (its reading, a repeat, is not in the figures: it adds little to the map).

    ``simulation``: the plate's simulation block (its drawn tilt and form, or its height map,
    the noise and the seed), so that the plate can be checked or run again with ``adaptive-cal
    run`` on the base cell with that block (an outside audit had to call internals for it)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    # a map no touch made reaches nothing: the prior's mean on a flat plate is no measurement
    # (an outside audit: a zero map credited adaptive with 0 touches)
    reached = [t for t, _, rms in trajectory if rms <= target_true and t > 0]
    true_touches = reached[0] if reached else None
    # a run makes no closure once the touch budget is spent (``run.loop``)
    closes = bool(ctx.plan.closure and stop_reason in CLOSING
                  and 0 < stop < ctx.study.bound.max_touches)
    paid = np.vstack([xy[:stop], xy[:1]]) if closes else xy[:stop]
    return {"strategy": strategy, "plate": ctx.plate.index, "seed": ctx.plate.seed,
            "noise_std_mm": ctx.plate.noise_std_mm, "touches": int(stop) + closes,
            "simulation": ctx.cell.simulation.model_dump(mode="json", exclude_defaults=True),
            "stop_reason": stop_reason, "robot_time_s": ctx.robot_time_s(paid),
            "travel_mm": ctx.robot(paid)[1], "closure": closes,
            **{k: float(final[k]) for k in ("mean_std_mm", "true_rms_mm", "true_max_mm",
                                             "coverage95")},
            "touches_true": true_touches,
            "robot_time_true_s": None if true_touches is None else ctx.robot_time_s(xy[:true_touches]),
            "trajectory": [[int(t), float(m), float(r)] for t, m, r in trajectory],
            "xy": np.round(xy[: max(stop, true_touches or 0)], 2).tolist(), **extra}


# -- the engine's loop --------------------------------------------------------------------------
class _PastTheStop:
    """The study's stop predicate for the loop: notes the survey's own stop (touches, reason,
    figures, hyper-parameters) and keeps going until the true RMS error is at most
    ``target_true`` too, or the touch budget is spent. Keeps the trajectory on the way."""

    def __init__(self, plan: SurveyPlan, truth_mm, budget: int, target_true: float):
        self.plan, self.truth, self.budget, self.target = plan, truth_mm, budget, target_true
        self.trajectory, self.stop, self.reason, self.final = [], None, None, None
        self.hyper, self.points = None, None

    def note(self, state: sv.SurveyState, status: Status, reason: str, err: dict) -> None:
        self.stop, self.reason = state.touches, reason
        self.hyper, self.points = list(state.hyper), _points(state)
        self.final = {"mean_std_mm": status.mean_std_mm, "true_rms_mm": err["rms_error_mm"],
                      "true_max_mm": err["max_error_mm"], "coverage95": err["coverage95"]}

    def __call__(self, state: sv.SurveyState, status: Status) -> str | None:
        err = state_truth_error(self.plan, state, self.truth)
        self.trajectory.append([state.touches, status.mean_std_mm, err["rms_error_mm"]])
        why = self.plan.stop(status)
        if self.stop is None and why:
            self.note(state, status, why, err)
        if self.stop is not None and err["rms_error_mm"] <= self.target:
            return "true_target"
        return "touch_budget" if state.touches >= self.budget else None


def run_planner(ctx: Context, *, learn: bool, target_true: float,
                run_to: float | None = None) -> dict:
    """The loop on the simulated cell until the cell's stop rule fires and the true RMS error is
    at most ``run_to`` (default ``target_true``; the budget spent ends it too). The record's
    touches to the true target count against ``target_true`` as every strategy's do: a stricter
    ``run_to`` (the paper's accuracy) only lengthens the trajectory."""
    data = ctx.cell.model_copy(update={"model": ctx.cell.model.model_copy(
        update={"learn_hyper": learn})})
    plan = survey_plan(data)
    opened = open_cell(data)
    watch = _PastTheStop(plan, opened.simulated.surface_mm, ctx.study.bound.max_touches,
                         target_true if run_to is None else min(target_true, run_to))
    try:
        state, _ = run_loop(plan, sv.start(plan), opened.cycle, stop=watch)
    finally:
        opened.close()
    if watch.stop is None:  # budget spent, or no admissible point: the last state is the stop
        status = sv.status(plan, state)
        err = state_truth_error(plan, state, watch.truth)
        watch.note(state, status, plan.stop(status) or NO_ADMISSIBLE_POINT, err)
    return record(ctx, "adaptive" if learn else "greedy_fixed", watch.trajectory, watch.stop,
                  watch.final, state.touched_xy_mm, watch.reason, target_true,
                  hyper=list(state.hyper), hyper_at_stop=watch.hyper,
                  hyper_points_at_stop=watch.points)


def _points(state: sv.SurveyState) -> list:
    """[[form_std_mm, length_scale_mm, noise_std_mm, weight, kernel], ...]: the hyper-parameter
    posterior the belief mixes (the point the belief rests on, weight 1, before any refit)."""
    points = state.hyper_points or [(state.hyper, 1.0)]
    return [[*map(float, h.theta), float(w), h.kernel] for h, w in points]


# -- fixed designs, learned estimator -------------------------------------------------------------
class _Learner:
    """Beliefs of growing designs under the planner's own estimator: its survey plan, the
    hyper-parameters learned (and carried from one checkpoint to the next), the self-checks,
    the model's growth and the unresolved structure in the stds -- only the design differs."""

    def __init__(self, ctx: Context):
        self.ctx, self.plan, self.truth = ctx, ctx.plan, ctx.truth_mm
        self.hyper = self.plan.model.hyper0

    def figures(self, xy, heights) -> dict:
        """The four figures of ``Evaluator`` (stds with the unresolved structure) and
        ``adequate``: the self-checks pass."""
        plan = self.plan
        state = sv.start(plan, hyper=self.hyper)
        rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
        state = replace(state, rows=rows, heights_mm=np.asarray(heights, float),
                        touches=len(xy))
        if sv.learns(plan, state) and len(xy) >= plan.hyper_after:
            state = sv.refit(plan, state)
            self.hyper = state.hyper
        else:
            state = replace(state, belief=bl.condition(state.belief, rows, state.heights_mm,
                                                       state.noise_var))
        status = sv.status(plan, state)
        err = state_truth_error(plan, state, self.truth)
        return {"mean_std_mm": status.mean_std_mm, "true_rms_mm": err["rms_error_mm"],
                "true_max_mm": err["max_error_mm"], "coverage95": err["coverage95"],
                "adequate": status.adequate}


def _sequence(ctx: Context, name: str, xy: np.ndarray, checkpoints: list[int],
              own_stop, target_true: float, reason_budget="touch_budget") -> dict:
    """Run a fixed touch sequence, judged at checkpoints; ``own_stop(n, figures, heights)`` says
    whether the strategy's own rule stops after n touches."""
    heights = heights_at(ctx.cell, xy)
    learner = _Learner(ctx)
    trajectory, stop, final, reason = [], None, None, None
    for n in checkpoints:
        fig = learner.figures(xy[:n], heights[:n])
        trajectory.append([n, fig["mean_std_mm"], fig["true_rms_mm"]])
        if stop is None:
            why = own_stop(n, fig, heights)
            if why:
                stop, final, reason = n, fig, why
        if stop is not None and fig["true_rms_mm"] <= target_true:
            break
    if stop is None:
        stop, final, reason = n, fig, reason_budget
    return record(ctx, name, trajectory, stop, final, xy, reason, target_true,
                  hyper=list(learner.hyper))


def paper_schedule(ctx: Context):
    """Touch sequence of the reference procedure up to the budget, and the round ends."""
    level, path = paper_points(ctx.cell, ctx.study.paper)
    budget = ctx.study.bound.max_touches
    rounds = max(1, (budget - len(level)) // len(path))
    xy = np.vstack([level] + [path] * rounds)
    ends = [len(level) + len(path) * (r + 1) for r in range(rounds)]
    return xy, ends, len(level), len(path)


def paper_stop(ctx: Context, n_level: int, n_path: int):
    """The paper's criterion: after each round the frame is levelled by the round's plane; stop
    when a round's least-squares plane tilts by at most level_tolerance_mm across the plate."""
    paper = ctx.study.paper
    wp = ctx.cell.workplane
    span = (wp.x_mm[1] - wp.x_mm[0], wp.y_mm[1] - wp.y_mm[0])

    def stop(n, fig, heights, xy):
        r = (n - n_level) // n_path
        if r < 1:
            return None
        lev = xy[:n_level]
        a = np.column_stack([lev, np.ones(n_level)])
        plane = np.linalg.lstsq(a, heights[:n_level], rcond=None)[0]
        for k in range(r):  # level by each round's plane in turn
            sl = slice(n_level + k * n_path, n_level + (k + 1) * n_path)
            pts = xy[sl]
            resid = heights[sl] - np.column_stack([pts, np.ones(len(pts))]) @ plane
            tilt = level_tilt_mm(pts, resid, span)
            if tilt <= paper.level_tolerance_mm:
                return "paper_level" if k == r - 1 else None
            plane = plane + np.linalg.lstsq(np.column_stack([pts, np.ones(len(pts))]), resid,
                                            rcond=None)[0]
        return "paper_rounds" if r >= paper.max_rounds else None

    return stop


def paper_native(ctx: Context, xy: np.ndarray, heights: np.ndarray, stop: int,
                 n_path: int) -> dict:
    """The paper's own map: the least-squares plane of the last round's readings (their
    eqs. 1-6) plus its residuals, linearly interpolated between the path points (the nearest
    residual outside them), against the truth on the evaluation grid."""
    from scipy.interpolate import griddata

    pts, h = xy[stop - n_path : stop], heights[stop - n_path : stop]
    design = np.column_stack([pts, np.ones(len(pts))])
    plane = np.linalg.lstsq(design, h, rcond=None)[0]
    resid = h - design @ plane
    est = griddata(pts, resid, ctx.eval_xy, method="linear")
    gap = ~np.isfinite(est)
    est[gap] = griddata(pts, resid, ctx.eval_xy[gap], method="nearest")
    est = est + np.column_stack([ctx.eval_xy, np.ones(len(ctx.eval_xy))]) @ plane
    err = est - ctx.truth_eval
    return {"native_true_rms_mm": float(np.sqrt(np.mean(err**2))),
            "native_true_max_mm": float(np.abs(err).max())}


def run_paper(ctx: Context, target_true: float) -> dict:
    xy, ends, n_level, n_path = paper_schedule(ctx)
    rule = paper_stop(ctx, n_level, n_path)
    rec = _sequence(ctx, "paper", xy, [n_level] + ends,
                    lambda n, fig, h: rule(n, fig, h, xy), target_true)
    if rec["touches"] > n_level:
        rec.update(paper_native(ctx, xy, heights_at(ctx.cell, xy), rec["touches"], n_path))
    return rec


def run_grid(ctx: Context, target_true: float) -> dict:
    """Serpentine grids of growing size, each a fresh run; stop at the first meeting the bound."""
    bound = ctx.study.bound
    learner = _Learner(ctx)
    trajectory, stop, final, best_xy, true_xy = [], None, None, None, None
    for nx, ny in grid_sizes(ctx.cell, bound.max_touches):
        xy = grid_points(ctx.cell, nx, ny)
        fig = learner.figures(xy, heights_at(ctx.cell, xy))
        trajectory.append([len(xy), fig["mean_std_mm"], fig["true_rms_mm"]])
        if stop is None and fig["mean_std_mm"] <= bound.mean_std_mm and fig["adequate"]:
            stop, final, best_xy = len(xy), fig, xy
        if fig["true_rms_mm"] <= target_true and true_xy is None:
            true_xy = xy
        if stop is not None and true_xy is not None:
            break
    reason = "mean_std_bound"
    if stop is None:
        stop, final, best_xy, reason = len(xy), fig, xy, "touch_budget"
    # robot time and travel by ``record``: the grid it stopped at (stop = len(best_xy)), and
    # its closure touch's trip back to that grid's first touch
    rec = record(ctx, "grid", trajectory, stop, final, best_xy, reason, target_true,
                 hyper=list(learner.hyper), grid=[nx, ny])
    if true_xy is not None:  # each grid is its own run: time the grid that met the target
        rec["robot_time_true_s"] = ctx.robot_time_s(true_xy)
    return rec


def run_random(ctx: Context, target_true: float) -> dict:
    bound = ctx.study.bound
    xy = random_points(ctx.cell, bound.max_touches, np.random.default_rng([ctx.plate.seed, 7]))
    plan = ctx.cell.plan
    checkpoints = list(range(plan.hyper_after, bound.max_touches + 1, plan.hyper_every))
    return _sequence(ctx, "random", xy, checkpoints,
                     lambda n, fig, h: "mean_std_bound" if fig["mean_std_mm"] <= bound.mean_std_mm
                     and fig["adequate"] else None, target_true)
