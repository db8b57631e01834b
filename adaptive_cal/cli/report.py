"""``adaptive-cal report DIR`` (a run folder) or ``adaptive-cal report RECORDING.csv --robot
CELL.yaml`` (a bare recording replayed with its cell file): one self-contained HTML page
(figures embedded)."""
from __future__ import annotations

from pathlib import Path

from adaptive_cal.report.status import quoted


def add_arguments(p) -> None:
    p.add_argument("run_dir", metavar="DIR|RECORDING.csv", help="a run folder written by "
                   "'adaptive-cal run --out DIR' (result.json, recording.csv, cell.yaml, "
                   "belief.npz; explain.json and explain's figures are included when present), or "
                   "a recording with --robot")
    p.add_argument("--robot", metavar="CELL.yaml", default=None, help="with a recording: the cell "
                   "file it was taken with; the recording is replayed to a map%(default).0s")
    # "%(default).0s" prints nothing; it stops the formatter appending "(default: None)"
    p.add_argument("--round", type=float, default=None, metavar="R", help="with a recording "
                   "whose round column holds several rounds: the one numbered R (as flatness "
                   "--round)%(default).0s")
    p.add_argument("--out", metavar="FILE.html", default=None,
                   help="where to write the page (default: DIR/report.html, or RECORDING.html "
                   "beside a recording)%(default).0s")


def command(args) -> int:
    from adaptive_cal.cli.common import (UserError, check_cell_file, check_recording,
                                         refuse_input_as_output)

    given = Path(args.run_dir)
    if given.is_file():
        if not args.robot:
            folder = given.parent
            if (folder / "cell.yaml").is_file() and given.name != "recording.csv" and \
                    (folder / "recording.csv").is_file():  # result.json, belief.npz, ...
                raise UserError(f"{given} is a file of the run folder {folder}: adaptive-cal "
                                f"report {quoted(folder)}")
            if given.name == "recording.csv" and (folder / "cell.yaml").is_file():
                raise UserError(f"{given} is a file; report wants the run folder it is in "
                                f"(adaptive-cal report {quoted(folder)}), or, to replay the recording "
                                f"with a cell file: adaptive-cal report {quoted(given)} --robot CELL.yaml")
            raise UserError(f"{given} is a file, a bare recording: report replays it with the "
                            f"cell file it was taken with: adaptive-cal report {quoted(given)} --robot "
                            "CELL.yaml (or give a run folder, which holds its own cell.yaml)")
        check_recording(str(given))
        check_cell_file(args.robot)
        from adaptive_cal.cli.run_guards import replay_cell_warning

        said = replay_cell_warning(given, Path(args.robot))
        if said:
            import sys

            print(said, file=sys.stderr)
        out = args.out or (given.with_suffix(".html") if args.round is None else
                           given.with_name(f"{given.stem}-round{args.round:g}.html"))
        refuse_input_as_output("--out", out, [given, args.robot])
        path = _from_recording(given, Path(args.robot), out, args.round)
    else:
        if not given.exists():
            raise UserError(f"{given}: " + ("no such recording" if args.robot or given.suffix
                                             == ".csv" else "no such folder (give the run "
                                             "folder 'adaptive-cal run --out DIR' wrote)"))
        if args.robot:
            raise UserError(f"--robot goes with a recording; {given} is a run folder, which holds "
                            "its own cell.yaml")
        if args.round is not None:
            raise UserError(f"--round goes with a recording and --robot; {given} is a run folder")
        from adaptive_cal.report.html import write

        if given.is_dir():
            refuse_input_as_output("--out", args.out or given / "report.html", [args.robot],
                                   [given], also=_page_reads())  # the page and run read them
            _check_belief(given)
        path = write(args.run_dir, args.out)
    print(f"wrote {path}")
    return 0


def _page_reads() -> tuple[str, ...]:
    """A run folder's files besides RUN_FILES that the page embeds or a resume reads: --out
    never replaces one (a page written over convergence.png was embedded as a broken image)."""
    from adaptive_cal.report.explain_page import EXPLAIN_FIGURES
    from adaptive_cal.run.recheck import PRIOR_RECORD

    return ("explain.json", "surface.png", "convergence.png", PRIOR_RECORD, *EXPLAIN_FIGURES)


def _check_belief(run_dir: Path) -> None:
    """The folder's belief.npz must be the map its cell.yaml gives (``cli.flatness.check_belief``);
    without belief.npz the recording is checked against result.json's count alone
    (``_check_without_belief``); a folder without cell.yaml is left to the page, which says what
    is missing."""
    if not (run_dir / "belief.npz").is_file():
        _check_without_belief(run_dir)
        return
    if not (run_dir / "cell.yaml").is_file():
        return
    from adaptive_cal.cell.build import plan_model
    from adaptive_cal.cell.run_cell import load_run_cell
    from adaptive_cal.cli.flatness import check_belief
    from adaptive_cal.formats.npz import read_npz

    from adaptive_cal.cli.run_guards import refuse_stale_map

    check_belief(run_dir, plan_model(load_run_cell(run_dir / "cell.yaml")).surface,
                 read_npz(run_dir / "belief.npz"), "report")
    if (run_dir / "recording.csv").is_file():
        refuse_stale_map(run_dir, "report")


def _check_without_belief(run_dir: Path) -> None:
    """No belief.npz, so no digest to check the recording against: its rows must at least be
    the touches result.json counts, and the page says it could not check more (an outside
    audit, 2026-12-01: a recording cut to 4 of 32 touches gave a page of '32 touches' beside a
    figure of 4, exit 0)."""
    import sys

    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.jsonfile import read_json
    from adaptive_cal.formats.recording import read_recording

    rec, res = run_dir / "recording.csv", run_dir / "result.json"
    if not (rec.is_file() and res.is_file()):
        return
    try:
        said = read_json(res).get("touches")
    except (OSError, ValueError, AttributeError):
        return  # the page says what is wrong with it
    rows = len(read_recording(rec))
    if type(said) is int and rows != said:
        raise UserError(f"{rec} holds {rows} touches, {res} counts {said}, and belief.npz, "
                        "whose digest would tell which is the run's, is missing: the recording "
                        f"was edited or the run went on. Replay the recording as it is: "
                        f"adaptive-cal report {quoted(rec)} --robot {quoted(run_dir / 'cell.yaml')}")
    print(f"warning: {run_dir / 'belief.npz'} is missing: the page shows result.json's figures "
          "and cannot check the recording against the map they came from", file=sys.stderr)


def _from_recording(recording, cell_file, out, round_=None) -> "Path":
    """Replay the recording (its round ``round_``, where given) with the cell's plan
    (``planning.survey.replay``) and write its page."""
    import numpy as np

    from adaptive_cal.analysis.flatness_answer import SEED
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.report.html import render_recording
    from adaptive_cal.run.results import result_of, unresolved_grid

    cell = load_cell(cell_file)
    plan = survey_plan(cell)
    from adaptive_cal.report.replay import closure_of, for_replay

    from adaptive_cal.cli.flatness import _picked

    picked = _picked(str(recording), round_, "--round") if round_ is not None else \
        read_recording(recording)
    rec = for_replay(picked.one_round("a report's map"), cell, cell_file)  # as the run judges
    if rec.fused.sum() < 4:
        raise UserError(f"{recording}: {int(rec.fused.sum())} fused touches; a report needs at "
                        "least 4")
    from adaptive_cal.analysis.flatness_intervals import spans_area

    spans_area(rec.x_mm[rec.fused], rec.y_mm[rec.fused], recording)  # names the file
    state = sv.replay(plan, sv.start(plan), rec)  # the recording read once, above
    stopped = plan.stop(sv.status(plan, state)) or "recording_ended"
    result = result_of(cell, plan, state, rec, stopped, rng=np.random.default_rng(SEED))
    closure = closure_of(plan, rec)  # the drift check, judged again from the recording
    if closure is not None:
        result["closure"] = {**closure.as_dict(), "text": closure.text() + " (judged again "
                             "from the recording; the run's own verdict is in its result.json)"}
    s = plan.model.surface
    belief = {"mean": state.belief.mean, "cov": state.belief.cov, "knots_x": s.sx.knots,
              "knots_y": s.sy.knots,
              **unresolved_grid(plan, state, result.get("local_features") or ())}
    out = Path(out) if out else Path(recording).with_suffix(".html")
    html = render_recording(result, cell, rec, belief, Path(recording), Path(cell_file))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(html, encoding="utf-8")
    return out
