"""``adaptive-cal flatness``: the paper's figures of a recording with 95 % intervals.

Values are the figures of the touched points (least-squares plane, eqs. 1-6 of Cheng et al.,
range, ISO 1101 minimum zone), so they compare with published numbers; the 95 % interval is the
spread over predicted repeat measurements at the same touches (``analysis.flatness_intervals``).
``--compare`` gives the probability that a later round's flatness is larger.
"""
from __future__ import annotations

import json
import sys

from adaptive_cal.cli.common import check_recording

NAMES = ("least_squares", "range", "minimum_zone")


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="RECORDING.csv", help="a v1 recording")
    p.add_argument("--compare", metavar="OTHER.csv", help="a later round: probability that its "
                   "flatness is larger, and the interval of the difference")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--samples", type=int, default=400, help="posterior samples for the intervals")
    p.add_argument("--seed", type=int, default=0, help="seed of the posterior samples")


def command(args) -> int:
    import numpy as np

    from adaptive_cal.analysis.flatness_intervals import compare, recording_flatness

    check_recording(args.recording)
    if args.compare:
        check_recording(args.compare)
    rng = np.random.default_rng(args.seed)
    out, sampled = recording_flatness(args.recording, rng, args.samples)
    if args.compare:
        other, sampled_b = recording_flatness(args.compare, rng, args.samples)
        out = {"first": out, "second": other, "change": compare(sampled, sampled_b)}
    if args.json:
        json.dump(out, sys.stdout, indent=2, allow_nan=False)
        print()
    else:
        _print(out)
    return 0


def _one(r: dict) -> list[str]:
    t, f = r["tilt"], r["flatness_mm"]
    lines = [f"{r['recording']}: {r['touches']} touches, reading noise {r['noise_std_mm'] * 1e3:.1f} um",
             f"  tilt correction: rx {t['rx_deg']:+.4f} deg, ry {t['ry_deg']:+.4f} deg "
             f"(a {t['a']:+.6f}, b {t['b']:+.6f} mm/mm)"]
    for k in NAMES:
        lo, hi = f[k]["ci95"]
        lines.append(f"  flatness {k:14s} {f[k]['value']:.4f} mm  (95 % of repeats {lo:.4f} .. {hi:.4f})")
    a = r["average_range_mm"]
    lines.append("  average range " + ", ".join(
        f"{k} {a[k]:.4f} mm" if a[k] is not None else f"{k} n/a (touches not on a grid along {k})"
        for k in ("x", "y")))
    return lines


LABELS = {"least_squares": "least squares", "minimum_zone": "minimum zone",
          "range": "range (tilt incl.)"}


def _verdict(c: dict) -> str:
    lo, hi = c["diff_ci95"]
    if lo > 0:
        return "larger"
    if hi < 0:
        return "smaller"
    return "within the noise"


def compare_table(out: dict) -> list[str]:
    """The change between two recordings as a table in mm, with P(worse) = P(later > earlier)."""
    from pathlib import Path

    a, b = out["first"], out["second"]
    lines = [f"change from {Path(a['recording']).name} to {Path(b['recording']).name} "
             "(later minus earlier; mm):",
             f"  {'figure':<19}{'earlier':>9}{'later':>9}{'change':>9}   {'95 % interval of change':<26}"
             f"{'P(worse)':>8}  verdict"]
    for k in ("least_squares", "minimum_zone", "range"):
        c = out["change"][k]
        va, vb = a["flatness_mm"][k]["value"], b["flatness_mm"][k]["value"]
        lo, hi = c["diff_ci95"]
        lines.append(f"  {LABELS[k]:<19}{va:>9.4f}{vb:>9.4f}{vb - va:>+9.4f}   "
                     f"{f'{lo:+.4f} .. {hi:+.4f}':<26}{c['p_b_greater']:>8.2f}  {_verdict(c)}")
    lines += ["  P(worse): the probability that the later flatness is larger (over predicted repeat",
              "  measurements). Range includes the tilt: a corrected tilt shows there, not flatness."]
    return lines


def _print(out: dict) -> None:
    if "change" not in out:
        print("\n".join(_one(out)))
        return
    print("\n".join(_one(out["first"]) + _one(out["second"]) + compare_table(out)))
