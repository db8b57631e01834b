"""What a run reports: tilt correction, posterior std, flatness with 95 % intervals, truth
errors on a simulated cell, and the figures. Every figure with an interval is written as
{"value": v, "ci95": [low, high]} in mm. Randomness (the posterior samples) is passed in.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptive_cal.analysis import flatness as fl
from adaptive_cal.cell.schema import Cell
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.run.folder import finite_json, replace_atomically, write_json
from adaptive_cal.run.truth import truth_error

SAMPLES = 200


def plate_estimates(plan: SurveyPlan, belief: bl.Belief, rng: np.random.Generator,
                     samples: int | None = None) -> dict:
    """Tilt and flatness of the plate from the belief: value on the posterior mean surface,
    interval over ``samples`` (default ``SAMPLES``) surfaces sampled from the belief
    (evaluation grid over the whole plate)."""
    samples = SAMPLES if samples is None else samples
    xy, rows = plan.eval_xy, plan.eval_rows
    mean, _ = bl.predict(belief, rows)
    draws = bl.sample(belief, rng, samples) @ rows.T  # (S, N)
    x, y = xy[:, 0], xy[:, 1]
    values = fl.figures(x, y, mean)
    names = ("least_squares", "range", "minimum_zone")
    sampled = fl.sampled_figures(x, y, draws)
    flat = fl.interval_figures({k: values[k] for k in names}, {k: sampled[k] for k in names})
    tilt = fl.plane_tilt(x, y, mean)
    angles = np.array([fl.tilt_correction_deg(*fl.least_squares_plane(x, y, d)[:2]) for d in draws])
    tilt["rx_std_deg"], tilt["ry_std_deg"] = (float(v) for v in angles.std(axis=0))
    return {"tilt": tilt, "flatness_mm": flat}


def write_results(cell: Cell, plan: SurveyPlan, state: sv.SurveyState, out: Path,
                  stopped_because: str, *, rng: np.random.Generator, history=None, truth=None,
                  true_rms_mm=None) -> dict:
    """result.json, surface.png and convergence.png in ``out``, each replaced whole (a temporary
    file moved over the old one); returns the result dict (non-finite numbers as None).
    ``rng`` draws the posterior samples of the intervals; ``history``: the status before the
    first touch and after each one (convergence figure)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    status = sv.status(plan, state)
    stop = cell.plan.stop
    surface = plan.model.surface
    result = {
        "touches": state.touches,
        "fused": state.fused,
        "stopped_because": stopped_because,
        "bound": {"mean_std_mm": stop.mean_std_mm, "max_std_mm": stop.max_std_mm,
                  "max_touches": stop.max_touches},
        "posterior": {"mean_std_mm": status.mean_std_mm, "max_std_mm": status.max_std_mm,
                      "mean_std_is": "RMS posterior std over the whole plate"},
        "hyper": dict(state.hyper._asdict()),
        "knots_mm": {"x": surface.sx.knots.tolist(), "y": surface.sy.knots.tolist(),
                     "ends": surface.sx.ends},
    }
    result.update(plate_estimates(plan, state.belief, rng))
    if truth is not None:
        result["truth"] = truth_error(plan, state.belief, truth)
    # the figures first: result.json, written last, marks the results complete (a kill while
    # drawing leaves the old result.json, so --resume does not take the run as finished)
    write_figures(cell, plan, state, out, history or [status], true_rms_mm)
    write_json(out / "result.json", result)  # atomic; NaN / inf as null
    return finite_json(result)


def write_figures(cell: Cell, plan: SurveyPlan, state: sv.SurveyState, out: Path, history,
                  true_rms_mm=None) -> None:
    """surface.png (mean and std maps, touches numbered by seq) and convergence.png (std against
    touches; ``true_rms_mm`` per history entry when the truth is known)."""
    from adaptive_cal.report import figures as plots

    wp = cell.workplane
    gx, gy, mean, std = sv.grid(plan, state.belief)
    keep = [(k.x_mm, k.y_mm) for k in wp.keep_outs]
    touched = np.array(state.touched_xy_mm, float).reshape(-1, 2)  # numbered as in the recording
    fig = plots.surface_figure(gx, gy, mean, std, touched, wp.x_mm, wp.y_mm,
                               keep_outs=keep, title=cell.name)
    _save(fig, out / "surface.png")
    h = history
    stop = cell.plan.stop
    fig = plots.convergence_figure(np.array([s.touches for s in h]),
                                   np.array([s.mean_std_mm for s in h]),
                                   np.array([s.max_std_mm for s in h]),
                                   bound_mean_mm=stop.mean_std_mm, bound_max_mm=stop.max_std_mm,
                                   true_rms_mm=true_rms_mm)
    _save(fig, out / "convergence.png")


def _save(fig, path: Path) -> None:
    replace_atomically(path, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)


def save_belief(plan: SurveyPlan, state: sv.SurveyState, path: Path) -> None:
    """The belief and its spline, for ``--prior-from`` in a later run (replaced whole), with
    the touches and fused readings it holds (never more than the recording's rows)."""
    s = plan.model.surface
    arrays = {"mean": state.belief.mean, "cov": state.belief.cov, "knots_x": s.sx.knots,
              "knots_y": s.sy.knots, "hyper": np.array(state.hyper),
              "touches": np.array(state.touches), "fused": np.array(state.fused)}
    replace_atomically(path, lambda f: np.savez(f, **arrays), binary=True)
