"""explain on an independent benchmark (issue 15, item 7): every case, every target, PASS / MISS.

The recordings come from benchmarks/explain_indep (numpy only, written from DESIGN.md's physics,
no code shared with adaptive_cal; docs/explain-benchmark.md). Each case's cell file and
recordings are written as text and read back with ``load_cell`` and ``read_recording``, then
``explain`` runs in-process. A case that raises is recorded with its error; the run goes on.

    python benchmarks/bench_explain_indep.py [--quick] [--n 10] [--seed 0] [--workers 2]
        [--only null_student_t,single/form/6]   # a subset of the case keys (targets print on it)
    python benchmarks/bench_explain_indep.py --from benchmarks/results/explain-indep-DATE.json

Writes benchmarks/results/explain-indep-<date>[-quick].json (every case and the printed lines).
"""
from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from explain_indep import cases, targets  # noqa: E402
from explain_indep.generate import write  # noqa: E402


def _key(entry: dict) -> list[int]:
    return [int(entry.get("round", 0)), int(entry["seq"])]


def run_one(job: tuple[dict, int]) -> dict:
    """Generate, write, read back and explain one case; never raises."""
    spec, seed = job
    t0 = time.perf_counter()
    rec = {"key": cases.spec_key(spec), "family": spec["family"], "k_sigma": spec["sigma"]}
    try:
        case = cases.build(spec, seed)
        rec.update({"design": case.design, "plate": case.plate, "rounds": len(case.rounds),
                    "noise_mm": case.noise_mm, "noise_range_stated": case.noise_range,
                    "truth": case.truth, "injected": [list(s) for s in case.suspects]})
        from adaptive_cal.analysis.explain import explain
        from adaptive_cal.cell.schema import load_cell
        from adaptive_cal.formats.recording import read_recording
        with tempfile.TemporaryDirectory() as tmp:
            cell_path, rec_paths = write(case, Path(tmp))
            f = explain([read_recording(p) for p in rec_paths], load_cell(cell_path)).findings
        chosen = next((e for e in f["left_out"] if e["effect"] == f["verdict"]), None)
        rec.update({
            "verdict": f["verdict"], "probability": float(f["verdict_probability"]),
            "ambiguous_with": f["ambiguous_with"],
            "params": chosen["params"] if chosen else None,
            "params_std": chosen["params_std"] if chosen else None,
            "held": chosen.get("held", []) if chosen else [],
            "log_bayes_factor": chosen["log_bayes_factor"] if chosen else None,
            "left_out": [e["effect"] for e in f["left_out"]],
            "as_well": [e["effect"] for e in f["left_out"]
                        if (e.get("given_verdict") or {}).get("left_out")],
            "left_out_params": {e["effect"]: e["params"] for e in f["left_out"]},
            "as_well_params": {e["effect"]: e["given_verdict"]["params"] for e in f["left_out"]
                               if (e.get("given_verdict") or {}).get("left_out")},
            "candidates": {c["effect"]: c["log_bayes_factor"] for c in f["candidates"]},
            "suspect_readings": f["suspect_readings"],
            "suspects_found": [_key(s) for s in f["suspect_readings"]],
            "unexplained_axis": (f.get("unexplained") or {}).get("axis"),
            "rms_before_mm": f["fit"]["rms_before_mm"], "rms_after_mm": f["fit"]["rms_after_mm"]})
    except Exception as exc:  # recorded, never aborts the run
        rec["error"] = f"{type(exc).__name__}: {exc}"
    rec["wall_s"] = time.perf_counter() - t0
    return rec


def reference_line() -> tuple[str, dict]:
    """explain on the reference cell's rounds 0 and 1 (Cheng et al. 2025)."""
    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording
    data = ROOT / "adaptive_cal" / "data" / "cheng2025"
    recs = [read_recording(data / n) for n in ("round0_initial.csv", "round1_first_correction.csv")]
    f = explain(recs, load_cell(ROOT / "configs" / "cheng2025-cell.yaml")).findings
    rms = f["fit"]["rms_after_mm"] * 1000
    ok = f["verdict"] == "form" and rms <= 34.0
    line = (f"{'PASS' if ok else 'MISS'}  reference cell (Cheng 2025 rounds 0+1): {f['verdict']} at "
            f"p = {f['verdict_probability']:.3f}, residual rms {f['fit']['rms_before_mm'] * 1000:.1f}"
            f" -> {rms:.1f} um (target: form, rms <= 2 x 17 um repeatability)")
    return line, {"verdict": f["verdict"], "probability": f["verdict_probability"],
                  "rms_after_um": rms}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10, help="recordings per cell of the table (10: 960)")
    ap.add_argument("--quick", action="store_true", help="n = 3: 288 recordings (about 2-3 min; 134 s measured)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="results JSON (default: dated)")
    ap.add_argument("--only", default="",
                    help="comma-separated parts of case keys to run (e.g. null_student_t,single/form/6)")
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="print the targets of an earlier results JSON, run nothing")
    args = ap.parse_args(argv)
    from adaptive_cal.analysis.explain.core import THRESHOLD
    if args.source:
        data = json.loads(args.source.read_text(encoding="utf-8"))
        print("\n".join(targets.report(data["cases"], data.get("threshold", THRESHOLD))))
        return
    n = 3 if args.quick else args.n
    specs = cases.table(n)
    if args.only:
        parts = [p for p in args.only.split(",") if p]
        specs = [s for s in specs if any(p in cases.spec_key(s) for p in parts)]
        if not specs:
            ap.error(f"--only {args.only!r} matches no case key (e.g. null_gauss/none/0/mixed/...)")
    print(f"{len(specs)} recordings, {args.workers} workers, seed {args.seed}", flush=True)
    t0 = time.perf_counter()
    jobs = [(s, args.seed) for s in specs]
    records = []
    if args.workers > 1:
        with mp.get_context("spawn").Pool(args.workers) as pool:
            for i, r in enumerate(pool.imap_unordered(run_one, jobs, chunksize=2), 1):
                records.append(r)
                if i % 50 == 0:
                    print(f"  {i}/{len(jobs)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    else:
        records = [run_one(j) for j in jobs]
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: r["key"])
    lines = targets.report(records, THRESHOLD)
    try:
        ref, ref_data = reference_line()
    except Exception as exc:  # reported, not fatal
        ref, ref_data = f"MISS  reference cell: {type(exc).__name__}: {exc}", {}
    lines.append(ref)
    per = sorted(r["wall_s"] for r in records)
    lines.append(f"wall time {wall:.0f} s for {len(records)} recordings ({args.workers} workers); "
                 f"per case median {per[len(per) // 2]:.2f} s, max {per[-1]:.1f} s")
    print("\n".join(lines), flush=True)
    date = datetime.date.today().isoformat()
    out = args.out or ROOT / "benchmarks" / "results" / (
        f"explain-indep-{date}{'-quick' if args.quick else ''}.json")
    out.write_text(json.dumps({"n": n, "seed": args.seed, "workers": args.workers,
                               "threshold": THRESHOLD, "wall_s": wall, "cpu_count": os.cpu_count(),
                               "reference": ref_data, "targets": lines, "cases": records},
                              indent=1, default=float), encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
