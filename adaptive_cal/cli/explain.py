"""``adaptive-cal explain``: where simulation and recordings differ, what physics was left out.

    adaptive-cal explain ROUND0.csv [ROUND1.csv ...] --robot CELL.yaml [--json OUT.json] [--out DIR]

Several recordings are rounds of the same cell: the tilt is calibrated per round, the plate's
form and the cell's effects may be shared (decided by evidence). See docs/explain.md.
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
    recordings = [read_recording(p) for p in args.recordings]
    result = explain(recordings, cell, rng=np.random.default_rng(args.seed))
    if args.out:
        path = write_cell(result, load_yaml(args.robot), args.robot, args.out)
        result.findings["model"] = str(path) if path else None
        if not args.no_figures:
            from adaptive_cal.report.explain_figures import figures  # matplotlib: only here

            result.findings["figures"] = [str(p) for p in figures(result, args.out)]
    if args.json:  # written before the terminal's lines: a reader that leaves (`| head`) loses none
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result.findings, indent=1), encoding="utf-8")
    _print(result.findings)
    written = ([result.findings["model"]] if args.out and result.findings.get("model") else []) \
        + list(result.findings.get("figures") or []) + ([args.json] if args.json else [])
    if written:  # where the terminal's findings went besides
        print("wrote " + ", ".join(str(w) for w in written))
    return 0
