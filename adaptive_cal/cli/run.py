"""``adaptive-cal run``: map a workplane on the cell a cell file describes."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

from adaptive_cal.cli.common import UserError, check_cell_file
from adaptive_cal.cli.run_guards import check_prior_from, same_cell, shift_note
from adaptive_cal.report.status import quoted


def add_arguments(p) -> None:
    p.add_argument("--robot", metavar="CELL.yaml", help="cell file (configs/sim-cell.yaml is the "
                   "built-in simulated cell); with --resume it defaults to DIR/cell.yaml")
    p.add_argument("--out", metavar="DIR", help="output folder: recording.csv, result.json, "
                   "surface.png, convergence.png, belief.npz, cell.yaml")
    p.add_argument("--resume", metavar="DIR", help="continue an interrupted run from DIR/recording.csv")
    p.add_argument("--prior-from", metavar="RUN_DIR", help="re-check: start from an earlier run's "
                   "belief, moved into the user frame corrected since (--correction-applied) and "
                   "widened by plan.drift_std_mm (mm)")
    p.add_argument("--correction-applied", metavar="proposed|none|RX,RY", help="with --prior-from: "
                   "the user-frame correction applied since RUN_DIR, rotx(RX) roty(RY) about the "
                   "frame origin: 'proposed' (the default: RUN_DIR's result.json tilt, deg), "
                   "'none' (not applied), or the measured angles RX,RY in deg, e.g. 0.11,-0.80")
    p.add_argument("--dry-run", action="store_true", help="plan and print the first touches, move nothing")
    p.add_argument("--yes", action="store_true", help="do not ask before moving a real robot")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def command(args) -> int:
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.hardware.base import AdapterError
    from adaptive_cal.run import recheck, session

    if args.robot:
        check_cell_file(args.robot)
    if args.dry_run:
        if not args.robot:
            raise UserError("--dry-run needs --robot CELL.yaml")
        if args.resume or args.prior_from:
            raise UserError(f"--dry-run plans a fresh run from the cell file; it does not "
                            f"continue {'--resume' if args.resume else '--prior-from'} (leave "
                            "--dry-run out to run it)")
        from adaptive_cal.cli.dry_run import dry_run

        cell = _doubted(load_cell(args.robot))
        _warn_unreachable(cell)
        return dry_run(cell)
    if args.resume:
        if args.out:  # a resumed run goes on in its own folder
            raise UserError(f"--resume {args.resume} goes on in that folder: leave --out out")
        out = Path(args.resume)
        if not out.is_dir():
            raise UserError(f"--resume {out}: {'a file, not a' if out.exists() else 'no such'} "
                            "folder (give the folder an interrupted 'adaptive-cal run --out DIR' "
                            "wrote)")
        rec = out / "recording.csv"
        if not rec.exists() or rec.stat().st_size == 0:  # before its cell.yaml is looked for
            again = (f"; a run stopped there before it recorded anything starts again with "
                     f"adaptive-cal run --robot {quoted(out / 'cell.yaml')} --out {quoted(out)}"
                     if (out / "cell.yaml").is_file() else "")
            raise UserError(f"--resume {out}: " + ("no recording.csv there" if not rec.exists()
                                                   else "recording.csv:1: an empty file")
                            + ", nothing to resume (give the folder an interrupted "
                            f"'adaptive-cal run --out DIR' wrote){again}")
        cell_path = Path(args.robot) if args.robot else out / "cell.yaml"
        if args.robot and (out / "cell.yaml").exists():
            same_cell(out, cell_path)
    else:
        if not args.robot or not args.out:
            raise UserError("run needs --robot CELL.yaml and --out DIR (or --resume DIR)")
        out, cell_path = Path(args.out), Path(args.robot)
    informed = bool(args.prior_from) or (out / "prior_from.json").exists()  # a re-check's
    cell = _doubted(load_cell(cell_path), informed_prior=informed)
    real = cell.robot.adapter not in ("sim", "manual") and not getattr(cell.robot, "emulated", False)
    if real and not args.yes:
        if not sys.stdin.isatty():
            raise UserError(f"{cell_path} drives a real robot ({cell.robot.adapter}): pass --yes to "
                            "confirm, or --dry-run to see the plan first")
        answer = input(f"Move the robot of '{cell.name}' ({cell.robot.adapter})? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            print("nothing moved", file=sys.stderr)
            return 1
    created = None  # (folders this run made, names --out held before)
    if not args.resume and not args.prior_from:
        _warn_unreachable(cell)
    from adaptive_cal.formats.lockfile import busy_by

    if busy_by(out) is not None:  # before "exists: --resume", which would then say "in use"
        raise UserError(f"{out} is in use by another run (pid {busy_by(out)}): wait for it to "
                        "end (or give this run another --out)")
    if not args.resume:
        if (out / "recording.csv").exists() and (out / "recording.csv").stat().st_size:
            raise UserError(f"{out}/recording.csv exists: continue it with --resume {out}, or "
                            "choose another --out")  # (empty: a start killed before its header)
        held = [n for n in ("result.json", "belief.npz") if (out / n).exists()]
        if held:  # another run's results, its recording moved away: never overwritten
            raise UserError(f"{out} holds {' and '.join(held)} of another run: another --out")
        theirs = [n for n in RUN_FILES if (out / n).exists()
                  and not (n == "cell.yaml" and _ours(out / n, cell_path))]
        if theirs:  # a run writes these names: a user's own files of that name are never lost
            raise UserError(f"{out} holds {', '.join(theirs)}, which a run writes: choose "
                            "another --out, or move them away")
        folders = [d for d in (out, *out.parents) if not d.exists()][::-1]
        before = {p.name for p in out.iterdir()} if out.is_dir() else set()
        created = (folders, before)
    correction = _correction(args)
    if args.prior_from and not args.resume:  # a resume keeps its own prior (recheck.saved_prior)
        check_prior_from(Path(args.prior_from), correction)
    if args.resume:
        try:
            was, c = recheck.saved_prior(out, True, args.prior_from, correction)
        except ValueError as e:
            raise UserError(str(e)) from None
        if was is not None and not args.prior_from:
            print(f"resuming the re-check from {was} (correction assumed applied: {c})")
    if args.prior_from:
        try:
            c = recheck.applied_correction(Path(args.prior_from), correction)
        except ValueError as e:
            raise UserError(str(e)) from None
        from adaptive_cal.report.sections import signed

        print(f"re-check from {args.prior_from}: correction assumed applied ({c['assumed']}): "
              f"rx {signed(c['correction_deg']['rx'], 4)} deg, ry "
              f"{signed(c['correction_deg']['ry'], 4)} deg")
        note = shift_note(Path(args.prior_from), cell, correction)
        if note:
            print(note)
    try:
        # the cell file is copied only once the session holds the folder's lock
        result = session.run(cell, out, resume=bool(args.resume), prior_from=args.prior_from,
                             correction_applied=correction,
                             progress=not args.no_progress,
                             before_start=None if args.resume else lambda: _copy_cell(out, cell_path))
    except BaseException as e:
        from adaptive_cal.run.folder import RunFolderBusy

        # a folder another run holds is that run's: leave everything in it as it is
        undone = (created is not None and not isinstance(e, RunFolderBusy)
                  and _undo_if_empty(out, created))
        if undone and isinstance(e, AdapterError):
            said = str(e).replace("then continue with --resume", "then run the same command "
                                  "again")  # nothing to resume: no two answers that disagree
            raise UserError(f"{said}.\nNothing was recorded, and {out} is left as it was before: "
                            "once the cause is fixed, run the same command again (not --resume)") from e
        if isinstance(e, AdapterError) and getattr(e, "result", None):
            from adaptive_cal.hardware.base import ProbeLeftDown

            if isinstance(e, ProbeLeftDown):  # the danger first, then what was measured
                notes = "".join(f"\n  {n}" for n in getattr(e, "__notes__", ()))
                print(f"adaptive-cal run: error: {e}{notes}", file=sys.stderr, flush=True)
                _summary(e.result, out, cell)
                return 130 if e.interrupted else 2
            _summary(e.result, out, cell)  # the touches a device failure left: INCOMPLETE
            sys.stdout.flush()  # before the error on stderr, which names the device
        raise
    if result.get("already_finished"):
        print(f"{out} is already finished ({result['already_finished']} after "
              f"{result['touches']} touches): nothing to do, nothing changed")
        return 0
    _summary(result, out, cell)
    if result.get("prior_from", {}).get("disagreement"):
        print(f"re-check stopped: {result['prior_from']['disagreement']}")
        return 1
    from adaptive_cal.report.status import exit_status

    return exit_status(result)  # 1 where the map is not a result: the summary said why


def _doubted(cell, informed_prior: bool = False):
    """``cell``, its doubtful settings (``cell.build.cell_doubts``) warned on stderr."""
    from adaptive_cal.cell.build import cell_doubts

    for line in cell_doubts(cell, informed_prior=informed_prior):
        print(f"warning: {line}", file=sys.stderr)
    return cell


def _correction(args):
    """--correction-applied as session.run takes it: 'proposed', 'none' or (rx, ry) in deg."""
    text = args.correction_applied
    if text is None:
        return "proposed"
    if not args.prior_from:
        raise UserError("--correction-applied needs --prior-from RUN_DIR")
    if text.strip() in ("proposed", "none"):
        return text.strip()
    try:
        rx, ry = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--correction-applied {text!r}: expected proposed, none or RX,RY in deg "
                        "(two numbers, e.g. 0.11,-0.80)") from None
    if not all(abs(v) <= 10 for v in (rx, ry)):  # also refuses nan and inf
        raise UserError(f"--correction-applied {text!r}: each angle must be finite and within "
                        "+-10 deg")
    return rx, ry


# files a run writes in --out besides its recording and results (refused if there before)
RUN_FILES = ("cell.yaml", "surface.png", "convergence.png")


def _ours(copy: Path, cell_path: Path) -> bool:
    """Whether the cell.yaml in a folder is the cell file itself, or the very copy a run with
    it writes (a start killed before its first touch left it: the same command goes on)."""
    if copy.resolve() == cell_path.resolve():
        return True
    try:
        return copy.read_bytes() == _copy_text(cell_path).encode("utf-8")
    except (OSError, ValueError):
        return False


def _copy_text(cell_path: Path) -> str:
    """The text ``_copy_cell`` writes."""
    import yaml

    from adaptive_cal.cell.schema import load_yaml, resolve_files

    data = load_yaml(cell_path)
    resolved = resolve_files(data, cell_path)  # the map named relative to the cell file
    if resolved is data:
        return cell_path.read_bytes().decode("utf-8")
    return (f"# copied from {cell_path} by adaptive-cal run; simulation.surface_file made "
            "absolute\n" + yaml.safe_dump(resolved, sort_keys=False, allow_unicode=True))


def _copy_cell(out: Path, cell_path: Path) -> None:
    """Copy the cell file into --out (the run folder keeps the cell it was run with). A height
    map named relative to the cell file (simulation.surface_file) is written as an absolute path
    in the copy, so --resume and report find it from the run folder."""
    if cell_path.resolve() != (out / "cell.yaml").resolve():
        (out / "cell.yaml").write_bytes(_copy_text(cell_path).encode("utf-8"))


def _undo_if_empty(out: Path, created: tuple[list[Path], set[str]]) -> bool:
    """After a failed start (a device that does not answer, Ctrl-C before the first touch):
    when no touch was recorded, remove what this run put in --out (and the folders it made),
    so the same command can be retried (returns True). A recording with touches stays: --resume
    continues it (returns False)."""
    folders, before = created
    if not out.is_dir() or _has_touches(out / "recording.csv"):
        return False
    for path in out.iterdir():
        if path.name not in before:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    for folder in reversed(folders):
        try:
            folder.rmdir()  # only when empty
        except OSError:
            break
    return True


def _has_touches(rec: Path) -> bool:
    if not rec.exists():
        return False
    with rec.open(encoding="utf-8", errors="replace") as f:
        rows = [line for line in f if line.strip() and not line.startswith("#")]
    return len(rows) > 1  # the header, then one row per touch


def _warn_unreachable(cell) -> None:
    """Say before anything moves where the bound is out of the budget's reach."""
    from adaptive_cal.cli.run_guards import unreachable_bound

    said = unreachable_bound(cell)
    if said:
        print(said, file=sys.stderr)


def _summary(r: dict, out: Path, cell=None) -> None:
    """The run's summary on stdout; ``cell``: the cell run (its robot speed and touch time, the
    model of the estimated robot time)."""
    from adaptive_cal.analysis.flatness_answer import answer_lines
    from adaptive_cal.report.sections import percent, signed, stopped_text, tilt_angles
    from adaptive_cal.formats.numbers import count
    from adaptive_cal.report.status import missing, next_step, quoted

    gap = missing(r)
    t, p = r["tilt"], r["posterior"]
    then = next_step(r, f"adaptive-cal run --resume {quoted(out)}")
    lines = [f"INCOMPLETE: {gap}. Not a result. {then}"] if gap else []
    lines += [
        f"stopped: {stopped_text(r['stopped_because'])} after "
        f"{count(r['touches'], 'touch', 'touches')} "
        f"({r['fused']} fused)",
        f"posterior std: RMS {p['mean_std_mm'] * 1e3:.2f} um, max {p['max_std_mm'] * 1e3:.2f} um",
        r.get('model', {}).get('summary') or 'model: not checked',
        *(k["text"] for k in r.get("keep_outs") or []),
        *([r["out_of_box"]["text"]] if r.get("out_of_box") and r["out_of_box"]["text"] not in then
          else []),
        *([r["closure"]["text"]] if r.get("closure") else []),
        f"tilt correction{' (provisional)' if gap else ''}: {tilt_angles(t)}; a {signed(t['a'], 6)}, "
        f"b {signed(t['b'], 6)} mm/mm, c {signed(t['c'], 4)} mm",
    ]
    lines += answer_lines(r, provisional=bool(gap))
    if "truth" in r:
        tr = r["truth"]
        lines.append(f"true error: RMS {tr['rms_error_mm'] * 1e3:.2f} um, max "
                     f"{tr['max_error_mm'] * 1e3:.2f} um, 95 % band covers "
                     f"{percent(tr['coverage95'])} of the plate")
    if r.get("robot_time_s") is not None:  # touches and robot time side by side
        # an estimate from the travel and the touch time, not the recording's clock (t_s)
        how = (f" at {cell.robot.speed_mm_per_s:g} mm/s, plus {cell.robot.touch_time_s:g} s per "
               "touch" if cell is not None else "")
        clock = r.get("clock_s")
        lines.append(f"estimated robot time: about {r['robot_time_s'] / 60:.1f} min for "
                     f"{r['touches']} touches ({r['travel_mm'] / 1000:.1f} m of travel{how})"
                     + (f"; the cell's own clock read {clock / 60:.1f} min at the last reading "
                        "(the estimate leaves out vertical moves and a guarded approach's extra "
                        "steps)" if clock is not None else ""))
    lines.append(f"wrote {out}/recording.csv, result.json, surface.png, convergence.png, "
                 "belief.npz, cell.yaml")
    print("\n".join(lines))
