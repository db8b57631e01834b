"""``adaptive-cal flatness``: the paper's figures of a recording with 95 % intervals.

Values are the figures of the readings themselves (least-squares plane, eqs. 1-6 of Cheng et al.,
range, ISO 1101 minimum zone), so they compare with published numbers. The 95 % interval is the
spread of the same figure over repeat measurements at the same touches, predicted from the
belief (spline + learned noise) fitted to the recording: two rounds whose intervals separate
really differ; ``--compare`` gives the probability directly.
"""
from __future__ import annotations

import json
import sys

import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.analysis import flatness as fl
from adaptive_cal.cell.schema import parse_cell
from adaptive_cal.cell.build import prior_model
from adaptive_cal.gaussian.prior import fit_hyper
from adaptive_cal.formats.recording import Recording, read_recording

NAMES = ("least_squares", "range", "minimum_zone")


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="RECORDING.csv", help="a v1 recording")
    p.add_argument("--compare", metavar="OTHER.csv", help="a later round: probability that its "
                   "flatness is larger, and the interval of the difference")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--samples", type=int, default=400, help="posterior samples for the intervals")
    p.add_argument("--seed", type=int, default=0, help="seed of the posterior samples")


def heights(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fused touches as surface heights up to the probe zero: reading + z (mm)."""
    f = rec.fused
    return rec.x_mm[f], rec.y_mm[f], rec.reading_mm[f] + rec.z_mm[f]


def cell_for(x, y, noise_std_mm: float = 0.01):
    """A cell around a recording's touches (bounding box plus half a grid step)."""
    pad_x = 0.5 * np.min(np.diff(np.unique(x))) if len(np.unique(x)) > 1 else 10.0
    pad_y = 0.5 * np.min(np.diff(np.unique(y))) if len(np.unique(y)) > 1 else 10.0
    return parse_cell({"name": "recording", "workplane": {
        "x_mm": [float(x.min() - pad_x), float(x.max() + pad_x)],
        "y_mm": [float(y.min() - pad_y), float(y.max() + pad_y)], "edge_margin_mm": 0.0},
        "probe": {"zero_mm": 0.0, "noise_std_mm": noise_std_mm},
        "model": {"tilt_std_deg": 5.0, "offset_std_mm": 10.0}})


def repeat_samples(x, y, z, rng: np.random.Generator, n: int) -> tuple[dict, dict]:
    """Figures of predicted repeat measurements at the same touches, and the fitted noise."""
    model = prior_model(cell_for(x, y))
    rows = model.surface.basis(x, y)
    hyper = fit_hyper(model, rows, z)
    post = bl.condition(model.belief(hyper), rows, z, hyper.noise_std_mm**2)
    draws = bl.sample(post, rng, n) @ rows.T
    draws = draws + hyper.noise_std_mm * rng.standard_normal(draws.shape)
    return fl.sampled_figures(x, y, draws), dict(hyper._asdict())


def report(path, rng: np.random.Generator, n: int) -> tuple[dict, dict]:
    rec = read_recording(path)
    x, y, z = heights(rec)
    if len(z) < 4:
        raise ValueError(f"{path}: {len(z)} usable touches; flatness needs at least 4")
    values = fl.figures(x, y, z)
    sampled, hyper = repeat_samples(x, y, z, rng, n)
    rx, ry = fl.average_ranges_mm(x, y, z)
    out = {"recording": str(path), "touches": int(len(z)),
           "tilt": fl.plane_tilt(x, y, z),
           "flatness_mm": fl.interval_figures({k: values[k] for k in NAMES},
                                              {k: sampled[k] for k in NAMES}),
           "average_range_mm": {"x": rx, "y": ry},
           "noise_std_mm": hyper["noise_std_mm"], "hyper": hyper}
    return out, sampled


def command(args) -> int:
    rng = np.random.default_rng(args.seed)
    out, sampled = report(args.recording, rng, args.samples)
    if args.compare:
        other, sampled_b = report(args.compare, rng, args.samples)
        out = {"first": out, "second": other,
               "change": fl.compare_rounds({k: sampled[k] for k in NAMES},
                                           {k: sampled_b[k] for k in NAMES})}
    if args.json:
        json.dump(out, sys.stdout, indent=2)
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
    lines.append(f"  average range x {a['x']:.4f} mm, y {a['y']:.4f} mm")
    return lines


def _print(out: dict) -> None:
    if "change" not in out:
        print("\n".join(_one(out)))
        return
    print("\n".join(_one(out["first"]) + _one(out["second"])))
    for k, c in out["change"].items():
        print(f"  change of {k}: {json.dumps(c)}")
