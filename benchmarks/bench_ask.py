"""One planning decision on the built-in simulated cell, as the README's table states it: the
cell (configs/sim-cell.yaml) driven 25 touches on its simulator, then ``ask`` (scoring 9,821
allowed candidates, refining the best three) and the scoring alone, timed (median of 9, after
2 warm-up calls), with the model's coefficient count. Speed figures belong in a script, not in
a test: run it on an idle machine.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_ask.py [--touches 25] [--json OUT.json]

The figures are also written to benchmarks/results/ask-<date>.json (or --json), with the load
average they were taken under, so the README's figure can be traced to a file.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI runs
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import adaptive_cal  # noqa: E402
from adaptive_cal.cell.build import survey_plan  # noqa: E402
from adaptive_cal.planning.ask import ask  # noqa: E402
from adaptive_cal.planning.scoring import variance_drop  # noqa: E402
from adaptive_cal.run.devices import open_cell  # noqa: E402
from helpers import drive, sim_cell  # noqa: E402  (tests/helpers.py: the loop without a recording)


def median_ms(fn, repeats: int = 9, warm: int = 2) -> float:
    for _ in range(warm):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--touches", type=int, default=25, help="touches made before timing")
    p.add_argument("--json", help="results file (default benchmarks/results/ask-<date>.json)")
    args = p.parse_args(argv)
    adaptive_cal.use_float64()
    cell = sim_cell()
    plan = survey_plan(cell)
    opened = open_cell(cell)
    try:
        state = drive(plan, opened, limit=args.touches)
    finally:
        opened.close()
    rows, cov, r = plan.candidates.rows, state.belief.cov, state.noise_var
    ask_ms = median_ms(lambda: ask(plan, state, 1))
    score_ms = median_ms(lambda: np.argmax(np.asarray(variance_drop(rows, cov, plan.gram, r)[0])))
    line = (f"sim-cell after {state.touches} touches: {len(plan.candidates.xy_mm)} candidates, "
            f"{cov.shape[0]} coefficients; ask {ask_ms:.1f} ms median, scoring alone "
            f"{score_ms:.1f} ms (load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    print(line)
    today = datetime.date.today().isoformat()
    out = Path(args.json or ROOT / "benchmarks" / "results" / f"ask-{today}.json")
    out.write_text(json.dumps({
        "date": today, "software": f"adaptive-cal {adaptive_cal.__version__}",
        "touches": state.touches, "candidates": len(plan.candidates.xy_mm),
        "coefficients": int(cov.shape[0]), "ask_ms_median": round(ask_ms, 2),
        "score_ms_median": round(score_ms, 2), "repeats": 9,
        "load_average": round(os.getloadavg()[0], 2), "cores": os.cpu_count(), "line": line},
        indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
