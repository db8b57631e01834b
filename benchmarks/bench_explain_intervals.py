"""How reliable is each parameter interval explain reports? z = (estimate - truth) / sd per parameter.

Reads results JSON files of bench_explain_indep.py (its ``cases``) and prints, for every covered
parameter (explain_indep.targets.COVERED) over the cases where the verdict named the true effect:
the share of 2-sd intervals that hold the truth (target 90-98 %, with its 95 % Wilson interval),
the standard deviation and median of z -- overall and per design (s_path, raster, random,
edge) and per size (4 / 6 / 10 sigma). sd(z) > 1: the sds are too narrow; < 1: too wide.
A share outside 90-98 % whose Wilson interval still reaches the band is flagged ``noise?``.

    python benchmarks/bench_explain_intervals.py benchmarks/results/explain-indep-DATE.json [...]
        [--by design|sigma|family] [--json OUT.json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from explain_indep.targets import COVERED, wilson  # noqa: E402

BAND = (0.90, 0.98)


def z_scores(records: list[dict]) -> dict[str, list[tuple[float, dict]]]:
    """{effect.param: [(z, labels)]}: one entry per right verdict whose parameter is a number."""
    out: dict[str, list[tuple[float, dict]]] = {}
    for r in records:
        if "error" in r or r.get("family") not in ("single", "warmup", "rounds_shared_form"):
            continue
        truth = r["truth"]["effects"][0]
        if r.get("verdict") != truth["effect"]:
            continue
        params, stds = r.get("params") or {}, r.get("params_std") or {}
        parts = r["key"].split("/")
        labels = {"design": r.get("design", parts[3]), "sigma": parts[2], "family": parts[0]}
        for name in COVERED.get(truth["effect"], ()):
            if (name not in truth or name not in params or isinstance(params[name], list)
                    or name in r.get("held", ())):  # held by the verdict's form: no estimate
                continue
            err = float(params[name]) - float(truth[name])
            sd = float(stds.get(name, 0.0))
            z = err / sd if sd > 0 else float(np.copysign(np.inf, err))
            out.setdefault(f"{truth['effect']}.{name}", []).append((z, labels))
    return out


def summary(z: np.ndarray) -> dict:
    """Coverage of |z| <= 2 with its Wilson interval, sd and median of z (inf excluded)."""
    k, n = int(np.sum(np.abs(z) <= 2.0)), int(z.size)
    finite = z[np.isfinite(z)]
    lo, hi = wilson(k, n)
    share = k / max(n, 1)
    verdict = ("PASS" if BAND[0] <= share <= BAND[1] else
               "noise?" if lo <= BAND[1] and hi >= BAND[0] else "MISS")
    return {"n": n, "covered": k, "share": share, "wilson": [lo, hi],
            "sd_z": float(np.std(finite)) if finite.size else float("nan"),
            "median_z": float(np.median(finite)) if finite.size else float("nan"),
            "verdict": verdict}


def line(name: str, s: dict) -> str:
    return (f"{s['verdict']:6s} {name:34s} {s['covered']:4d}/{s['n']:<4d} = {s['share']:6.1%} "
            f"[{s['wilson'][0]:.0%}, {s['wilson'][1]:.0%}]  sd(z) {s['sd_z']:.2f}  "
            f"median z {s['median_z']:+.2f}")


def report(records: list[dict], by: str = "design") -> tuple[list[str], dict]:
    lines = [f"2-sd parameter intervals (target {BAND[0]:.0%}-{BAND[1]:.0%}; by {by}):"]
    data = {}
    for key, rows in sorted(z_scores(records).items()):
        z = np.array([v for v, _ in rows])
        data[key] = {"all": summary(z)}
        lines.append(line(key, data[key]["all"]))
        for group in sorted({lab[by] for _, lab in rows}):
            zz = np.array([v for v, lab in rows if lab[by] == group])
            data[key][group] = summary(zz)
            lines.append("   " + line(f"{key} / {group}", data[key][group]))
    return lines, data


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_explain_indep.py results JSON")
    ap.add_argument("--by", choices=("design", "sigma", "family"), default="design")
    ap.add_argument("--json", type=Path, default=None, help="write the figures as JSON")
    args = ap.parse_args(argv)
    records = []
    for path in args.results:
        records += json.loads(path.read_text(encoding="utf-8"))["cases"]
    lines, data = report(records, args.by)
    print("\n".join(lines))
    if args.json:
        args.json.write_text(json.dumps(data, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
