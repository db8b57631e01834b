"""explain in the open world, on recordings from an independent generator (issue 15, items 3, 5, 6).

The generator (tests/open_world_generator.py, numpy only) shares no code with adaptive_cal.
Cases: structure outside the library at 10 sigma (a 50 mm ripple along x on an S-path, a
y-backlash on a column-wise serpentine) -> how often ``unexplained``, and never a library name at
p >= 0.9; Gaussian nulls -> false positives (a library effect or ``unexplained`` named); one
library effect at 6 sigma (form, arm_sag, reversal) -> right verdict. Prints the figures.

    python benchmarks/bench_explain_open.py [--quick] [--n 20] [--seed 0]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import open_world_generator as gen  # noqa: E402

from adaptive_cal.analysis.explain import explain  # noqa: E402
from adaptive_cal.cell.schema import load_cell  # noqa: E402
from adaptive_cal.formats.recording import read_recording  # noqa: E402

CASES = (("ripple", 10.0), ("backlash_y", 10.0), ("null", 0.0), ("form", 6.0),
         ("arm_sag", 6.0), ("reversal", 6.0))


def run_case(kind: str, sigma: float, n: int, seed: int, tmp: Path) -> list[dict]:
    out = []
    for s in range(n):
        rng = np.random.default_rng([seed, s, CASES.index((kind, sigma))])
        case = gen.recording(kind, rng, sigma)
        cell_path, rec_path = gen.write(tmp, case)
        f = explain([read_recording(rec_path)], load_cell(cell_path)).findings
        out.append({"verdict": f["verdict"], "p": f["verdict_probability"],
                    "ambiguous_with": f["ambiguous_with"],
                    "axis": (f.get("unexplained") or {}).get("axis"),
                    "ni": [(e["effect"], tuple(e.get("inside_span_of", e["aliased_with"])))
                           for e in f["not_identifiable"]]})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="recordings per case")
    ap.add_argument("--quick", action="store_true", help="8 recordings per case (< 2 min)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = 8 if args.quick else args.n
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for kind, sigma in CASES:
            runs = run_case(kind, sigma, n, args.seed, Path(tmp))
            verdicts = Counter(r["verdict"] for r in runs)
            library = [r for r in runs if r["verdict"] not in ("none", "unexplained")]
            line = f"{kind:>11} {sigma:4.0f} sigma, {n} recordings: " + ", ".join(
                f"{k} {v}" for k, v in verdicts.most_common())
            if kind in ("ripple", "backlash_y"):
                line += (f" | unexplained {verdicts['unexplained'] / n:.0%} (target >= 80 %); "
                         f"library name at p >= 0.9: {sum(r['p'] >= 0.9 for r in library)} "
                         "(target 0); axes " + ", ".join(
                             f"{a} {c}" for a, c in Counter(r["axis"] for r in runs
                                                            if r["axis"]).most_common()))
            elif kind == "null":
                fp = n - verdicts["none"]
                line += f" | false positives {fp / n:.0%} (target <= 5 %)"
            else:
                line += (f" | right {verdicts[kind] / n:.0%}; with ambiguous_with "
                         f"{sum(bool(r['ambiguous_with']) for r in runs if r['verdict'] == kind)};"
                         f" verdict listed not identifiable "
                         f"{sum(any(e == r['verdict'] for e, _ in r['ni']) for r in runs)}")
            print(line, flush=True)
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
