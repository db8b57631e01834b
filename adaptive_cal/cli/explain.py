"""``adaptive-cal explain``: where simulation and recordings differ, what physics was left out.

    adaptive-cal explain ROUND0.csv [ROUND1.csv ...] --robot CELL.yaml [--json OUT.json] [--out DIR]

Several recordings are rounds of the same cell: the tilt is calibrated per round, the plate's
form and the cell's effects may be shared (decided by evidence). A reading outside the probe's
usable stroke (``probe.usable_mm``) is set aside first, as ``flatness --robot`` and ``report``
set it aside (``report.replay.for_replay``, the one rule; ``run`` rejects it), and the findings
list it (``readings.not_used``). See docs/explain.md.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from adaptive_cal.cli.common import UserError, at_least, check_cell_file, check_recording


def add_arguments(parser) -> None:
    parser.add_argument("recordings", nargs="+", metavar="RECORDING.csv",
                        help="recording(s) of the cell; several = rounds")
    parser.add_argument("--robot", metavar="CELL.yaml", dest="robot",
                        help="the cell file (required); its simulation block: effects, "
                        "parameters, which are unknown")
    parser.add_argument("--sim", dest="robot", help=argparse.SUPPRESS)  # the old name
    parser.add_argument("--json", metavar="OUT.json", help="write the report here")
    parser.add_argument("--out", metavar="DIR", help="write the updated cell file and figures here")
    parser.add_argument("--no-figures", action="store_true", help="skip the figures in DIR")
    parser.add_argument("--seed", type=at_least(0), default=0,
                        help="seed of the bootstrap of the round-to-round flatness change")


def _print(report: dict) -> None:
    from adaptive_cal.report.explain_text import effect_units, lines

    print("\n".join(lines(report, effect_units())))


def _refuse_overwrite(args) -> None:
    """--json and the files --out writes (the explained cell file, the figures) must not be a
    recording, the cell file or a run folder's measurement: they would overwrite it."""
    from adaptive_cal.cli.common import refuse_input_as_output

    inputs = [*args.recordings, args.robot]
    if args.json:
        refuse_input_as_output("--json", args.json, inputs)
    if args.out:
        out = Path(args.out)
        if out.is_file():
            raise UserError(f"--out {out} is a file; --out takes a folder (the explained cell file "
                            "and the figures are written into it)")
        refuse_input_as_output("--out", out / f"{Path(args.robot).stem}-explained.yaml", inputs)
        for given in inputs:  # a figure's name: residual_map.png, residual_vs_*.png, ...
            name = Path(given).name
            if name.endswith(".png") and (name.startswith("residual_")
                                          or name == "fitted_effect.png"):
                refuse_input_as_output("--out", out / name, inputs)


def within_stroke(recordings: list, cell, cell_file: str) -> tuple[list, list[dict]]:
    """The recordings with their readings outside ``probe.usable_mm`` flagged not fused, as
    ``flatness --robot`` and ``report`` judge a replayed reading (``for_replay``: said on
    stderr), and one entry {seq, reading_mm, why[, recording]} for each reading set aside."""
    from adaptive_cal.report.replay import for_replay

    lo, hi = cell.probe.usable_mm
    why = (f"outside the probe's usable stroke {lo:g} .. {hi:g} mm (probe.usable_mm of "
           f"{cell_file}): run rejects such a reading (rejected;stroke_end), flatness --robot "
           "and report leave it out")
    judged, aside = [], []
    for rec in recordings:
        out = for_replay(rec, cell, cell_file)
        judged.append(out)
        rounds = rec.extra.get("round") if len(rec.rounds) > 1 else None  # one file, rounds
        aside += [{"seq": int(rec.seq[i]), "reading_mm": float(rec.reading_mm[i]), "why": why,
                   **({"recording": rec.path} if len(recordings) > 1 else {}),
                   **({"round": float(rounds[i])} if rounds is not None else {})}
                  for i in (rec.fused & ~out.fused).nonzero()[0]]
    return judged, aside


def command(args) -> int:
    if not args.robot:
        raise UserError("explain needs --robot CELL.yaml (the cell file with its simulation block)")
    check_cell_file(args.robot)
    for path in args.recordings:
        check_recording(path)
    _refuse_overwrite(args)
    import numpy as np

    from adaptive_cal.cell.schema import load_cell, load_yaml
    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.analysis.explain.summary import write_cell
    from adaptive_cal.formats.recording import read_recording

    cell = load_cell(args.robot)
    recordings, aside = within_stroke([read_recording(p) for p in args.recordings], cell,
                                      args.robot)
    result = explain(recordings, cell, rng=np.random.default_rng(args.seed))
    if aside:
        result.findings["readings"]["not_used"] = aside
    stale: list[Path] = []
    if args.out:
        path = write_cell(result, load_yaml(args.robot), args.robot, args.out)
        result.findings["model"] = str(path) if path else None
        if not args.no_figures:
            from adaptive_cal.report.explain_figures import figures  # matplotlib: only here

            result.findings["figures"] = [str(p) for p in figures(result, args.out)]
        stale = _remove_stale(Path(args.out), result.findings, args.robot)
    if args.json:  # written before the terminal's lines: a reader that leaves (`| head`) loses none
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        from adaptive_cal.formats.writing import provenance

        Path(args.json).write_text(json.dumps({**result.findings, **provenance()}, indent=1),
                                   encoding="utf-8")  # and which code made them, and when
    _print(result.findings)
    written = ([result.findings["model"]] if args.out and result.findings.get("model") else []) \
        + list(result.findings.get("figures") or []) + ([args.json] if args.json else [])
    if written:  # where the terminal's findings went besides
        print("wrote " + ", ".join(str(w) for w in written))
    if stale:
        print("removed " + ", ".join(str(p) for p in stale) + ": an earlier explain's, which "
              "do not go with these findings")
    return 0


def _remove_stale(out: Path, findings: dict, cell_file: str) -> list[Path]:
    """explain's own files in ``out`` (its figures, the explained cell file) that this explain did
    not write: an earlier explain's, left beside the new findings they do not describe (a
    residual_vs_time.png of an earlier drift beside a verdict none). Removed once the new ones
    are written; the list is said."""
    from adaptive_cal.report.explain_page import EXPLAIN_FIGURES

    own = [out / name for name in EXPLAIN_FIGURES] + [out / f"{Path(cell_file).stem}-explained.yaml"]
    kept = {Path(p).resolve() for p in [findings.get("model"), *(findings.get("figures") or [])]
            if p}
    stale = [p for p in own if p.is_file() and p.resolve() not in kept]
    for p in stale:
        p.unlink()
    return stale
