"""What a run reports: tilt correction, posterior std, flatness with 95 % intervals, truth
errors on a simulated cell, and the figures. Every figure with an interval is written as
{"value": v, "ci95": [low, high], "value_is": ...} in mm; flatness comes from
``analysis.flatness_answer`` (of the touched points and of the whole plate). Randomness (the
posterior samples) is passed in.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptive_cal.cell.build import plan_model, touch_floor
from adaptive_cal.analysis.flatness_answer import SAMPLES, flatness_answer, largest_gap
from adaptive_cal.analysis.reach import out_of_box
from adaptive_cal.analysis.local_features import confirmed, feature_var_mm2, weighted_out
from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.npz import broken_belief, broken_text, read_npz, saved_hyper
from adaptive_cal.formats.recording import read_recording, surface_height_mm
from adaptive_cal.formats.times import last_time_s
from adaptive_cal.formats.writing import provenance, rows_digest
from adaptive_cal.formats.numbers import count
from adaptive_cal.planning.gap import largest_gap as gap_radius
from adaptive_cal.planning.gate import flagged_weight
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import Hyper, kernel_weights
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.route import robot_time_s
from adaptive_cal.report.status import missing
from adaptive_cal.run.folder import finite_json, replace_atomically, write_json
from adaptive_cal.run.truth import state_truth_error


def plate_estimates(plan: SurveyPlan, belief: bl.Belief, rng: np.random.Generator,
                    samples: int = SAMPLES) -> dict:
    """Tilt and flatness of the whole plate from the belief (``analysis.flatness_answer``)."""
    return flatness_answer(plan, belief, 0.0, None, rng, samples)


def touched_heights(plan: SurveyPlan, recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, height) in mm of a recording's fused touches, with the plan's probe zero: the
    heights exactly as written, so a result and ``flatness`` on the file agree to the digit."""
    f = (rec := _recording(recording)).fused
    return rec.x_mm[f], rec.y_mm[f], surface_height_mm(rec.reading_mm[f], rec.z_mm[f], plan.zero_mm)


def reweighted(state: sv.SurveyState, rec) -> list[dict]:
    """The fused readings whose weight was lowered below what their flags say -- by a refit
    (``planning.survey.reweighed``), or when a retake confirmed a gated reading they contradicted
    (``planning.robust.condemned``): [{seq, outlier_probability}] (p = 1 - weight now)."""
    fused = rec.fused
    if not rec.flags or int(fused.sum()) != state.fused:
        return []
    flagged = np.array([flagged_weight(f) for f, k in zip(rec.flags, fused) if k])
    now = state.fused_weights
    return [{"seq": int(seq), "outlier_probability": float(1.0 - w)}
            for seq, w, was in zip(rec.seq[fused], now, flagged) if w < was - 1e-9]


def _recording(recording):
    return read_recording(recording) if isinstance(recording, (str, Path)) else recording


def result_of(cell: Cell, plan: SurveyPlan, state: sv.SurveyState, recording,
              stopped_because: str, *, rng: np.random.Generator, truth=None) -> dict:
    """The result dict of a state (result.json without writing it): counts, bounds, posterior,
    hyper-parameters, knots, tilt and the flatness answer (touched points from ``recording``, a
    path or a Recording, and the whole plate), and the truth errors when ``truth`` is given."""
    status = sv.status(plan, state)
    stop = cell.plan.stop
    surface = plan.model.surface
    robot_s, travel_mm = robot_time_s(plan.start_xy_mm, state.touched_xy_mm, plan.speed_mm_per_s,
                                      plan.touch_time_s)
    result = {
        "touches": state.touches,
        "fused": state.fused,
        # robot time beside the touches: straight travel from the plate centre through every
        # touch at robot.speed_mm_per_s, plus robot.touch_time_s per touch (an estimate)
        "robot_time_s": robot_s,
        "travel_mm": travel_mm,
        "robot_time_is": robot_time_is(plan.speed_mm_per_s, plan.touch_time_s),
        "stopped_because": stopped_because,
        "bound": {"mean_std_mm": stop.mean_std_mm, "max_std_mm": stop.max_std_mm,
                  "max_touches": stop.max_touches, "max_gap_mm": stop.max_gap_mm,
                  "defaulted": sorted(set(type(stop).model_fields) - stop.model_fields_set),
                  # touches before a bound may stop the run (the stop rule's touch floor)
                  "min_touches": touch_floor(cell, plan.model.form_surface.size,
                                             informed_prior=state.prior is not None)},
        "posterior": {"mean_std_mm": status.mean_std_mm, "max_std_mm": status.max_std_mm,
                      "mean_std_is": "RMS posterior std over the whole plate"},
        "hyper": {**state.hyper._asdict(), "kernel_weights": kernel_weights(state.hyper_points)},
        "knots_mm": {"x": surface.sx.knots.tolist(), "y": surface.sy.knots.tolist(),
                     "ends": surface.sx.ends},
    }
    result["model"] = model_block(state, status, plan)
    # the closure touch's verdict (planning.closure), or None when none was made
    result["closure"] = state.closure.as_dict() if state.closure is not None else None
    rec = _recording(recording) if not isinstance(recording, (str, Path)) \
        or Path(recording).exists() else None
    xyz = touched_heights(plan, rec) if rec is not None else None
    result["clock_s"] = last_time_s(rec)  # the cell's own clock at the last reading (its t_s)
    # a dent or burr a retake confirmed and the spline cannot follow (analysis.local_features)
    result["local_features"] = (confirmed(plan.model.surface, state.belief,
                                          state.hyper.noise_std_mm, rec, plan.zero_mm)
                                if rec is not None else [])
    lowered = reweighted(state, rec) if rec is not None else []
    result["model"]["reweighted"] = lowered
    result["weighted_out"] = (weighted_out(rec.seq[rec.fused], state.fused_weights)
                              if rec is not None and int(rec.fused.sum()) == state.fused else [])
    if lowered:
        shown = ", ".join(f"seq {r['seq']} p {r['outlier_probability']:.2f}" for r in lowered[:3])
        more = f" and {len(lowered) - 3} more" if len(lowered) > 3 else ""
        result["model"]["summary"] += (
            f"; {count(len(lowered), 'fused reading')} judged a gross error after fusion "
            f"({shown}{more}): in the map at weight 1 - p")
    result.update(flatness_answer(plan, state.belief, state.hyper.noise_std_mm,
                                  xyz if xyz is not None and len(xyz[2]) >= 4 else None, rng,
                                  SAMPLES, sv.unresolved_var_mm2(plan, state, plan.eval_xy),
                                  result["local_features"], plan.learn))
    # where a narrow feature could hide between the fused touches; where the box keeps it off
    result["largest_gap"] = largest_gap(
        plan, np.c_[xyz[0], xyz[1]] if xyz is not None else state.touched_xy_mm)
    result["out_of_box"] = out_of_box(plan, state.belief)
    result["keep_outs"] = keep_out_maps(cell, plan, state)
    # the units of the tilt's plane (its keys a, b, c stay as they are: a stable interface)
    result["tilt"] = {**result["tilt"], "plane_is": TILT_PLANE_IS}
    if truth is not None:
        result["truth"] = state_truth_error(plan, state, truth)
    return finite_json(result)


#: result.json's tilt.plane_is: what a, b and c are, with their units
TILT_PLANE_IS = ("least-squares plane z = a x + b y + c of the map in the workplane frame: a and "
                 "b slopes along x and y (mm/mm), c the height at the frame origin (mm, from "
                 "where the probe reads its zero); rx_deg, ry_deg the correction rotx(rx) "
                 "roty(ry) (deg), *_std_deg their posterior std (deg); where noise_dof is given, "
                 "with the learned noise's own uncertainty counted: the std of the Gaussian with "
                 "the same 2-sd interval as a Student-t on noise_dof degrees of freedom")


def robot_time_is(speed_mm_per_s: float, touch_time_s: float) -> str:
    """What result.json's robot_time_s is: an estimate, not a clock."""
    return (f"estimate: straight travel from the plate centre through every touch at "
            f"{speed_mm_per_s:g} mm/s (robot.speed_mm_per_s) plus {touch_time_s:g} s per touch "
            "(robot.touch_time_s); the recording's t_s is the cell's own clock")


def write_results(cell: Cell, plan: SurveyPlan, state: sv.SurveyState, out: Path,
                  stopped_because: str, *, rng: np.random.Generator, history=None, truth=None,
                  true_rms_mm=None, refits=(), extra: dict | None = None) -> dict:
    """belief.npz, result.json, surface.png and convergence.png in ``out``, each replaced whole
    (a temporary file moved over the old one); returns the result dict (non-finite numbers as
    None). ``rng`` draws the posterior samples of the intervals; ``history``: the status before
    the first touch and after each one (convergence figure); ``extra``: keys added to
    result.json (a re-check's "prior_from"), in the one write that marks the results complete."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rec = read_recording(out / "recording.csv") if (out / "recording.csv").exists() else None
    result = {**result_of(cell, plan, state, rec if rec is not None else out / "recording.csv",
                          stopped_because, rng=rng, truth=truth), **(extra or {})}
    features = result.get("local_features") or ()
    save_belief(plan, state, out / "belief.npz", features,
                None if rec is None else rows_digest(rec, state.touches))
    status = sv.status(plan, state)
    # the belief and the figures first: result.json, written last, marks the results complete
    # (a kill while drawing leaves the old result.json, so --resume does not take the run as
    # finished)
    history, true_rms_mm, jump = closing_point(state, status, history, true_rms_mm)
    write_figures(cell, plan, state, out, history, true_rms_mm, refits,
                  incomplete=missing(result), features=features, jump=jump)
    result = {**result, **provenance()}  # which code wrote these figures, and when
    write_json(out / "result.json", result)  # atomic; NaN / inf as null
    return finite_json(result)


def closing_point(state: sv.SurveyState, status, history, true_rms_mm):
    """The convergence history with the run's final status appended where a closure touch found
    a drift: its d^2 widens every band after the last touch was fused, so the history's last
    point (the status at that touch) is below the std result.json and the report's card give.
    (history, true_rms_mm, the note of that jump or None); the map's mean, and so its true error,
    is the same at the jump."""
    history = list(history or [status])
    c = state.closure
    if c is None or c.drift_var_mm2 <= 0.0 or status.mean_std_mm <= history[-1].mean_std_mm:
        return history, true_rms_mm, None  # (a resume that ended on it: its history has it)
    history.append(status)
    if true_rms_mm is not None and len(true_rms_mm):
        true_rms_mm = [*true_rms_mm, true_rms_mm[-1]]
    return history, true_rms_mm, (f"closure: drift {abs(c.difference_mm) * 1e3:.1f} um "
                                  "added to every band")


def model_block(state: sv.SurveyState, status, plan: SurveyPlan | None = None) -> dict:
    """result.json's "model": whether the spline's self-checks pass, each check, the RMS of the
    structure finer than the spline (mm, included in the posterior stds) and where the map
    should not be trusted (``planning.adequacy``). A model not checked (too few readings, or
    hyper-parameters not learned: a re-check) still says where the map is extrapolated, as a
    checked one does (``plan``: the workplane and the box touches reach)."""
    if state.adequacy is None:
        summary = ("model not checked yet (too few fused readings for its self-checks)"
                   if not status.adequate else "model not checked (the hyper-parameters are "
                   "not learned: fixed, or carried by --prior-from)")
        ext = _extrapolated(plan) if plan is not None else None
        return {"adequate": status.adequate, "checks": {}, "unresolved_rms_mm": 0.0,
                "where": [], "extrapolated": ext,
                "summary": summary if ext is None else f"{summary}; {ext['text']}"}
    return state.adequacy.as_dict()


def keep_out_maps(cell: Cell, plan: SurveyPlan, state: sv.SurveyState) -> list[dict]:
    """The map under each keep-out (``workplane.keep_outs``, clipped to the plate), where no
    touch goes and no check looks: how far it lies from the nearest touch (mm; the fill
    distance of the touches over it, ``planning.gap.largest_gap``), and the band's
    std there (its largest and RMS on a 9 x 9 grid, mm, the unresolved structure included),
    with a line. An outside audit (2026-11-29) found a corner clamp's map 13-23 um off the truth
    under bands of 9-13 um and nothing that said the map there was untouched."""
    (px0, px1), (py0, py1) = plan.plate_mm
    touched = np.asarray(state.touched_xy_mm, float).reshape(-1, 2)
    out = []
    for i, k in enumerate(cell.workplane.keep_outs):
        (x0, x1), (y0, y1) = (max(k.x_mm[0], px0), min(k.x_mm[1], px1)), (max(k.y_mm[0], py0),
                                                                            min(k.y_mm[1], py1))
        if x1 <= x0 or y1 <= y0:
            continue
        xx, yy = (v.ravel() for v in np.meshgrid(np.linspace(x0, x1, 9), np.linspace(y0, y1, 9)))
        var = bl.predict(state.belief, plan.model.surface.basis(xx, yy))[1]
        std = np.sqrt(np.maximum(var + sv.unresolved_var_mm2(plan, state, np.c_[xx, yy]), 0.0))
        far = gap_radius(np.c_[xx, yy], touched)[0] if len(touched) else None
        text = (f"keep_outs[{i}] (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm) is never touched: the "
                "map under it rests on touches" + (f" up to {far:.0f} mm away" if far is not None
                                                   else "") + " and no check tests it there; its "
                f"std there up to {std.max() * 1e3:.1f} um")
        out.append({"index": i, "x_mm": [x0, x1], "y_mm": [y0, y1], "farthest_from_touch_mm": far,
                    "std_max_mm": float(std.max()), "std_rms_mm": float(np.sqrt(np.mean(std**2))),
                    "text": text})
    return out


def _extrapolated(plan: SurveyPlan) -> dict | None:
    """``Adequacy.extrapolated`` of the plan's workplane and reachable box, without checks: it
    reads those two boxes alone."""
    from adaptive_cal.planning.adequacy import Adequacy

    none = np.zeros((1, 1))
    return Adequacy(True, {}, none, np.zeros(2), np.zeros(2), 0.0, none,
                    plate_mm=tuple(map(tuple, plan.plate_mm)),
                    reach_mm=tuple(map(tuple, plan.bounds_mm))).extrapolated()


def write_figures(cell: Cell, plan: SurveyPlan, state: sv.SurveyState, out: Path, history,
                  true_rms_mm=None, refits=(), incomplete: str | None = None,
                  features=(), jump: str | None = None) -> None:
    """surface.png (mean and std maps, touches numbered by seq) and convergence.png (std against
    touches; ``true_rms_mm`` per history entry when the truth is known; the refits (touch
    counts) and the touch floor of the stop rule marked). ``incomplete``: what an unfinished run
    misses (``report.status.missing`` of its result, the terminal's INCOMPLETE line), marked
    in both titles; ``jump``: what widened the bands after the last touch (``closing_point``)."""
    from adaptive_cal.report import figures as plots

    wp = cell.workplane
    gx, gy, mean, std = sv.grid(plan, state.belief, state=state,
                                extra_var=(lambda x, y: feature_var_mm2(features, x, y))
                                if features else None)
    keep = [(k.x_mm, k.y_mm) for k in wp.keep_outs]
    touched = np.array(state.touched_xy_mm, float).reshape(-1, 2)  # numbered as in the recording
    fig = plots.surface_figure(gx, gy, mean, std, touched, wp.x_mm, wp.y_mm,
                               keep_outs=keep, title=cell.name, incomplete=incomplete)
    _save(fig, out / "surface.png")
    h = history
    stop = cell.plan.stop
    fig = plots.convergence_figure(np.array([s.touches for s in h]),
                                   np.array([s.mean_std_mm for s in h]),
                                   np.array([s.max_std_mm for s in h]),
                                   bound_mean_mm=stop.mean_std_mm, bound_max_mm=stop.max_std_mm,
                                   true_rms_mm=true_rms_mm, refits=refits,
                                   floor_touches=touch_floor(cell, plan.model.form_surface.size,
                                                             informed_prior=state.prior is not None),
                                   incomplete=incomplete, jump=jump)
    _save(fig, out / "convergence.png")


def _save(fig, path: Path) -> None:
    replace_atomically(path, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)


UNRESOLVED_NODES = 81  # per side of the saved grid of s_u^2 (``unresolved_grid``)


def unresolved_grid(plan: SurveyPlan, state: sv.SurveyState, features=()) -> dict[str, np.ndarray]:
    """s_u^2 (``planning.survey.unresolved_var_mm2``: structure finer than the knots, a drift
    the closure found; plus the confirmed local ``features``, ``feature_var_mm2``) on a
    UNRESOLVED_NODES-square grid over the workplane, as belief.npz keeps it, so the report's
    and compensate's bands are the run's (the spline's variance plus this)."""
    (x0, x1), (y0, y1) = plan.plate_mm
    gx, gy = np.linspace(x0, x1, UNRESOLVED_NODES), np.linspace(y0, y1, UNRESOLVED_NODES)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    u = sv.unresolved_var_mm2(plan, state, np.c_[xx.ravel(), yy.ravel()]).reshape(xx.shape)
    u = u + feature_var_mm2(features, xx, yy)
    return {"unresolved_x_mm": gx, "unresolved_y_mm": gy, "unresolved_var_mm2": u}


def save_belief(plan: SurveyPlan, state: sv.SurveyState, path: Path, features=(),
                digest: str | None = None) -> None:
    """The belief and its spline, for ``--prior-from`` in a later run (replaced whole), with
    the touches and fused readings it holds (never more than the recording's rows), the
    ``digest`` of those rows (``formats.writing.rows_digest``), and the variance of structure
    finer than the knots and of confirmed local ``features`` on a grid (``unresolved_grid``)."""
    s = plan.model.surface
    arrays = {"mean": state.belief.mean, "cov": state.belief.cov, "knots_x": s.sx.knots,
              "knots_y": s.sy.knots, "hyper": state.hyper.theta,
              "kernel": np.array(state.hyper.kernel),
              "touches": np.array(state.touches), "fused": np.array(state.fused),
              **unresolved_grid(plan, state, features),
              **({} if digest is None else {"recording_sha256": np.array(digest)})}
    replace_atomically(path, lambda f: np.savez(f, **arrays), binary=True)


def read_belief(run_dir: Path, cell: Cell) -> tuple[bl.Belief, Hyper]:
    """The belief ``save_belief`` wrote into RUN_DIR/belief.npz, as saved (not widened), and its
    hyper-parameters; its knots must be the ones ``cell`` gives (``plan_model(cell).surface``
    then evaluates it)."""
    path = Path(run_dir) / "belief.npz"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no saved belief (is {run_dir} a finished run?)")
    data = read_npz(path)
    if belief_mismatch(plan_model(cell).surface, data) is not None:
        raise ValueError(f"{path}: the earlier run used other knots; give the cell file the same "
                         "model.knots_x / knots_y")
    bad = broken_belief(data)
    if bad:
        raise ValueError(broken_text(path, bad))
    return bl.Belief(data["mean"], data["cov"]), saved_hyper(data)


def belief_mismatch(surface, data) -> str | None:
    """None when a saved belief (``data``: belief.npz's arrays) is a map on ``surface``'s spline:
    the same knots, a mean and covariance of their size; else what its knots are ("7 x 6",
    "8 x 7 at other places" or "unreadable")."""
    k = (len(surface.sx.knots), len(surface.sy.knots))
    try:
        kx, ky = np.asarray(data["knots_x"], float), np.asarray(data["knots_y"], float)
        mean, cov = np.asarray(data["mean"]), np.asarray(data["cov"])
        fits = (kx.shape == (k[0],) and ky.shape == (k[1],) and np.allclose(kx, surface.sx.knots)
                and np.allclose(ky, surface.sy.knots) and mean.shape == (k[0] * k[1],)
                and cov.shape == (k[0] * k[1],) * 2)
    except (KeyError, ValueError, TypeError):
        return "unreadable"
    return None if fits else (
        f"{kx.size} x {ky.size}" + ("" if (kx.size, ky.size) != k else " at other places"))
