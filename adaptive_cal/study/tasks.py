"""The units of work of a study, each run in-process or in a Dask worker: every per-plate
strategy on one plate (``plate_task``), one fixed design on many plates (``fixed_batch_task``).

Tasks take plain data (the study as JSON, the base cell as a mapping) so they pickle to any
worker. They set no global state: a worker needs JAX float64 on, which the caller arranges
(``run_study(..., worker_setup=...)``; the CLI passes its own); a task refuses to run without it.
"""
from __future__ import annotations

from typing import Callable

import jax

from adaptive_cal.gaussian.prior import Hyper
from adaptive_cal.study.bound import (best_integer_touches, design_problem, greedy_touches,
                                      integer_touches, marginal_problem, relaxed_touches)
from adaptive_cal.study.checkpoint import code_fingerprint
from adaptive_cal.study.config import Study
from adaptive_cal.study.plates import plate_cell, sample_plate


def require_float64() -> None:
    """Refuse to run a study in float32 (a worker whose caller did not turn on x64)."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError("study tasks need float64: call adaptive_cal.use_float64() first; "
                           "for Dask workers pass run_study(..., worker_setup=use_float64)")


def in_worker(setup: Callable[[], None] | None, task: Callable, *args) -> list[dict]:
    """Run ``setup`` (the caller's worker initialiser, e.g. ``use_float64``) then ``task``."""
    if setup is not None:
        setup()
    return task(*args)


def lower_bounds(study: Study, cell, model, rec: dict) -> dict:
    """The lower bounds on touches for an adaptive record: relaxed (real and whole touches),
    best integer design, greedy design with known hyper-parameters, and the whole-touch bounds
    under the hyper-parameters and the hyper-parameter posterior the planner held at its stop."""
    lb = study.lower_bound

    def problem(hyper):
        return design_problem(cell, model, Hyper(*hyper), candidates=lb.candidates)

    prob = problem(rec["hyper"])
    budget = study.bound.max_touches
    j = prob.area_mm2 * study.bound.mean_std_mm**2
    out = {"relaxed_touches": relaxed_touches(prob, j, budget)}
    out["relaxed_whole_touches"] = integer_touches(prob, j, budget,
                                                   relaxed=out["relaxed_touches"])
    out["best_integer_touches"] = best_integer_touches(prob, j, budget, lb.exhaustive_limit)
    out["greedy_known_touches"] = greedy_touches(prob, j, budget)
    # the same bound under what the planner believed when it stopped (the run goes on past its
    # stop until the true error meets the target, and refits on the way)
    if rec["hyper_at_stop"] == rec["hyper"]:
        out["relaxed_whole_touches_at_stop"] = out["relaxed_whole_touches"]
    else:
        out["relaxed_whole_touches_at_stop"] = integer_touches(problem(rec["hyper_at_stop"]), j,
                                                               budget)
    # and for the question the planner's stop answers: its belief mixes the posteriors under
    # the weighted hyper-parameter points of its last refit
    points = [(Hyper(*p[:3], *p[4:5]), p[3]) for p in rec["hyper_points_at_stop"]]
    out["marginal_whole_touches_at_stop"] = integer_touches(
        marginal_problem(cell, model, points, candidates=lb.candidates), j, budget)
    return out


def plate_task(study_data: dict, base: dict, index: int, todo: tuple[str, ...],
               report: Callable[[dict], None] | None = None) -> list[dict]:
    """Every per-plate strategy of ``todo`` on plate ``index``. ``report``: called with each
    record as it is made (progress in-process; a Dask task reports when it returns)."""
    require_float64()
    from adaptive_cal.study.strategies import Context, run_grid, run_paper, run_planner, run_random

    study = Study.model_validate(study_data)
    plate = sample_plate(study, index)
    cell = plate_cell(study, base, plate)
    ctx = Context.create(study, plate, cell)
    target = study.bound.true_mm
    # each record names the code that made it and the height map that was its plate
    extra = {"code": code_fingerprint()}
    if plate.surface_file:
        extra["surface_file"] = plate.surface_file
    out = _Reported(report, extra)
    paper_rms = None
    learned = study.estimator == "learned"
    if "paper" in study.strategies and ("paper" in todo or "adaptive" in todo):
        rec = run_paper(ctx, target) if learned else None
        if rec is not None:
            paper_rms = rec["true_rms_mm"]
            if "paper" in todo:
                out.append(rec)
    for name in todo:
        if name == "adaptive":
            # on to the paper's accuracy where it is stricter (adaptive against paper), its
            # touches to the target counted against the target as every strategy's are
            rec = run_planner(ctx, learn=True, target_true=target, run_to=paper_rms)
            if paper_rms is not None:
                rec["paper_true_rms_mm"] = paper_rms
            if index < study.lower_bound.plates:
                rec.update(lower_bounds(study, cell, ctx.model, rec))
            out.append(rec)
        elif name == "greedy_fixed":
            out.append(run_planner(ctx, learn=False, target_true=target))
        elif name == "grid" and learned:
            out.append(run_grid(ctx, target))
        elif name == "random" and learned:
            out.append(run_random(ctx, target))
    return list(out)


class _Reported(list):
    """A list of records that tells ``report`` of each one appended."""

    def __init__(self, report: Callable[[dict], None] | None, extra: dict | None = None):
        super().__init__()
        self.report = report
        self.extra = extra or {}

    def append(self, rec: dict) -> None:
        rec.update(self.extra)
        super().append(rec)
        if self.report is not None:
            self.report(rec)


def fixed_batch_task(study_data: dict, base: dict, indices: list[int], strategy: str,
                     how: str = "vmap") -> list[dict]:
    """One fixed design (estimator: fixed) on many plates at once (jax.vmap)."""
    require_float64()
    from adaptive_cal.study.batch import run_fixed
    from adaptive_cal.study.strategies import Context

    study = Study.model_validate(study_data)
    contexts = []
    for i in indices:
        plate = sample_plate(study, i)
        contexts.append(Context.create(study, plate, plate_cell(study, base, plate)))
    records = run_fixed(strategy, contexts, [study.bound.true_mm] * len(contexts), how=how)
    return [{**rec, "code": code_fingerprint()} for rec in records]
