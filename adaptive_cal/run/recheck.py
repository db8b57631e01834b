"""A re-check (``run --prior-from``): an earlier run's belief moved into the user frame corrected
since, widened by the drift allowance, and recorded in the run folder so ``--resume`` continues
from it.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from adaptive_cal.cell.build import plan_model
from adaptive_cal.cell.schema import Cell
from adaptive_cal.effects.frame import plane_in_corrected_frame
from adaptive_cal.formats.jsonfile import read_json
from adaptive_cal.formats.numbers import fixed
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import Hyper
from adaptive_cal.planning.clearance import Guard
from adaptive_cal.run.results import read_belief

PRIOR_RECORD = "prior_from.json"  # a re-check's --prior-from and correction, for --resume
CORRECTION_RANGE_DEG = 10.0  # as simulation.frame_correction_deg
# a re-check (--prior-from) stops after this many readings the gate flagged and their retakes
# confirmed (flag "surprise"): the plate is not where the earlier belief, moved by the
# correction assumed applied, puts it
PRIOR_SURPRISES = 3
# after a confirmed surprise, touches before a bound may stop a re-check: each further touch on
# a plate the earlier belief misplaces is another surprise (gated, then confirmed: 2 touches),
# so a wrong prior reaches PRIOR_SURPRISES first; a lone burr costs these touches only
PRIOR_HOLD = 2 * PRIOR_SURPRISES
PRIOR_DISAGREES = "prior_disagrees_with_readings"


def applied_correction(run_dir: Path, correction: str | tuple[float, float] = "proposed") -> dict:
    """The user-frame correction assumed applied since the run in ``run_dir``: ``"proposed"``
    (its result.json tilt, rx_deg / ry_deg), ``"none"`` (not applied: its belief is used as is)
    or (rx, ry) in deg (a measured applied correction). Returns the record result.json keeps:
    {"run": ..., "correction_deg": {"rx": .., "ry": ..}, "assumed": proposed | none | measured}."""
    run_dir = Path(run_dir)
    if correction == "none":
        rx, ry, assumed = 0.0, 0.0, "none"
    elif correction == "proposed":
        path = run_dir / "result.json"
        try:
            tilt = read_json(path)["tilt"]
            rx, ry = float(tilt["rx_deg"]), float(tilt["ry_deg"])
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: no proposed tilt correction (tilt rx_deg, ry_deg) to "
                             f"assume applied ({type(e).__name__}: {e}); pass the applied one "
                             "as --correction-applied RX,RY (deg), or none") from None
        assumed = "proposed"
    elif isinstance(correction, str) or len(correction) != 2:
        raise ValueError(f"correction {correction!r}: expected 'proposed', 'none' or (rx, ry) in deg")
    else:
        rx, ry = (float(v) for v in correction)
        assumed = "measured"
    if not all(math.isfinite(v) and abs(v) <= CORRECTION_RANGE_DEG for v in (rx, ry)):
        raise ValueError(f"correction rx {rx} deg, ry {ry} deg: each must be finite and within "
                         f"+-{CORRECTION_RANGE_DEG:g} deg")
    return {"run": str(run_dir), "correction_deg": {"rx": rx, "ry": ry}, "assumed": assumed}


def corrected_belief(model, belief: bl.Belief, rx_deg: float, ry_deg: float) -> bl.Belief:
    """The belief in the user frame corrected by rotx(rx) roty(ry) (``effects.frame``: about the
    frame's origin). The mean's plane theta = (s_x, s_y, c at the plate centre), its least-squares
    plane in coefficient space (theta = P^+ m, P = model.tilt_basis; exact when the mean is a
    plane), is replaced by the same plane seen in the corrected frame, exactly
    (``plane_in_corrected_frame``); the form is kept (its change is second order: below 1e-4 of
    the form height for a 1 deg correction). The covariance goes through the map's Jacobian
    A = I + P (J - I) P^+, J the plane map's 3 x 3 Jacobian (central differences)."""
    p = model.tilt_basis
    pinv = np.linalg.pinv(p)
    xc, yc = model.centre_mm

    def mapped(theta):
        sx, sy, c = theta
        a, b, c0 = plane_in_corrected_frame(sx, sy, c - sx * xc - sy * yc, rx_deg, ry_deg)
        return np.array([a, b, c0 + a * xc + b * yc])

    theta = pinv @ belief.mean
    steps = np.array([1e-6, 1e-6, 1e-6])
    jac = np.column_stack([(mapped(theta + h) - mapped(theta - h)) / (2 * h[i])
                           for i, h in enumerate(np.diag(steps))])
    a = np.eye(len(belief.mean)) + p @ (jac - np.eye(3)) @ pinv
    cov = a @ belief.cov @ a.T
    return bl.Belief(belief.mean + p @ (mapped(theta) - theta), 0.5 * (cov + cov.T))


def saved_prior(out: Path, resume: bool, prior_from, correction):
    """A resumed re-check continues from the prior its start recorded (``PRIOR_RECORD``): the
    --prior-from run and --correction-applied, which --resume then need not repeat. A different
    --prior-from on resume is refused (the touches so far were planned from the recorded one),
    and so is one on resuming a run mapped from scratch (it has no record: its touches so far
    were planned from the cell's prior, and an earlier belief fused under them gives another
    plate's map)."""
    path = Path(out) / PRIOR_RECORD
    if resume and prior_from is not None and not path.exists():
        raise ValueError(f"--resume {out} --prior-from {prior_from}: {out} was mapped from "
                         f"scratch (it has no {PRIOR_RECORD}), not as a re-check; resume it "
                         "without --prior-from, or start a re-check in a new folder (adaptive-cal "
                         f"run --robot CELL.yaml --out NEW_DIR --prior-from {prior_from})")
    if not resume or not path.exists():
        return prior_from, correction
    try:
        rec = read_json(path)
        run, saved = rec["run"], rec["correction_applied"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: unreadable ({type(e).__name__}: {e}); pass --prior-from and "
                         "--correction-applied again") from None
    saved = saved if isinstance(saved, str) else tuple(float(v) for v in saved)
    given = correction if isinstance(correction, str) else tuple(float(v) for v in correction)
    if prior_from is not None and (Path(prior_from).resolve() != Path(run).resolve()
                                   or given != saved):
        raise ValueError(f"{out} is a re-check from {run} with the correction {saved!r} assumed "
                         f"applied, not from {prior_from} with {given!r}: resume it without "
                         "--prior-from (it continues from the recorded one), or start a new run")
    return run, saved


def load_prior(run_dir: Path, cell: Cell, correction: str | tuple[float, float] = "proposed"
               ) -> tuple[bl.Belief, Hyper, dict, list[bl.Belief]]:
    """An earlier run's belief, moved into the user frame corrected since (``correction``, see
    ``applied_correction``; default: the correction that run proposed), then widened by the
    drift allowance d = plan.drift_std_mm: the plate may have moved rigidly since (offset std
    d, slopes std d over half the plate diagonal) and its form may have changed by a quarter of
    that (form std d / 4, same length scale). A routine re-check then needs a handful of
    touches. Returns the belief, the hyper-parameters, the ``applied_correction`` record and
    the same belief in the frames not assumed (unmoved, and moved by the proposed correction
    where that was not the one assumed), widened alike: a correction assumed but not applied
    leaves the plate there (``planning.clearance.Guard`` keeps the probe clear of them)."""
    earlier, hyper = read_belief(run_dir, cell)
    info = applied_correction(run_dir, correction)
    model = plan_model(cell)
    frames = {(0.0, 0.0): earlier}
    said = [info] + ([] if info["assumed"] == "proposed" else _proposed(run_dir))
    for c in (s["correction_deg"] for s in said):
        key = (c["rx"], c["ry"])
        if key not in frames:
            frames[key] = corrected_belief(model, earlier, *key)
    c = info["correction_deg"]
    d = cell.plan.drift_std_mm
    wp = cell.workplane
    half = 0.5 * math.hypot(wp.x_mm[1] - wp.x_mm[0], wp.y_mm[1] - wp.y_mm[0])
    centre = (0.5 * sum(wp.x_mm), 0.5 * sum(wp.y_mm))  # the drift turns about the plate's middle
    drift = type(model)(model.surface, d / half, d, centre, hyper)
    # the drift's form is smooth (squared exponential) whatever kernel the map's form took
    extra = drift.belief(Hyper(d / 4, hyper.length_scale_mm, hyper.noise_std_mm)).cov
    widened = {k: bl.widen(b, extra) for k, b in frames.items()}
    assumed = widened.pop((c["rx"], c["ry"]))
    # each frame not assumed as --correction-applied would name it (a stop says which one the
    # readings agree with: ``matching_frame``)
    named = {(0.0, 0.0): "none", **{(s["correction_deg"]["rx"], s["correction_deg"]["ry"]):
                                    "proposed" for s in said[1:]}}
    info = {**info, "not_assumed": [named.get(k, f"{k[0]:g},{k[1]:g}") for k in widened]}
    return assumed, hyper, info, list(widened.values())


def _proposed(run_dir: Path) -> list[dict]:
    """The correction ``run_dir`` proposed, as ``applied_correction`` records it; none where
    its result.json has none."""
    try:
        return [applied_correction(run_dir, "proposed")]
    except ValueError:
        return []


def recheck_guard(plan, others: list[bl.Belief], assumed: bl.Belief, rec=None) -> Guard:
    """The guard of a re-check (``planning.clearance.Guard``): clear of the plate in the frames
    not assumed (``others``, from ``load_prior``) until readings where ``assumed`` puts the
    plate refute them, and of the plate the cell's own prior allows, told every reading; a
    resumed one (``rec``: its recording) counts the readings taken."""
    from adaptive_cal.planning.survey import start

    guard = Guard(plan, others, "a frame the re-check did not assume, or where the cell's own "
                  "prior lets it stand before readings bound it", assumed,
                  safety=start(plan).belief)
    for row in zip(rec.x_mm, rec.y_mm, rec.z_mm, rec.reading_mm) if rec is not None else ():
        guard.seen(*map(float, row))
    return guard


MATCH_Z = 4.0  # a frame agrees with the readings where none lies beyond this many sd of it


def matching_frame(plan, rec, assumed: bl.Belief, others: list[bl.Belief], carried: dict
                   ) -> str:
    """Which frame the readings inside the usable stroke agree with (each within ``MATCH_Z``
    predictive sd of the frame's belief, the probe's noise at the cell's guess in), named as
    --correction-applied takes it: the one assumed, one of the others, or none of them (the
    plate moved by more than a correction). '' where no reading lies inside the stroke."""
    lo, hi = plan.usable_mm
    inside = (rec.reading_mm >= lo) & (rec.reading_mm <= hi)
    if not inside.any():
        return ""
    height = rec.reading_mm[inside] + rec.z_mm[inside] - plan.zero_mm
    basis = plan.model.surface.basis(rec.x_mm[inside], rec.y_mm[inside])
    noise = plan.model.hyper0.noise_std_mm ** 2
    c = carried["correction_deg"]
    names = [carried["assumed"] if carried["assumed"] != "measured" else f"{c['rx']:g},{c['ry']:g}",
             *carried.get("not_assumed", [])]
    worst = []
    for frame in [assumed, *others]:
        mean, var = bl.predict(frame, basis)
        worst.append(float(np.max(np.abs(height - mean) / np.sqrt(var + noise))))
    agree = [name for name, w in zip(names, worst) if w <= MATCH_Z]
    n = f"the {int(inside.sum())} readings inside the probe's stroke"
    if not agree:
        return (f"{n} agree with none of the frames (--correction-applied "
                f"{' | '.join(names)}): the plate moved, so map it from scratch")
    if len(agree) > 1:
        both = " and ".join(f"--correction-applied {a}" + " (assumed)" * (a == names[0])
                            for a in agree)
        return f"{n} agree with {both} alike (they cannot tell those apart)"
    if agree[0] == names[0]:
        return f"{n} agree with the frame assumed"
    return f"{n} agree with --correction-applied {agree[0]}, not the frame assumed"


def disagreement(carried: dict, surprises: list[int], off_stroke: list[int] = (),
                 match: str = "") -> str:
    """Why a re-check stopped early, and what to do, in one sentence for the terminal.
    ``off_stroke``: seqs of touches whose reading left the probe's usable stroke where the
    belief put it mid-stroke (1 in 10^6): one is enough, and the next could overrun the
    stroke's end (an outside safety audit, 2026-11-29: a correction assumed but not applied
    drove the probe 1.19 mm past it, twice)."""
    c = carried["correction_deg"]
    seen = ([f"{len(surprises)} readings (seq {', '.join(map(str, surprises))}) were confirmed "
             "by their retake far outside its band"] if surprises else []) + (
        [f"the reading of seq {', '.join(map(str, off_stroke))} left the probe's usable stroke "
         "where that belief put it mid-stroke (below it: no contact; above it: the probe was "
         "pushed past its stroke's top, so check that it moves freely; the next touch could "
         "overrun it)"] if off_stroke else [])
    return (f"the plate is not where the earlier run's belief puts it in the frame assumed "
            f"({carried['assumed']}: rx {fixed(c['rx'], 4, '+')} deg, ry "
            f"{fixed(c['ry'], 4, '+')} deg): "  # never "-0.0000"
            + "; ".join(seen) + (f"; {match}" if match else "") + ". Not a result: give "
            "the correction that was "
            "really applied (--correction-applied proposed | none | RX,RY), or map from scratch "
            "without --prior-from")


def frame_shift_mm(run_dir: Path, cell: Cell, correction="proposed") -> float:
    """How far apart (mm) the earlier run's plate stands in the frame assumed and in the others
    a re-check keeps clear of (``load_prior``: unmoved, and moved by the proposed correction
    where that is not the one assumed): the largest |difference of the means| on a 21 x 21 grid,
    edges included; 0 where there is no other. Where it passes the usable stroke's half width,
    a plain approach could run past the stroke's end were the frame assumed the wrong one: the
    run approaches in steps (``planning.clearance.Guard``) and says so first
    (``cli.run_guards.shift_note``)."""
    assumed, _, _, others = load_prior(run_dir, cell, correction)
    if not others:
        return 0.0
    model = plan_model(cell)
    (x0, x1), (y0, y1) = cell.workplane.x_mm, cell.workplane.y_mm
    x, y = (v.ravel() for v in np.meshgrid(np.linspace(x0, x1, 21), np.linspace(y0, y1, 21)))
    rows = model.surface.basis(x, y)
    return max(float(np.max(np.abs(rows @ (o.mean - assumed.mean)))) for o in others)


def provisional_note(run_dir: Path) -> str | None:
    """What an earlier run's map lacks where that run was not a result (``report.status``):
    a re-check or a survey from it starts from a provisional map (an outside audit: a run that
    stopped with readings_disagree after 4 fused readings, its map 1.3 mm off, was taken
    without a word). None for a finished run or one without result.json."""
    from adaptive_cal.report.status import missing

    path = Path(run_dir) / "result.json"
    if not path.is_file():
        return None
    why = missing(read_json(path))
    return (f"{run_dir} was not a result ({why}): its map is provisional, and a survey from it "
            "starts from that" if why else None)
