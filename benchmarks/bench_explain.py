"""Benchmark of ``adaptive-cal explain`` on concealed effects and nulls.

Prints the confusion matrix (true effect x verdict), parameter errors, the false-positive rate on
nulls, the threshold calibration (FP rate and accuracy for several log Bayes factor thresholds),
and the time for 40 and 10,000 rows. Writes benchmarks/results/explain.json.

    python benchmarks/bench_explain.py [--seeds 20] [--nulls 200] [--workers 2] [--scan-nulls 1000]
        [--first-seed 0] [--first-null 0] [--runs-out RUNS.json]

It also computes an upper bound (``oracle_bounds``): the power of the best test for each effect
alone at the same false-positive budget, so a missed target can be told apart from a weak method.
"""
from __future__ import annotations

import argparse
import json
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from scipy import stats

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import Context
from adaptive_cal.analysis.explain.core import THRESHOLD, effect_params, explain
from adaptive_cal.analysis.explain.design import build_design
from adaptive_cal.simulation.concealed import EFFECTS, concealed_recording

MAGNITUDES = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)  # uniform: >= 4 pools 4..8 evenly
NULL_DESIGNS = ({}, {"ny": 6}, {"raster": True}, {"varied_z": True})
MAIN = {name: effects.get(name).main for name in EFFECTS}
THRESHOLDS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
LABELS = EFFECTS + ("none",)


def defect_max_z2(recording, cell) -> float:
    """max over the defect search grid (all radii) of z^2 = (x^T M y)^2 / (|M x|^2 s^2): the
    statistic of the best possible scan test for a bump (location and radius unknown)."""
    ctx = Context.of(build_design([recording], cell))
    d = ctx.design
    s2 = float(ctx.yt @ ctx.yt) / ctx.m
    best = 0.0
    for r in effects.local_defect.grid(d.features, d.geometry)["radius_mm"]:
        gx, gy = effects.defect_centres(d.geometry, r)
        X = ctx.project(effects.defect_regressor_grid(d.features, gx, gy, r))
        nn = np.einsum("ij,ij->j", X, X)
        ok = nn > 1e-18
        best = max(best, float(np.max((X[:, ok].T @ ctx.yt) ** 2 / nn[ok])) / s2)
    return best


def oracle_bounds(runs, null_max_z2, alphas=(0.05, 0.05 / 6)) -> dict:
    """Power of the best test for each effect alone, at size alpha, per magnitude (an upper bound).

    Effects of one known regressor (drift, reversal, gain, sag with its true p): the two-sided
    t-test on that regressor (F with 1 and m - 1 dof, m = 37 after the tilt on 40 touches),
    noncentrality = norm^2. Form: the F-test on the four shapes (4 and m - 4 dof), the most
    powerful invariant test when the shape direction is unknown. Local defect: the scan test
    max z^2 over the search grid, threshold from null recordings of the defect's design.
    alpha = 5 % is the whole false-positive budget given to one effect (no test with <= 5 % can do
    better); 5 %/6 is the budget split evenly over the six candidates.
    """
    m = 37
    out = {}
    for a in alphas:
        per = {}
        for name in EFFECTS:
            row = {}
            for mag in MAGNITUDES:
                if name == "local_defect":
                    crit = float(np.quantile(null_max_z2, 1 - a))
                    zz = [r["defect_max_z2"] for r in runs
                          if r["effect"] == name and r["magnitude"] == mag]
                    row[str(mag)] = float(np.mean(np.asarray(zz) > crit))
                else:
                    k = 4 if name == "form" else 1
                    crit = stats.f.ppf(1 - a, k, m - k)
                    row[str(mag)] = float(stats.ncf.sf(crit, k, m - k, mag ** 2))
            row["4_and_above"] = float(np.mean([row[str(g)] for g in MAGNITUDES if g >= 4]))
            per[name] = row
        per["all_4_and_above"] = float(np.mean([per[n]["4_and_above"] for n in EFFECTS]))
        out[f"alpha_{a:.4f}"] = per
    return out


def _null_scan(seed):
    c = concealed_recording("none", np.random.default_rng([11, seed]), ny=6)
    return defect_max_z2(c.recording, c.cell)


def _one(job):
    effect, magnitude, seed, design = job
    c = concealed_recording(effect, np.random.default_rng([7, LABELS.index(effect), seed,
                                                           int(10 * magnitude)]),
                            nonabsorbed_sigma=magnitude, **design)
    e = explain([c.recording], c.cell, identifiability=False)
    out = {"effect": effect, "magnitude": magnitude, "seed": seed, "design": design,
           "candidates": [(k.effect, k.log_bf) for k in e.candidates],
           "verdict": e.findings["verdict"], "noise_std_mm": c.noise_std_mm,
           "rms_before_mm": e.findings["fit"]["rms_before_mm"],
           "rms_after_mm": e.findings["fit"]["rms_after_mm"],
           "cv_rms_before_mm": e.findings["fit"]["cv_rms_before_mm"],
           "cv_rms_after_mm": e.findings["fit"]["cv_rms_after_mm"]}
    if effect != "none":
        cand = next(k for k in e.candidates if k.effect == effect)
        params, std = effect_params(cand, e.context.design)
        key = MAIN[effect]
        truth = c.params[key]
        if key not in params:  # the warm-up form won (amplitude_mm, tau_s): no rate to compare
            out["param"] = {"name": key, "true": truth, "estimate": None, "form": sorted(params)}
            return out
        out["param"] = {"name": key, "true": truth, "estimate": params[key], "std": std[key],
                        "rel_error": (params[key] - truth) / abs(truth),
                        "z": (params[key] - truth) / max(std[key], 1e-300)}
        if effect == "local_defect":
            out["defect_max_z2"] = defect_max_z2(c.recording, c.cell)
            out["param"]["location_error_mm"] = float(np.hypot(params["x_mm"] - c.params["x_mm"],
                                                               params["y_mm"] - c.params["y_mm"]))
        if effect == "arm_sag":
            out["param"]["p_true"], out["param"]["p_est"] = c.params["p"], params["p"]
    return out


def verdict(cands, threshold) -> str:
    if not cands:
        return "none"
    return cands[0][0] if cands[0][1] > threshold else "none"


def summarise(runs, threshold):
    nulls = [r for r in runs if r["effect"] == "none"]
    fp = float(np.mean([verdict(r["candidates"], threshold) != "none" for r in nulls]))
    eff = [r for r in runs if r["effect"] != "none"]
    acc4 = [verdict(r["candidates"], threshold) == r["effect"] for r in eff if r["magnitude"] >= 4]
    per = {}
    for name in EFFECTS:
        rr = [r for r in eff if r["effect"] == name]
        per[name] = {str(m): float(np.mean([verdict(r["candidates"], threshold) == name
                                            for r in rr if r["magnitude"] == m]))
                     for m in MAGNITUDES}
    per4 = {name: float(np.mean([verdict(r["candidates"], threshold) == name for r in eff
                                 if r["effect"] == name and r["magnitude"] >= 4]))
            for name in EFFECTS}
    wrong4 = float(np.mean([verdict(r["candidates"], threshold) not in (r["effect"], "none")
                            for r in eff if r["magnitude"] >= 4]))
    return {"threshold": threshold, "null_fp_rate": fp, "accuracy_at_4sigma_and_above":
            float(np.mean(acc4)), "accuracy_4sigma_by_effect": per4,
            "wrong_effect_at_4sigma_and_above": wrong4,
            "accuracy_by_effect_and_magnitude": per}


def confusion(runs, threshold, min_mag=0.0):
    m = {t: {v: 0 for v in LABELS} for t in LABELS}
    for r in runs:
        if r["effect"] == "none" or r["magnitude"] >= min_mag:
            m[r["effect"]][verdict(r["candidates"], threshold)] += 1
    return m


def _print_confusion(m, title):
    print(f"\n{title} (rows: true effect, columns: verdict)")
    short = {n: n[:8] for n in LABELS}
    print(" " * 14 + "".join(f"{short[v]:>9}" for v in LABELS))
    for t in LABELS:
        print(f"{t:>14}" + "".join(f"{m[t][v]:>9}" for v in LABELS))


def timing():
    out = {}
    for label, nx, ny in (("40_rows", 10, 4), ("10000_rows", 125, 80)):
        c = concealed_recording("thermal_drift", np.random.default_rng(3), nx=nx, ny=ny,
                                nonabsorbed_sigma=6.0)
        t0 = time.perf_counter()
        e = explain([c.recording], c.cell)  # full analysis, identifiability included
        out[label] = {"rows": len(c.recording), "seconds": time.perf_counter() - t0,
                      "verdict": e.findings["verdict"]}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="seeds per effect and magnitude")
    ap.add_argument("--nulls", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scan-nulls", type=int, default=1000,
                    help="null recordings for the defect scan-test threshold of the bound")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="effect seeds first..first+seeds-1 (a fresh set: not 0)")
    ap.add_argument("--first-null", type=int, default=0, help="null seeds likewise")
    ap.add_argument("--runs-out", help="also write every recording's candidates and verdict here")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "explain.json"))
    args = ap.parse_args(argv)
    f = args.first_seed
    jobs = [(e, m, s, {}) for e in EFFECTS for m in MAGNITUDES for s in range(f, f + args.seeds)]
    jobs += [("none", 0.0, s, NULL_DESIGNS[s % len(NULL_DESIGNS)])
             for s in range(args.first_null, args.first_null + args.nulls)]
    t0 = time.perf_counter()
    with Pool(args.workers) as pool:
        runs = pool.map(_one, jobs, chunksize=8)
        null_z2 = pool.map(_null_scan, range(args.scan_nulls), chunksize=16)
    elapsed = time.perf_counter() - t0
    if args.runs_out:
        Path(args.runs_out).write_text(json.dumps(runs, default=float))
    calib = [summarise(runs, t) for t in THRESHOLDS]
    print(f"{len(runs)} recordings in {elapsed:.0f} s")
    ms = summarise(runs, THRESHOLD)
    print("right verdict >= 4 sigma by effect: " + ", ".join(
        f"{k} {v:.3f}" for k, v in ms["accuracy_4sigma_by_effect"].items())
        + f"; wrong effect named {ms['wrong_effect_at_4sigma_and_above']:.3f}")
    print("\nthreshold  null FP  accuracy >= 4 sigma")
    for c in calib:
        print(f"{c['threshold']:>9.1f}  {c['null_fp_rate']:7.3f}  {c['accuracy_at_4sigma_and_above']:7.3f}")
    main_sum = summarise(runs, THRESHOLD)
    _print_confusion(confusion(runs, THRESHOLD), f"confusion, all magnitudes, threshold {THRESHOLD}")
    _print_confusion(confusion(runs, THRESHOLD, 4.0), f"confusion, magnitude >= 4 sigma, threshold {THRESHOLD}")
    print("\nright verdict by effect and non-absorbed norm (sigma):")
    print(" " * 14 + "".join(f"{m:>7g}" for m in MAGNITUDES))
    for name, row in main_sum["accuracy_by_effect_and_magnitude"].items():
        print(f"{name:>14}" + "".join(f"{row[str(m)]:>7.2f}" for m in MAGNITUDES))
    errors = {}
    print("\nparameter of the true effect's candidate (all magnitudes >= 4 sigma):")
    for name in EFFECTS:
        rr = [r["param"] for r in runs if r["effect"] == name and r["magnitude"] >= 4
              and r["param"]["estimate"] is not None]
        if not rr:
            continue
        rel = np.array([p["rel_error"] for p in rr])
        z = np.array([p["z"] for p in rr])
        errors[name] = {"param": MAIN[name], "median_abs_rel_error": float(np.median(np.abs(rel))),
                        "fraction_within_2_std": float(np.mean(np.abs(z) < 2))}
        if name == "local_defect":
            errors[name]["median_location_error_mm"] = float(np.median(
                [p["location_error_mm"] for p in rr]))
        if name == "arm_sag":
            errors[name]["median_abs_p_error"] = float(np.median(
                [abs(p["p_est"] - p["p_true"]) for p in rr]))
        print(f"  {name:>14} {MAIN[name]:>14}: " + ", ".join(f"{k} {v:.3g}" for k, v in
                                                             errors[name].items() if k != "param"))
    bounds = oracle_bounds(runs, null_z2)
    print("\nupper bound: power of the best test for each effect alone (see oracle_bounds)")
    for key, per in bounds.items():
        print(f"  {key}: " + ", ".join(f"{n} {per[n]['4_and_above']:.3f}" for n in EFFECTS)
              + f"; all {per['all_4_and_above']:.3f} (>= 4 sigma)")
        print("   at 4 sigma: " + ", ".join(f"{n} {per[n]['4.0']:.2f}" for n in EFFECTS))
    tim = timing()
    print("\ntiming (full explain incl. identifiability, no figures):")
    for k, v in tim.items():
        print(f"  {v['rows']:>6} rows: {v['seconds']:.2f} s (verdict {v['verdict']})")
    result = {"threshold": THRESHOLD, "magnitudes": MAGNITUDES,
              "seeds": args.seeds, "first_seed": args.first_seed, "nulls": args.nulls,
              "first_null": args.first_null, "calibration": calib,
              "summary": main_sum, "confusion_all": confusion(runs, THRESHOLD),
              "confusion_4sigma": confusion(runs, THRESHOLD, 4.0), "parameter_errors": errors,
              "oracle_bounds": bounds, "scan_nulls": args.scan_nulls,
              "timing": tim, "elapsed_s": elapsed}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1, default=float))
    print(f"\nwritten {args.out}")


if __name__ == "__main__":
    main()
