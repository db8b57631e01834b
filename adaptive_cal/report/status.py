"""Whether a run's result is a result: what is missing from an unfinished run, in one line.

A run is finished when it stopped on its bound (or spent the touch budget of a cell file that
sets no bound) and every bound it sets is met. An interrupted run, one whose planner found no
admissible point, or one that spent its budget with a bound not met is not: the terminal summary
and the HTML report open with ``missing(result)`` and call the tilt correction provisional.
Reads result.json's dict only; standard library only (the CLI imports it).
"""
from __future__ import annotations

WHY = {
    "interrupted": "interrupted",
    "touch_budget": "touch budget spent",
    "no_admissible_point": "stopped: no admissible point",
    "invalid_readings": "stopped: 3 invalid readings in a row (NaN, infinite or off the plate)",
    "touches_rejected": "stopped: the touches gave no usable reading (3 in a row at the probe's "
                        "stroke's end or with their samples spread, or one past the stroke's top "
                        "whose approach would overrun it again)",
    "readout_frozen": "stopped: the probe read the very same value touch after touch (a "
                      "frozen readout)",
    "readings_disagree": "stopped: two touches in a row at one place were held back by the "
                         "gate and their retakes disagreed with them (the readings agree neither "
                         "with the map nor with each other)",
    "prior_disagrees_with_readings": "stopped: the readings contradict the earlier belief "
                                     "(--prior-from) in the frame assumed",
    "drift": "stopped: the cell drifted during the run (the closure touch read the first place "
             "again and the reading had moved beyond the noise)",
}
# reasons that --resume does not cure: what to do instead
INSTEAD = {
    "prior_disagrees_with_readings": "give the correction really applied (--correction-applied "
                                     "proposed | none | RX,RY) or map from scratch without "
                                     "--prior-from, in a new folder",
    "touches_rejected": "check that the plate is where the cell file puts it (workplane z, "
                        "the tilt, the probe's zero and usable stroke: a reading at the stroke's "
                        "end means the approach height is off the plate) and that the probe "
                        "moves freely, then map again in a new folder",
    "readout_frozen": "check that the probe's readout is live (the gauge's cable and port, "
                      "the PLC's register and handshake: the value must change with the tip), "
                      "then continue with --resume (the first few repeats were fused before they "
                      "were seen to repeat; those flagged frozen;rejected were not)",
    "readings_disagree": "see the error: state the probe's noise where the readings are "
                         "noisier than the map assumed (probe.noise_std_mm, noise_range_mm), or "
                         "check that the plate, fixture and probe hold still, then map again in "
                         "a new folder",
    "drift": "warm the cell up (run the robot over the plate for as long as the drift took) and "
             "map again in a new folder, or model the drift: adaptive-cal explain on the "
             "recording",
}
# reasons after which a run may be complete (when no bound is left unmet)
FINISHING = ("mean_std_bound", "max_std_bound", "touch_budget", "at_least")


def unmet_bounds(result: dict) -> list[str]:
    """Each bound of the cell file the run does not meet, as words with units: the posterior
    stds, the largest gap (``plan.stop.max_gap_mm``), and where a std bound is set the touch
    floor (a bound met on fewer touches rests on too few readings) and the model's self-checks
    (a bound never stops a run whose model they call inadequate), said where the stds are
    met -- the stop rule's own terms: a budget spent with any of them open is not a result."""
    bound, post = result.get("bound", {}), result["posterior"]
    out = []
    for key, name in (("mean_std_mm", "posterior RMS std"), ("max_std_mm", "posterior max std")):
        b = bound.get(key)
        if b is not None and post[key] > b:
            out.append(f"{name} {post[key] * 1e3:.1f} um against the {b * 1e3:g} um bound"
                       + (f" (plan.stop.{key}'s default: the cell file sets none)"
                          if key in bound.get("defaulted", ()) else ""))
    gap, radius = bound.get("max_gap_mm"), (result.get("largest_gap") or {}).get("radius_mm")
    if gap is not None and radius is not None and radius > gap:
        out.append(f"largest gap between touches {radius:.0f} mm radius against the {gap:g} mm "
                   "bound (plan.stop.max_gap_mm)")
    stds = [key for key in ("mean_std_mm", "max_std_mm") if bound.get(key) is not None]
    if stds and not out:  # the stds met: what else a bound stop would have waited for
        floor = bound.get("min_touches") or 0
        if result["touches"] < floor:
            out.append(f"{result['touches']} touches, fewer than the {floor} a bound needs "
                       "before it may stop a run (the touch floor: plan.stop.min_touches)")
        if (result.get("model") or {}).get("adequate") is False:
            out.append("the model's self-checks fail (model.adequate false: see the model line)")
    return out


def missing(result: dict) -> str | None:
    """None for a finished run; else one line saying what is missing, e.g. "interrupted after 9
    touches; posterior RMS std 39.0 um against the 4 um bound"."""
    why = result["stopped_because"]
    unmet = unmet_bounds(result)
    if why in FINISHING and not unmet:
        return None
    from adaptive_cal.formats.numbers import count

    touches = count(result['touches'], 'touch', 'touches')
    text = f"{WHY.get(why, why.replace('_', ' '))} after {touches}"
    late = result.get("recorded_not_fused")  # a second Ctrl-C: recorded, not yet in the map
    late = [f"{count(late, 'touch', 'touches')} more in the recording, stopped before it was "
            "fused: --resume fuses it"] if isinstance(late, int) and late > 0 else []
    return "; ".join([text] + late + unmet)


def exit_status(result: dict) -> int:
    """``adaptive-cal run``'s exit status: 130 interrupted (``--resume`` continues it), 1 where
    the map is not a result (``missing``: drift, rejected touches or readings, a budget spent or
    no admissible point with a bound unmet) -- a script must not use it --, else 0."""
    if result["stopped_because"] == "interrupted":
        return 130
    return 1 if missing(result) is not None else 0


def next_step(result: dict, resume: str | None) -> str:
    """What to do with an unfinished run, one sentence: ``resume`` is the command that continues
    it (None when nothing continues it, e.g. a page built from a recording)."""
    instead = INSTEAD.get(result.get("stopped_because", ""))
    if instead:
        return instead[0].upper() + instead[1:]
    if resume and result.get("error_is") == "UnsafeTarget":  # the same travel, refused again
        return (f"Continue with {resume} --robot CHANGED.yaml, a copy of the run's cell.yaml "
                "changed as the error says (robot.safe_height_mm and workspace.z_mm may differ on "
                "a resume; --resume alone asks the same move and is refused again)")
    box = result.get("out_of_box")
    if box and result.get("stopped_because") in ("touch_budget", "no_admissible_point"):
        return box["text"][0].upper() + box["text"][1:]  # a larger budget maps no more of it
    if resume and result.get("stopped_because") == "touch_budget":  # --resume alone stops again
        return (f"Continue with {resume} --robot MORE.yaml, a copy of the run's cell.yaml with a "
                "larger plan.stop.max_touches")
    if resume:
        return f"Continue with {resume}"
    return "Take more touches until the bound is met"


def quoted(path) -> str:
    """A path as a command to copy needs it: quoted for a POSIX shell where it has spaces or
    other special characters (``run --resume 'my runs/plate 1'``), else as it is."""
    import shlex

    return shlex.quote(str(path))


def unfinished(run_dir, name: str) -> str:
    """What to do about a run folder missing ``name``: a folder with its recording and cell
    but not its results stopped before writing them (``run --resume`` writes them); one with
    result.json but not belief.npz lost it since; else it is not a folder ``run --out`` wrote."""
    from pathlib import Path

    from adaptive_cal.formats.lockfile import busy_by

    run_dir = Path(run_dir)
    if name in ("result.json", "belief.npz") and busy_by(run_dir) is not None:
        return (f"a run (pid {busy_by(run_dir)}) is going on in {run_dir} and writes its "
                "results when it stops: wait for it")
    if name in ("result.json", "belief.npz") and (run_dir / "recording.csv").is_file() \
            and (run_dir / "cell.yaml").is_file():
        replay = (f"without the robot, adaptive-cal report {quoted(run_dir / 'recording.csv')} "
                  f"--robot {quoted(run_dir / 'cell.yaml')} replays the touches taken")
        if name == "belief.npz" and (run_dir / "result.json").is_file():
            return ("the run finished (its result.json is there) but belief.npz was removed or "
                    f"not copied with it: copy it back, or, {replay}")
        return (f"the run stopped before writing its results; adaptive-cal run --resume "
                f"{quoted(run_dir)} writes them (it moves the robot on), or, {replay}")
    return f"is {run_dir} a folder written by 'adaptive-cal run --out DIR'?"
