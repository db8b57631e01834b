"""Running a study: plates in-process or on Dask distributed, results appended as JSON lines.

Each finished plate is appended (and flushed) to ``plates.jsonl`` at once, so an interrupted
study keeps the plates already finished and a rerun skips them. The first line names the study
(a hash of the study and cell), so a checkpoint of another study is never mixed in.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from adaptive_cal.cell.schema import parse_cell
from adaptive_cal.study.config import Study

PER_PLATE = ("paper", "adaptive", "greedy_fixed")  # paper first: adaptive runs on to its accuracy
FIXED_DESIGNS = ("paper", "grid", "random")


class SchedulerError(ConnectionError):
    """The Dask scheduler cannot be reached; the message names the address."""


def study_key(study: Study, base: dict) -> str:
    text = json.dumps({"study": study.model_dump(mode="json"), "cell": base}, sort_keys=True,
                      default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _worker_setup() -> None:
    """Entry of a worker process (like the CLI): float64 in JAX, one BLAS thread."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import jax

    jax.config.update("jax_enable_x64", True)
    try:  # numpy may already be loaded with threads in a worker we did not start
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass


def plate_task(study_data: dict, base: dict, index: int, todo: tuple[str, ...]) -> list[dict]:
    """Every per-plate strategy of ``todo`` on plate ``index`` (runs in a worker)."""
    _worker_setup()
    from adaptive_cal.study.bound import (best_integer_touches, design_problem, greedy_touches, integer_touches,
                        marginal_problem, relaxed_touches)
    from adaptive_cal.study.config import Study as _Study
    from adaptive_cal.study.plates import plate_cell, sample_plate
    from adaptive_cal.study.strategies import Context, run_grid, run_paper, run_planner, run_random

    study = _Study.model_validate(study_data)
    plate = sample_plate(study, index)
    cell = plate_cell(study, base, plate)
    ctx = Context.create(study, plate, cell)
    target = study.bound.true_mm
    out = []
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
            t = target if paper_rms is None else min(target, paper_rms)
            rec = run_planner(ctx, learn=True, target_true=t)
            if paper_rms is not None:
                rec["paper_true_rms_mm"] = paper_rms
            if index < study.lower_bound.plates:
                from adaptive_cal.gaussian.prior import Hyper

                def problem(hyper):
                    return design_problem(cell, ctx.model, Hyper(*hyper),
                                          candidates=study.lower_bound.candidates)

                prob = problem(rec["hyper"])
                j = prob.area_mm2 * study.bound.mean_std_mm**2
                rec["relaxed_touches"] = relaxed_touches(prob, j, study.bound.max_touches)
                rec["relaxed_whole_touches"] = integer_touches(
                    prob, j, study.bound.max_touches, relaxed=rec["relaxed_touches"])
                rec["best_integer_touches"] = best_integer_touches(
                    prob, j, study.bound.max_touches, study.lower_bound.exhaustive_limit)
                rec["greedy_known_touches"] = greedy_touches(prob, j, study.bound.max_touches)
                # the same bound under what the planner believed when it stopped (the run goes
                # on past its stop until the true error meets the target, and refits on the way)
                if rec["hyper_at_stop"] == rec["hyper"]:
                    rec["relaxed_whole_touches_at_stop"] = rec["relaxed_whole_touches"]
                else:
                    rec["relaxed_whole_touches_at_stop"] = integer_touches(
                        problem(rec["hyper_at_stop"]), j, study.bound.max_touches)
                # and for the question the planner's stop answers: its belief mixes the posteriors
                # under the weighted hyper-parameter points of its last refit
                points = [(p[:3], p[3]) for p in rec["hyper_points_at_stop"]]
                rec["marginal_whole_touches_at_stop"] = integer_touches(
                    marginal_problem(cell, ctx.model, points,
                                     candidates=study.lower_bound.candidates),
                    j, study.bound.max_touches)
            out.append(rec)
        elif name == "greedy_fixed":
            out.append(run_planner(ctx, learn=False, target_true=target))
        elif name == "grid" and learned:
            out.append(run_grid(ctx, target))
        elif name == "random" and learned:
            out.append(run_random(ctx, target))
    return out


def fixed_batch_task(study_data: dict, base: dict, indices: list[int], strategy: str,
                     how: str = "vmap") -> list[dict]:
    """One fixed design (estimator: fixed) on many plates at once (jax.vmap)."""
    _worker_setup()
    from adaptive_cal.study.batch import run_fixed
    from adaptive_cal.study.config import Study as _Study
    from adaptive_cal.study.plates import plate_cell, sample_plate
    from adaptive_cal.study.strategies import Context

    study = _Study.model_validate(study_data)
    contexts = []
    for i in indices:
        plate = sample_plate(study, i)
        contexts.append(Context.create(study, plate, plate_cell(study, base, plate)))
    return run_fixed(strategy, contexts, [study.bound.true_mm] * len(contexts), how=how)


# -- checkpoint -----------------------------------------------------------------------------------
def read_checkpoint(path: Path, key: str) -> list[dict]:
    if not path.exists():
        return []
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines:
        return []
    head = json.loads(lines[0])
    if head.get("study_key") != key:
        raise ValueError(f"{path} holds plates of another study (key {head.get('study_key')}, "
                         f"this study {key}): delete it or choose another --out")
    records = []
    for line in lines[1:]:
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:  # a line cut by the interruption: that plate runs again
            break
    return records


class Checkpoint:
    """Append-only JSON lines, flushed and fsynced per plate."""

    def __init__(self, path: Path, key: str):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self.records = read_checkpoint(path, key)
        # rewrite without a cut last line (atomically), then append
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(json.dumps({"study_key": key}) + "\n")
            for r in self.records:
                f.write(json.dumps(r) + "\n")
        os.replace(tmp, path)
        self._f = open(path, "a", encoding="utf-8")

    def done(self) -> set[tuple[int, str]]:
        return {(r["plate"], r["strategy"]) for r in self.records}

    def add(self, records: Iterable[dict]) -> None:
        for r in records:
            self._f.write(json.dumps(r) + "\n")
            self.records.append(r)
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


# -- running --------------------------------------------------------------------------------------
def _jobs(study: Study, done: set) -> tuple[dict, dict]:
    per_plate, fixed = {}, {}
    learned = study.estimator == "learned"
    for i in range(study.plates):
        todo = tuple(s for s in study.strategies if (i, s) not in done
                     and (learned or s not in FIXED_DESIGNS))
        todo = tuple(sorted(todo, key=lambda s: PER_PLATE.index(s) if s in PER_PLATE else 9))
        if todo:
            per_plate[i] = todo
        if not learned:
            for s in study.strategies:
                if s in FIXED_DESIGNS and (i, s) not in done:
                    fixed.setdefault(s, []).append(i)
    return per_plate, fixed


def connect(scheduler: str | None, workers: int, timeout_s: float = 5.0):
    """A Dask client: the scheduler at ``scheduler`` (tcp://host:port) or a LocalCluster."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError) as e:
            raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler} within "
                                 f"{timeout_s:.0f} s ({type(e).__name__}); is it running "
                                 "and is the address right?") from None
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # inherited by the worker processes
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0")
    return Client(cluster)


def run_study(study: Study, base: dict, checkpoint: Path, *, client=None,
              progress: Callable[[int, int], None] | None = None, limit: int | None = None) -> list[dict]:
    """Run every plate not yet in ``checkpoint``; returns all records. ``client``: a Dask client
    (None: in-process). ``limit`` stops after that many new tasks (tests of interruption)."""
    parse_cell(base)  # fails early on a bad cell
    key = study_key(study, base)
    ck = Checkpoint(checkpoint, key)
    try:
        per_plate, fixed = _jobs(study, ck.done())
        data = study.model_dump(mode="json")
        total, finished = len(per_plate) + len(fixed), 0
        tasks = [(plate_task, (data, base, i, todo)) for i, todo in per_plate.items()]
        tasks += [(fixed_batch_task, (data, base, idx, s)) for s, idx in fixed.items()]
        if limit is not None:
            tasks = tasks[:limit]
        if client is None:
            for fn, args in tasks:
                ck.add(fn(*args))
                finished += 1
                if progress:
                    progress(finished, total)
        else:
            from dask.distributed import as_completed

            futures = [client.submit(fn, *args, pure=False) for fn, args in tasks]
            try:
                for fut in as_completed(futures):
                    ck.add(fut.result())
                    finished += 1
                    if progress:
                        progress(finished, total)
            finally:
                for f in futures:
                    f.cancel()
        return sorted(ck.records, key=lambda r: (r["plate"], r["strategy"]))
    finally:
        ck.close()


# -- summary --------------------------------------------------------------------------------------
def _mean(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def summarise(study: Study, records: list[dict]) -> dict:
    """OUT.json: per strategy the touches and robot time to reach the bound on the TRUE error
    (the budget counted where it was never reached), and at the strategy's own stop the posterior
    bound, true RMS and max error and 95 % coverage; the lower bound; adaptive against paper."""
    budget = study.bound.max_touches
    out = {"study": study.name, "plates": study.plates, "bound": study.bound.model_dump(),
           "strategies": {}, "lower_bound": {}}
    by = {s: [r for r in records if r["strategy"] == s] for s in study.strategies}
    for s, recs in by.items():
        if not recs:
            continue
        touches = [r["touches_true"] if r["touches_true"] is not None else budget for r in recs]
        out["strategies"][s] = {
            "plates": len(recs),
            "touches_mean": float(np.mean(touches)),
            "touches_p90": float(np.percentile(touches, 90)),
            "robot_time_s_mean": _mean(r["robot_time_true_s"] for r in recs),
            "true_bound_reached": float(np.mean([r["touches_true"] is not None for r in recs])),
            "true_rms_mm_mean": _mean(r["true_rms_mm"] for r in recs),
            "true_max_mm_mean": _mean(r["true_max_mm"] for r in recs),
            "coverage95_mean": _mean(r["coverage95"] for r in recs),
            "stop_touches_mean": _mean(r["touches"] for r in recs),
            "stop_touches_p90": float(np.percentile([r["touches"] for r in recs], 90)),
            "stop_robot_time_s_mean": _mean(r["robot_time_s"] for r in recs),
            "stop_mean_std_mm_mean": _mean(r["mean_std_mm"] for r in recs),
        }
    adaptive = by.get("adaptive", [])
    lb = [r for r in adaptive if r.get("relaxed_touches") is not None]
    relaxed = _mean(r["relaxed_touches"] for r in lb)
    best = [r.get("best_integer_touches") for r in lb]
    out["lower_bound"] = {
        "plates": len(lb),
        "relaxed_touches": relaxed,
        "best_integer_touches": _mean(best) if best and all(b is not None for b in best) else None,
        "adaptive_stop_touches_same_plates": _mean(r["touches"] for r in lb),
        "adaptive_over_relaxed": _mean(r["touches"] / r["relaxed_touches"] for r in lb
                                       if r["relaxed_touches"] and np.isfinite(r["relaxed_touches"])),
    }
    whole = [r for r in lb if r.get("relaxed_whole_touches") is not None]
    if whole:  # the relaxation rounded up to whole touches: the tightest bound computed
        out["lower_bound"].update(
            relaxed_whole_touches=_mean(r["relaxed_whole_touches"] for r in whole),
            adaptive_over_relaxed_whole=_mean(
                r["touches"] / r["relaxed_whole_touches"] for r in whole
                if r["relaxed_whole_touches"] and np.isfinite(r["relaxed_whole_touches"])))
    at_stop = [r for r in lb if r.get("relaxed_whole_touches_at_stop")]
    if at_stop:
        out["lower_bound"].update(adaptive_over_relaxed_whole_at_stop=_mean(
            r["touches"] / r["relaxed_whole_touches_at_stop"] for r in at_stop
            if np.isfinite(r["relaxed_whole_touches_at_stop"])))
    marginal = [r for r in lb if r.get("marginal_whole_touches_at_stop")]
    if marginal:  # the bound for the planner's own stop, under its hyper-parameter posterior
        out["lower_bound"].update(
            marginal_whole_touches_at_stop=_mean(r["marginal_whole_touches_at_stop"]
                                                 for r in marginal),
            adaptive_over_marginal_whole_at_stop=_mean(
                r["touches"] / r["marginal_whole_touches_at_stop"] for r in marginal
                if np.isfinite(r["marginal_whole_touches_at_stop"])),
            adaptive_below_marginal_plates=sum(
                r["touches"] < r["marginal_whole_touches_at_stop"] for r in marginal))
    greedy = [r for r in lb if r.get("greedy_known_touches")]
    if greedy:  # a feasible integer design under the same hyper-parameters: brackets the best one
        out["lower_bound"].update(
            greedy_known_touches=_mean(r["greedy_known_touches"] for r in greedy),
            greedy_known_over_relaxed=_mean(r["greedy_known_touches"] / r["relaxed_touches"]
                                            for r in greedy if r["relaxed_touches"]),
            adaptive_over_greedy_known=_mean(r["touches"] / r["greedy_known_touches"]
                                             for r in greedy))
    papers = {r["plate"]: r for r in by.get("paper", [])}
    pairs = [(a, papers[a["plate"]]) for a in adaptive if a["plate"] in papers]
    if pairs:
        reach = []
        for a, p in pairs:
            hit = [t for t, _, rms in a["trajectory"] if rms <= p["true_rms_mm"]]
            reach.append(hit[0] if hit else None)
        got = [(t, p["touches"]) for t, (_, p) in zip(reach, pairs) if t is not None]
        level = float(np.mean([p["true_rms_mm"] for _, p in pairs]))
        pop = [next((t for t, _, rms in a["trajectory"] if rms <= level), budget) for a, _ in pairs]
        out["adaptive_vs_paper"] = {
            "plates": len(pairs),
            "paper_touches_mean": float(np.mean([p["touches"] for _, p in pairs])),
            "paper_true_rms_mm_mean": float(np.mean([p["true_rms_mm"] for _, p in pairs])),
            "adaptive_touches_to_paper_accuracy_mean": _mean(t for t, _ in got),
            "reached": len(got) / len(pairs),
            "touch_ratio_mean": _mean(t / n for t, n in got),
            "touch_ratio_of_means": (float(np.mean([t for t, _ in got])
                                           / np.mean([n for _, n in got])) if got else None),
            # against the paper's mean accuracy (free of the paper's luck on single plates)
            "adaptive_touches_to_paper_mean_accuracy": float(np.mean(pop)),
            "touch_ratio_mean_accuracy": float(np.mean(pop) / np.mean([p["touches"]
                                                                       for _, p in pairs])),
        }
        native = [(a, p) for a, p in pairs if p.get("native_true_rms_mm") is not None]
        if native:
            # the paper's procedure as published: its own map (last round, interpolated)
            t_native = [next((t for t, _, rms in a["trajectory"]
                              if rms <= p["native_true_rms_mm"]), budget) for a, p in native]
            n_paper = float(np.mean([p["touches"] for _, p in native]))
            out["adaptive_vs_paper"].update(
                paper_native_true_rms_mm_mean=float(np.mean([p["native_true_rms_mm"]
                                                             for _, p in native])),
                adaptive_touches_to_paper_native_accuracy_mean=float(np.mean(t_native)),
                touch_ratio_native=float(np.mean(t_native) / n_paper))
    return out
