"""``adaptive-cal explain``: where simulation and recordings differ, what physics was left out.

    adaptive-cal explain ROUND0.csv [ROUND1.csv ...] --robot CELL.yaml [--json OUT.json] [--out DIR]

Several recordings are rounds of the same cell: the tilt is calibrated per round, the plate's
form and the cell's effects may be shared (decided by evidence). See docs/explain.md.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from adaptive_cal.cli.common import UserError


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
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the bootstrap of the round-to-round flatness change")


def _print(report: dict) -> None:
    fit = report["fit"]
    amb = report.get("ambiguous_with") or []
    print(f"verdict: {report['verdict']} (probability {report['verdict_probability']:.2f}"
          + (f"; cannot be told apart from {', '.join(amb)} on this design" if amb else "") + ")")
    for e in report["left_out"]:
        print(f"  left out: {e['summary']}")
    for e in report["not_identifiable"]:
        print(f"  not identifiable: {e['effect']} ({', '.join(e['aliased_with']) or '-'}): {e['why']}")
    print(f"mismatch: rms {1e3 * report['mismatch']['rms_mm']:.1f} um")
    for axis, v in report["mismatch"]["by"].items():
        p = v.get("p_value")
        print(f"  {axis:>10}: " + (f"F-test p = {p:.3g}{' (real)' if v['real'] else ''}"
                                   if p is not None else v.get("note", "")))
    for w in report["mismatch"]["where"]:
        print(f"  concentrated near x {w['x_mm']:g}, y {w['y_mm']:g} mm: "
              f"{1e3 * w['residual_mm']:+.1f} um (z {w['z']:.1f})")
    print(f"fit: rms {1e3 * fit['rms_before_mm']:.1f} -> {1e3 * fit['rms_after_mm']:.1f} um, "
          f"leave-one-out {1e3 * fit['cv_rms_before_mm']:.1f} -> {1e3 * fit['cv_rms_after_mm']:.1f} um")
    if "rounds" in report and "p_value" in report["rounds"]:
        r = report["rounds"]
        print(f"rounds: flatness {r['flatness_mm'][0]:.4f} -> {r['flatness_mm'][1]:.4f} mm, change "
              f"{r['change_mm']:+.4f} mm; noise alone gives 95 % within "
              f"[{r['null_change_95_mm'][0]:+.4f}, {r['null_change_95_mm'][1]:+.4f}] mm "
              f"(repeatability {1e3 * r['repeatability_mm']:.1f} um), p = {r['p_value']:.3f}")
    if report["model"]:
        print(f"model: {report['model']}")


def command(args) -> int:
    if not args.robot:
        raise UserError("explain needs --robot CELL.yaml (the cell file with its simulation block)")
    import numpy as np

    from adaptive_cal.cell.schema import load_cell, load_yaml
    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.analysis.explain.summary import write_cell
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.report.explain_figures import figures

    cell = load_cell(args.robot)
    recordings = [read_recording(p) for p in args.recordings]
    result = explain(recordings, cell, rng=np.random.default_rng(args.seed))
    if args.out:
        path = write_cell(result, load_yaml(args.robot), args.robot, args.out)
        result.findings["model"] = str(path) if path else None
        if not args.no_figures:
            result.findings["figures"] = [str(p) for p in figures(result, args.out)]
    _print(result.findings)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result.findings, indent=1), encoding="utf-8")
    return 0
