"""The closure touch (planning/closure.py) on the built-in simulated cell: how often it says
"drift" where the cell does not drift -- Gaussian readings, and heavy-tailed ones with gross
errors -- and how often it catches a warm-up that does happen.

    python benchmarks/bench_closure.py                 # 30 runs a kind, about 8 min on 2 cores
    python benchmarks/bench_closure.py --runs 100 --kinds none,heavy
    python benchmarks/bench_closure.py --out F.json    # every run's closure as result.json has it

Each run is the product's own loop (``run.loop``) on configs/sim-cell.yaml with its simulation
seed set to ``--seed`` + i, to its stop (a bound, or the budget) with its closure.
Kinds: ``none`` (the cell as shipped: 2 um probe, 5 um robot repeatability, Gaussian);
``heavy`` (Student-t readings with 3 degrees of freedom at the same sd, and 2 % gross errors of
50 um: a chip, dust, a probe that misreads); ``gross-5`` (Gaussian readings, 5 % of them gross
errors of 50 um: a dusty plate); ``warm-N`` (a warm-up of N um with tau 60 s,
``thermal_drift``, the arm straight from cold); ``early`` (short runs: the probe's noise span
stated 3-8 um, its readings at the top, 8 um, the bound 8 um: the run stops after about 24
touches, where the learned noise rests on about 11 degrees of freedom); ``early-warm-40`` (the
same with a 40 um warm-up). A drift alarm where the cell does not drift is a false alarm (the
test's level is 1 %: ``planning.closure.ALPHA``); on a warm-up it is a catch.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from explain_indep.targets import wilson  # noqa: E402  (the benchmarks' Wilson interval)
KINDS = ("none", "heavy", "gross-5", "warm-10", "warm-20", "warm-30", "warm-40", "early",
         "early-warm-40")


def one(job: tuple[str, int]) -> dict:
    import adaptive_cal
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.cell.schema import load_yaml, parse_cell
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.run.loop import run_loop

    adaptive_cal.use_float64()
    kind, seed = job
    data = load_yaml(ROOT / "configs" / "sim-cell.yaml")
    sim = data["simulation"]
    sim["seed"] = seed
    if kind == "heavy":
        sim.update(noise_dof=3.0, outlier_rate=0.02, outlier_mm=0.05)
    elif kind == "gross-5":
        sim.update(outlier_rate=0.05, outlier_mm=0.05)
    if kind.startswith("early"):
        data["probe"]["noise_range_mm"] = [0.003, 0.008]
        data["plan"]["stop"]["mean_std_mm"] = 0.008
        sim.update(noise_std_mm=0.008, repeatability_mm=0.0)
    if "warm-" in kind:
        amp = float(kind.split("-")[-1]) * 1e-3
        sim["effects"] = {**sim["effects"], "thermal_drift": {"amplitude_mm": amp, "tau_s": 60}}
    cell = parse_cell(data, f"{kind} {seed}")
    plan = survey_plan(cell)
    opened = open_cell(cell)
    t0 = time.perf_counter()
    try:
        state, why = run_loop(plan, sv.start(plan), opened.cycle)
    finally:
        opened.close()
    c = state.closure
    return {"kind": kind, "seed": seed, "stopped_because": why, "touches": state.touches,
            "fused": state.fused,
            "wall_s": time.perf_counter() - t0,
            "closure": None if c is None else c.as_dict()}


def report(records: list[dict]) -> list[str]:
    lines = ["kind        runs  drift said (95 % Wilson)      closure not judged  touches  "
             "median p  |d| mean um"]
    for kind in [k for k in KINDS if any(r["kind"] == k for r in records)]:
        rr = [r for r in records if r["kind"] == kind and "error" not in r]
        n = len(rr)
        alarms = sum(r["stopped_because"] == "drift" for r in rr)
        lo, hi = wilson(alarms, n)
        made = [r["closure"] for r in rr if r["closure"] and r["closure"]["made"]]
        unjudged = sum(1 for r in rr if r["closure"] and not r["closure"]["made"])
        ps = sorted(c["p"] for c in made)
        med = ps[len(ps) // 2] if ps else math.nan
        d = sum(abs(c["difference_mm"]) for c in made) / max(len(made), 1) * 1e3
        touches = sum(r["touches"] for r in rr) / max(n, 1)
        lines.append(f"{kind:10s} {n:5d}  {alarms:3d} = {100 * alarms / max(n, 1):5.1f} % "
                     f"[{100 * lo:4.1f}, {100 * hi:5.1f}]   {unjudged:10d}  {touches:8.1f}  "
                     f"{med:8.3f}  {d:9.1f}")
    errors = [r for r in records if "error" in r]
    if errors:
        lines.append(f"{len(errors)} runs failed, first: {errors[0]['error']}")
    return lines


def _safe(job):
    try:
        return one(job)
    except Exception as e:  # a run that raises is recorded, the benchmark goes on
        return {"kind": job[0], "seed": job[1], "error": f"{type(e).__name__}: {e}"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=30, help="runs per kind")
    p.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated of {KINDS}")
    p.add_argument("--seed", type=int, default=5000, help="first simulation seed")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", help="JSON of every run")
    args = p.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        p.error(f"--kinds: {bad[0]!r} is none of {', '.join(KINDS)}")
    jobs = [(k, args.seed + i) for k in kinds for i in range(args.runs)]
    t0 = time.perf_counter()
    records = []
    with cf.ProcessPoolExecutor(args.workers) as pool:
        for i, rec in enumerate(pool.map(_safe, jobs), 1):
            records.append(rec)
            if i % 10 == 0 or i == len(jobs):
                print(f"  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s", file=sys.stderr,
                      flush=True)
    lines = report(records)
    print("\n".join(lines))
    print(f"wall time {time.perf_counter() - t0:.0f} s for {len(jobs)} runs "
          f"({args.workers} workers)")
    if args.out:
        Path(args.out).write_text(json.dumps({"runs": args.runs, "seed": args.seed,
                                              "records": records, "report": lines}, indent=1))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
