"""Calibration of explain's answers (issue 15, item 2): do its probabilities and intervals hold?

Two tables on a mixed benchmark:

- reliability: verdicts binned by ``verdict_probability``; per bin the count, the share wrong
  (the verdict is not the concealed effect; ``none`` on a null is right) and the mean probability.
  Targets: p >= 0.99 at most 1 % wrong, 0.9-0.99 at most 10 % wrong.
- coverage: for every right verdict, each parameter of the concealed effect whose truth is known:
  the share with |estimate - truth| <= 2 sd (target 90-98 %), and, where explain gives one, the
  share inside ``parameter_interval_95``.

Generators: ``open`` (tests/open_world_generator.py, numpy only, independent of adaptive_cal;
S-path grid and random designs) and ``project`` (adaptive_cal.simulation.concealed, the
project's own generator: a second opinion).

    python benchmarks/bench_explain_calib.py [--n 6] [--seed 0] [--generator open|project|both]
        [--out runs.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import open_world_generator as gen  # noqa: E402

from adaptive_cal.analysis.explain import explain  # noqa: E402
from adaptive_cal.cell.schema import load_cell  # noqa: E402
from adaptive_cal.formats.recording import read_recording  # noqa: E402

OPEN_KINDS = ("null", "form", "bow", "arm_sag", "reversal", "local_defect", "thermal_drift",
              "warmup")
SIGMAS = (4.0, 6.0, 10.0)
DESIGNS = ("s_path", "random")
PROJECT_KINDS = ("none", "form", "arm_sag", "reversal", "local_defect", "thermal_drift",
                 "probe_gain")
BINS = ((0.0, 0.5), (0.5, 0.9), (0.9, 0.99), (0.99, 1.01))
EXPECT = {"null": "none", "bow": "form", "form_rounds": "form", "warmup": "thermal_drift"}  # the verdict a kind should get (default: its name)
# parameters whose truth the generators know (the effect table's names)
CHECKED = {"form": ("pv_mm",), "arm_sag": ("sag_mm_at_1m", "p"), "reversal": ("span_mm",),
           "local_defect": ("height_mm",),
           "thermal_drift": ("rate_mm_per_s", "amplitude_mm", "tau_s"),
           "probe_gain": ("gain",)}


def _row(kind: str, sigma: float, design: str, findings: dict, truth: dict) -> dict:
    expect = EXPECT.get(kind, kind)
    out = {"kind": kind, "sigma": sigma, "design": design, "verdict": findings["verdict"],
           "p": float(findings["verdict_probability"]), "right": findings["verdict"] == expect,
           "checks": [], "ambiguous_with": findings["ambiguous_with"],
           "verdict_not_identifiable": [e.get("inside_span_of", e["aliased_with"]) for e in
                                        findings["not_identifiable"]
                                        if e["effect"] == findings["verdict"]]}
    if not out["right"] or expect == "none":
        return out
    entry = next(e for e in findings["left_out"] if e["effect"] == expect)
    intervals = entry.get("parameter_interval_95", {})
    for name in CHECKED.get(expect, ()):
        if name not in truth or name not in entry["params"] or name in entry.get("held", ()):
            continue  # a parameter the verdict's form holds is not an estimate
        est, sd, true = entry["params"][name], entry["params_std"][name], truth[name]
        if expect == "form":  # pv is a magnitude
            true = abs(true)
        check = {"param": f"{expect}.{name}", "estimate": est, "sd": sd, "truth": true,
                 "in_2sd": bool(abs(est - true) <= 2.0 * sd)}
        if name in intervals:
            lo, hi = intervals[name]
            check["in_95"] = bool(lo <= true <= hi)
        out["checks"].append(check)
    return out


def open_runs(n: int, seed: int, tmp: Path) -> list[dict]:
    out = []
    for k, kind in enumerate(OPEN_KINDS):
        for sigma in ((0.0,) if kind == "null" else SIGMAS):
            for d, design in enumerate(DESIGNS):
                for s in range(n):
                    rng = np.random.default_rng([seed, k, int(sigma), d, s])
                    xy = gen.random_path(rng) if design == "random" else None
                    case = gen.recording(kind, rng, sigma or 10.0, xy=xy)
                    cell_path, rec_path = gen.write(tmp, case)
                    f = explain([read_recording(rec_path)], load_cell(cell_path)).findings
                    out.append(_row(kind, sigma, design, f, gen.pattern_truth(kind, case)))
    for sigma in (6.0, 10.0):  # three rounds sharing one form: never arm_sag without ambiguity
        for s in range(n):
            recs = []
            for r in range(3):
                case = gen.recording("form", np.random.default_rng([seed, 50, int(sigma), s, r]),
                                     sigma, shape_rng=np.random.default_rng([seed, 51, s]))
                cell_path, rec_path = gen.write(tmp, case, name=f"r{r}.csv")
                recs.append(read_recording(rec_path))
            f = explain(recs, load_cell(cell_path)).findings
            out.append(_row("form_rounds", sigma, "s_path x 3 rounds", f, {}))
    return out


def project_runs(n: int, seed: int) -> list[dict]:
    from adaptive_cal.simulation.concealed import concealed_recording
    out = []
    for k, kind in enumerate(PROJECT_KINDS):
        for sigma in ((0.0,) if kind == "none" else SIGMAS):
            for s in range(n):
                rng = np.random.default_rng([seed, 100 + k, int(sigma), s])
                c = concealed_recording(kind, rng, nonabsorbed_sigma=sigma or 4.0)
                f = explain([c.recording], c.cell).findings
                row = _row("null" if kind == "none" else kind, sigma, "serpentine", f, c.params)
                out.append(row)
    return out


def reliability(runs: list[dict]) -> list[str]:
    lines = ["verdict probability   count   wrong   wrong %   mean p   target"]
    for lo, hi in BINS:
        sel = [r for r in runs if lo <= r["p"] < hi]
        wrong = sum(not r["right"] for r in sel)
        target = {0.99: "<= 1 %", 0.9: "<= 10 %"}.get(lo, "")
        mean_p = np.mean([r["p"] for r in sel]) if sel else float("nan")
        lines.append(f"[{lo:.2f}, {min(hi, 1.0):.2f}{']' if hi > 1 else ')'}        {len(sel):5d}   "
                     f"{wrong:5d}   {100 * wrong / max(len(sel), 1):6.1f}   {mean_p:6.3f}   {target}")
    return lines


def coverage(runs: list[dict]) -> list[str]:
    by = defaultdict(list)
    for r in runs:
        for c in r["checks"]:
            by[c["param"]].append(c)
    lines = ["parameter                    n   within 2 sd   inside 95 % interval   target 90-98 %"]
    for name in sorted(by):
        cs = by[name]
        in95 = [c["in_95"] for c in cs if "in_95" in c]
        bias = np.median([(c["estimate"] - c["truth"]) / abs(c["truth"]) for c in cs
                          if c["truth"] != 0])
        lines.append(f"{name:<26} {len(cs):4d}   {100 * np.mean([c['in_2sd'] for c in cs]):8.1f} %"
                     f"   {(f'{100 * np.mean(in95):8.1f} %' if in95 else '       -  '):>20}"
                     f"   (median relative error {100 * bias:+.1f} %)")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6, help="recordings per kind, size and design")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--generator", choices=("open", "project", "both"), default="open")
    ap.add_argument("--out", type=Path, help="write every run's verdict and checks as JSON")
    args = ap.parse_args()
    t0 = time.perf_counter()
    runs = []
    if args.generator in ("open", "both"):
        with tempfile.TemporaryDirectory() as tmp:
            runs += [{**r, "generator": "open"} for r in open_runs(args.n, args.seed, Path(tmp))]
    if args.generator in ("project", "both"):
        runs += [{**r, "generator": "project"} for r in project_runs(args.n, args.seed)]
    for gname in sorted({r["generator"] for r in runs}):
        sel = [r for r in runs if r["generator"] == gname]
        print(f"== generator {gname}: {len(sel)} recordings")
        print("\n".join(reliability(sel)))
        print("\n".join(coverage(sel)))
        listed = [r for r in sel if r["verdict_not_identifiable"] and not r["ambiguous_with"]]
        print(f"verdict listed as not identifiable with no ambiguous_with: {len(listed)} "
              f"(of {sum(r['verdict'] not in ('none', 'unexplained') for r in sel)} named)")
        rounds = [r for r in sel if r["kind"] == "form_rounds"]
        if rounds:
            print(f"rounds sharing a form: {sum(r['right'] for r in rounds)} of {len(rounds)} form, "
                  f"arm_sag without form in ambiguous_with: {sum(r['verdict'] == 'arm_sag' and 'form' not in r['ambiguous_with'] for r in rounds)}")
        wrong_sure = [r for r in sel if not r["right"] and r["p"] >= 0.9]
        for r in wrong_sure[:12]:
            print(f"  wrong at p {r['p']:.3f}: {r['kind']} {r['sigma']:g} sigma {r['design']} "
                  f"-> {r['verdict']}")
        for r in sel:
            for c in r["checks"]:
                if not c["in_2sd"]:
                    print(f"  miss {c['param']} {r['sigma']:g} sigma {r['design']}: "
                          f"{c['estimate']:.4g} +- {c['sd']:.2g}, truth {c['truth']:.4g}")
    if args.out:
        args.out.write_text(json.dumps(runs, indent=1), encoding="utf-8")
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
