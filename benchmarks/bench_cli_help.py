"""Start-up cost of the command line: wall time of ``adaptive-cal --help`` and of each command's
``--help`` (a fresh interpreter each, median of 5 runs), and its ratio to a bare ``python -c pass``.

The budget is 0.3 s per help (issue 13); the ratio shows what the package adds to the interpreter
on this machine, which is what to compare across machines.

    python benchmarks/bench_cli_help.py [--runs 5] [--json benchmarks/results/cli_help.json]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUDGET_S = 0.3


def wall_s(cmd: list[str], runs: int) -> float:
    """Median wall time (s) of ``runs`` runs of ``cmd`` (output discarded)."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT,
                       check=False)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> int:
    sys.path.insert(0, str(ROOT))
    from adaptive_cal.cli import SUBCOMMANDS  # the dispatcher's table: standard library only

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per command (median taken)")
    ap.add_argument("--json", metavar="OUT.json", help="also write the timings here")
    args = ap.parse_args()

    bare = wall_s([sys.executable, "-c", "pass"], args.runs)
    rows = {"python -c pass": bare}
    for name in [""] + list(SUBCOMMANDS):
        argv = ([name] if name else []) + ["--help"]
        rows[" ".join(["adaptive-cal"] + argv)] = wall_s(
            [sys.executable, "-m", "adaptive_cal.cli"] + argv, args.runs)

    print(f"{'command':<32} {'median s':>9} {'x bare':>7}  (budget {BUDGET_S} s, {args.runs} runs)")
    for label, t in rows.items():
        flag = "" if t <= BUDGET_S or label.startswith("python") else "  over budget"
        print(f"{label:<32} {t:9.3f} {t / bare:7.1f}{flag}")
    if args.json:
        Path(args.json).write_text(json.dumps(
            {"runs": args.runs, "budget_s": BUDGET_S, "python": sys.version.split()[0],
             "median_s": rows, "ratio_to_bare": {k: v / bare for k, v in rows.items()}},
            indent=2) + "\n", encoding="utf-8")
    return 0 if all(t <= BUDGET_S for t in rows.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
