"""Fixed designs with fixed hyper-parameters, all plates at once (``estimator: fixed``).

The covariance along a design does not depend on the readings, so the whole study of a design is
one ``jax.vmap`` over plates of a ``lax.scan`` over touches (designs.evaluate_vmap). Records have
the same fields as the per-plate strategies'.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.study.designs import evaluate_loop, evaluate_vmap, grid_points, grid_sizes, random_points
from adaptive_cal.study.plates import heights_at
from adaptive_cal.study.strategies import Context, paper_native, paper_schedule, paper_stop, record

EVALUATE = {"vmap": evaluate_vmap, "loop": evaluate_loop}


def _inputs(contexts: list[Context], xy_per_plate):
    rows = [c.model.surface.basis(xy[:, 0], xy[:, 1]) for c, xy in zip(contexts, xy_per_plate)]
    heights = np.array([heights_at(c.cell, xy) for c, xy in zip(contexts, xy_per_plate)])
    truth = np.array([c.truth_eval for c in contexts])
    return rows, heights, truth


def run_fixed(strategy: str, contexts: list[Context], targets: list[float], *,
              how: str = "vmap") -> list[dict]:
    """Records of ``strategy`` (paper, grid, random) on every plate of ``contexts``."""
    ctx0 = contexts[0]
    model, bound = ctx0.model, ctx0.study.bound
    prior, noise_var = model.belief(model.hyper0), model.hyper0.noise_std_mm**2
    ev = ctx0.evaluator
    evaluate = EVALUATE[how]
    hyper = list(model.hyper0)
    if strategy == "paper":
        xy, ends, n_level, n_path = paper_schedule(ctx0)
        rows, heights, truth = _inputs(contexts, [xy] * len(contexts))
        rule = paper_stop(ctx0, n_level, n_path)
        checkpoints = [n_level] + ends
        stops = [next((n for n in checkpoints if rule(n, None, h, xy)), checkpoints[-1])
                 for h in heights]
        per, fin = evaluate(prior, noise_var, ev, rows[0], heights, truth, np.array(stops))
        out = []
        for p, c in enumerate(contexts):
            traj = [[n, per[0][p, n - 1], per[1][p, n - 1]] for n in checkpoints]
            reason = rule(stops[p], None, heights[p], xy) or "touch_budget"
            rec = record(c, "paper", traj, stops[p], {k: v[p] for k, v in fin.items()},
                         xy, reason, targets[p], hyper=hyper)
            if stops[p] > n_level:
                rec.update(paper_native(c, xy, heights[p], stops[p], n_path))
            out.append(rec)
        return out
    if strategy == "random":
        xys = [random_points(c.cell, bound.max_touches, np.random.default_rng([c.plate.seed, 7]))
               for c in contexts]
        rows, heights, truth = _inputs(contexts, xys)
        n = bound.max_touches
        per, _ = evaluate(prior, noise_var, ev, np.array(rows), heights, truth, np.full(len(xys), n))
        met = per[0] <= bound.mean_std_mm
        stops = [int(np.argmax(m)) + 1 if m.any() else n for m in met]
        _, fin = evaluate(prior, noise_var, ev, np.array(rows), heights, truth, np.array(stops))
        return [record(c, "random", [[t + 1, per[0][p, t], per[1][p, t]] for t in range(n)],
                       stops[p], {k: v[p] for k, v in fin.items()}, xys[p],
                       "mean_std_bound" if met[p].any() else "touch_budget", targets[p],
                       hyper=hyper) for p, c in enumerate(contexts)]
    if strategy == "grid":
        sizes = grid_sizes(ctx0.cell, bound.max_touches)
        runs = []
        for nx, ny in sizes:  # padded to the budget: one compiled shape for every grid
            xy = grid_points(ctx0.cell, nx, ny)
            rows, heights, truth = _inputs(contexts, [xy] * len(contexts))
            pad = bound.max_touches - len(xy)
            r = np.vstack([rows[0], np.zeros((pad, rows[0].shape[1]))])
            h = np.hstack([heights, np.zeros((len(contexts), pad))])
            _, fin = evaluate(prior, noise_var, ev, r, h, truth, np.full(len(contexts), len(xy)))
            runs.append((xy, fin))
        out = []
        for p, c in enumerate(contexts):
            traj = [[len(xy), fin["mean_std_mm"][p], fin["true_rms_mm"][p]] for xy, fin in runs]
            k = next((i for i, (_, fin) in enumerate(runs)
                      if fin["mean_std_mm"][p] <= bound.mean_std_mm), len(runs) - 1)
            xy, fin = runs[k]
            rec = record(c, "grid", traj, len(xy), {q: v[p] for q, v in fin.items()}, xy,
                         "mean_std_bound" if fin["mean_std_mm"][p] <= bound.mean_std_mm
                         else "touch_budget", targets[p], hyper=hyper, grid=list(sizes[k]))
            t = next((i for i, (_, f) in enumerate(runs) if f["true_rms_mm"][p] <= targets[p]), None)
            rec["robot_time_true_s"] = None if t is None else c.robot_time_s(runs[t][0])
            out.append(rec)
        return out
    raise ValueError(f"strategy {strategy!r} has no fixed-design batch")
