"""What ``adaptive-cal run`` checks before a folder is touched: a resume's cell against the one
the folder was mapped with, a re-check's earlier run folder."""
from __future__ import annotations

import sys
from pathlib import Path

from adaptive_cal.cli.common import UserError
from adaptive_cal.report.status import quoted


#: keys of a cell that may differ on --resume: they change neither the map nor the touches (the
#: run's name, how long it goes on, how the robot and probe are reached and timed)
RESUME_MAY_DIFFER = ("name", "plan.stop.", "robot.speed_mm_per_s", "robot.touch_time_s",
                     "robot.safe_height_mm", "robot.manual.", "robot.hses.", "robot.modbus.",
                     "robot.robodk.", "probe.serial.", "probe.modbus.", "probe.settle_s",
                     "workspace.z_mm")  # the box's height: what a refused travel asks raised
#: ... except where a key moves the frame the touches are taken in, or how a length is read: a
#: resume with robot.hses.offset_mm 50 um lower read every new touch 50 um off, and was told it
#: changed nothing (an outside audit, 2026-12-02); these must be the recording's own
RESUME_MAY_NOT_DIFFER = ("robot.hses.offset_mm", "robot.hses.frame", "robot.hses.user_frame",
                         "robot.hses.user_frame_in_base", "robot.hses.tool",
                         "robot.hses.orientation_deg", "robot.modbus.scale",
                         "robot.modbus.number", "robot.modbus.word_order", "probe.modbus.scale",
                         "probe.modbus.number", "probe.modbus.word_order", "probe.serial.scale")


def _flat(value, prefix: str = "") -> dict:
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out if out or not prefix else {prefix[:-1]: value}
    return {prefix[:-1]: value}


def _differ(was: dict, now: dict) -> tuple[list[str], list[str]]:
    """The keys two flattened cells differ in: (those that change the map or the touches,
    those that do not -- ``RESUME_MAY_DIFFER``)."""
    differ = [k for k in sorted(set(was) | set(now)) if was.get(k) != now.get(k)]
    bad = [k for k in differ if not any(k == m or k.startswith(m) for m in RESUME_MAY_DIFFER)
           or any(k == m or k.startswith(m + ".") for m in RESUME_MAY_NOT_DIFFER)]
    return bad, [k for k in differ if k not in bad]


def _cells(was_path: Path, given: Path, load_was=None) -> tuple[dict, dict]:
    """Both cells flattened; ``load_was`` reads the first (default ``load_cell``)."""
    from adaptive_cal.cell.schema import load_cell

    was = (load_was or load_cell)(was_path)
    return tuple(_flat(c.model_dump(mode="json")) for c in (was, load_cell(given)))


def replay_cell_warning(recording: Path, given: Path) -> str | None:
    """A recording of a run folder replayed with another cell file (``flatness`` and
    ``report`` with --robot): the keys where it differs from the folder's cell.yaml in what
    changes the map, as a warning line (None where it does not, or the recording is in no run
    folder). Allowed -- a corrected probe zero, say -- but said: the figures are not the run's."""
    folder = Path(recording).parent
    if not (folder / "cell.yaml").is_file() or \
            (folder / "cell.yaml").resolve() == Path(given).resolve():
        return None
    from adaptive_cal.cell.run_cell import load_run_cell

    bad, _ = _differ(*_cells(folder / "cell.yaml", Path(given), load_run_cell))
    if not bad:
        return None
    more = f" and {len(bad) - 4} more" if len(bad) > 4 else ""
    return (f"warning: {recording} was mapped with {folder / 'cell.yaml'}; --robot {given} differs "
            f"from it in what changes the map ({', '.join(bad[:4])}{more}): the figures are a "
            "replay with the file given, not the run's")


def same_cell(out: Path, given: Path) -> None:
    """--resume DIR --robot CELL.yaml: CELL must be the cell DIR was mapped with (DIR/cell.yaml)
    in everything that changes the map or the touches (the knots, the workplane, the probe, the
    prior, the plan, the simulation), else the old touches would be fused into another map while
    DIR/cell.yaml stays the old one. Raises UserError naming the keys that differ."""
    was, now = _cells(out / "cell.yaml", given)
    bad, fine = _differ(was, now)
    differ = sorted(bad + fine)
    if bad:
        shown = "; ".join(f"{k}: {was.get(k)!r} in {out / 'cell.yaml'}, {now.get(k)!r} in {given}"
                          for k in bad[:6]) + (f"; and {len(bad) - 6} more" if len(bad) > 6 else "")
        raise UserError(f"--resume {out} --robot {given}: not the cell {out} was mapped with, it "
                        f"differs in {shown}. The touches in {out}/recording.csv belong to "
                        f"{out / 'cell.yaml'}: resume without --robot (adaptive-cal run --resume "
                        f"{quoted(out)}), or map with {given} into a new folder (adaptive-cal run "
                        f"--robot {quoted(given)} --out NEW_DIR)")
    if differ:
        print(f"resuming with {given}, which differs from {out / 'cell.yaml'} only in "
              f"{', '.join(differ)} (neither the map nor the touches change; {out / 'cell.yaml'} "
              "is kept as it is)")


def check_prior_from(prior: Path, correction) -> None:
    """--prior-from RUN_DIR must be a run folder with its map (and, for the proposed correction,
    its result.json): say so plainly, not as an OS error on a file in it."""
    if not prior.exists():
        raise UserError(f"--prior-from {prior}: no such run folder")
    if not prior.is_dir():
        raise UserError(f"--prior-from {prior}: a file, not a run folder (give the folder an "
                        "earlier 'adaptive-cal run --out DIR' wrote)")
    if correction == "proposed" and not (prior / "result.json").is_file():
        raise UserError(f"--prior-from {prior}: it has no result.json, so no proposed tilt "
                        "correction to assume applied; pass the applied one as "
                        "--correction-applied RX,RY (deg), or none")
    if not (prior / "belief.npz").is_file():
        raise UserError(f"--prior-from {prior}: not a run folder with a map, it has no "
                        "belief.npz (give the folder an earlier 'adaptive-cal run --out DIR' "
                        "wrote)")
    from adaptive_cal.run.recheck import provisional_note

    note = provisional_note(prior)
    if note:
        print(f"warning: --prior-from {note}", file=sys.stderr)


def refuse_stale_map(folder: Path, command: str) -> None:
    """UserError where the run folder's map (belief.npz) is not the map of its recording and
    result.json: the recording holds more touches (a resumed run stopped by a kill before it
    wrote them again: an outside audit saw 20-touch figures under a 104-touch recording, exit
    0), fewer, or other rows than the map was made from (a row deleted or edited since: its
    reading stayed in the map), or result.json is of another count of touches (a kill between
    the two writes: report showed one, flatness the other). The message names what differs and
    how to get one consistent answer."""
    from adaptive_cal.formats.jsonfile import read_json
    from adaptive_cal.formats.npz import read_npz
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.formats.writing import rows_digest

    saved = read_npz(folder / "belief.npz", keys=(), optional=("touches", "recording_sha256"))
    if "touches" not in saved:  # a map saved before the count was: nothing to compare
        return
    map_touches = int(saved["touches"])
    rec = folder / "recording.csv"
    data = read_recording(rec)
    rows = len(data)
    replay = (f"adaptive-cal report {quoted(rec)} --robot {quoted(folder / 'cell.yaml')}"
              if command == "report" else
              f"adaptive-cal flatness {quoted(rec)} --robot {quoted(folder / 'cell.yaml')}")
    if rows > map_touches:
        try:
            late = read_json(folder / "result.json").get("recorded_not_fused")
        except (OSError, ValueError, AttributeError):
            late = None
        why = ("the run was stopped at once (a second Ctrl-C) after it recorded them, before it "
               "fused them" if late == rows - map_touches else "the run went on after it was "
               "saved (a resume) and was stopped before it saved again")
        raise UserError(f"{rec} holds {rows} touches, but the map saved beside it (result.json, "
                        f"belief.npz) is of the first {map_touches}: {why}. To use "
                        f"every touch, replay the recording: {replay}; or finish the run: "
                        f"adaptive-cal run --resume {quoted(folder)}")
    digest = str(saved["recording_sha256"]) if "recording_sha256" in saved else None
    if rows < map_touches or (digest is not None and rows_digest(data, rows) != digest):
        raise UserError(f"{rec} is not the recording the map saved beside it (belief.npz, "
                        f"result.json) was made from: it holds {rows} rows, the map "
                        f"{map_touches}{'' if rows < map_touches else ', with other values'} "
                        "(a row deleted or edited since?), and the map still holds what the "
                        f"recording no longer does. Replay the recording as it is: {replay}")
    try:
        said = read_json(folder / "result.json").get("touches")
    except (OSError, ValueError, AttributeError):
        return  # no result.json (a kill before it): the commands that need it say so
    if type(said) is int and said != map_touches:  # another type: the reader names the key
        raise UserError(f"{folder / 'result.json'} is of {said} touches, belief.npz of "
                        f"{map_touches}: the run was stopped while it saved its results. "
                        f"adaptive-cal run --resume {quoted(folder)} saves them again whole")


def shift_note(run_dir: Path, cell, correction) -> str | None:
    """A line for the terminal where the frames a re-check keeps clear of lie far apart: the
    correction moves the earlier plate by more than the probe's usable stroke leaves either
    side of mid-stroke, so were the frame assumed the wrong one, a plain approach would run
    the probe past its stroke's end (an outside safety audit, 2026-11-29: 2 deg about an origin
    525 mm away, 18 mm, the first touch 13 mm past it). The run then approaches in steps from
    above the other frame's plate (``planning.clearance.Guard``). None where they lie close."""
    from adaptive_cal.run import recheck

    lo, hi = cell.probe.usable_mm
    try:
        shift = recheck.frame_shift_mm(run_dir, cell, correction)
    except (OSError, ValueError):  # the run itself says what is wrong with the earlier run
        return None
    if shift <= 0.5 * (hi - lo):
        return None
    return (f"the correction moves the earlier plate by up to {shift:.2f} mm, more than the "
            f"probe's usable stroke leaves either side of mid-stroke ({0.5 * (hi - lo):.2f} mm): "
            "until the readings tell the frames apart, each touch is approached in steps from "
            "above where the plate would stand in the other frame (none applied, or the "
            "proposed one), and travels clear it")


#: the relaxed design behind ``unreachable_bound`` is solved up to this many spline coefficients
#: (30 take 0.2 s; 256 took 20 s and 576 80 s on the 2-core machine: no warning there)
DESIGN_MAX_COEFFICIENTS = 150


def unreachable_bound(cell) -> str | None:
    """A warning where the cell's RMS std bound (``plan.stop.mean_std_mm``) lies below what its
    touch budget can reach: the relaxed optimal design of ``plan.stop.max_touches`` touches at
    the least noise the cell allows (``probe.noise_range_mm``'s low end, else
    ``probe.noise_std_mm``) has a larger RMS posterior std, so no design meets the bound and the
    run spends its whole budget (an outside audit: a 0.2 um bound with a 3-8 um probe ran 150
    touches, 8 min of robot time, to end INCOMPLETE at 1.4 um). None where it is reachable.
    The design is solved only where the bound is below sigma sqrt(K / n) (K spline
    coefficients, n touches): above that the G-optimal design's largest variance, K sigma^2 / n
    (Kiefer-Wolfowitz), already meets it, and so does the RMS of the best design."""
    import math

    from adaptive_cal.cell.build import prior_model
    from adaptive_cal.gaussian.belief import rms_std_from_integrated_variance
    from adaptive_cal.study.bound import design_problem, relaxed_integrated_variance

    stop, probe = cell.plan.stop, cell.probe
    bound, n = stop.mean_std_mm, stop.max_touches
    sigma = probe.noise_range_mm[0] if probe.noise_range_mm else probe.noise_std_mm
    if bound is None or not sigma or sigma <= 0:
        return None
    try:  # a warning: it never stops a run, whatever the cell
        model = prior_model(cell)
        k = model.surface.size
        if bound >= sigma * math.sqrt(k / n) or k > DESIGN_MAX_COEFFICIENTS:
            return None
        prob = design_problem(cell, model, model.hyper0._replace(noise_std_mm=sigma),
                              candidates=400)
        floor = float(rms_std_from_integrated_variance(
            relaxed_integrated_variance(prob, n, iterations=60), prob.area_mm2))
    except Exception:  # noqa: BLE001 -- the run's own checks speak for a cell this cannot plan
        return None
    if bound >= floor:
        return None
    said = ("probe.noise_range_mm's low end" if probe.noise_range_mm else "probe.noise_std_mm")
    return (f"warning: plan.stop.mean_std_mm={bound:g} mm is out of reach of "
            f"plan.stop.max_touches={n}: with reading noise of {sigma * 1e3:g} um ({said}) no "
            f"design of {n} touches brings the RMS posterior std below {floor * 1e3:.2f} um "
            f"(relaxed optimal design), so the run will spend its whole budget (at least "
            f"{n * cell.robot.touch_time_s / 60:.0f} min of touching) and end incomplete; "
            "raise the bound or the budget")
