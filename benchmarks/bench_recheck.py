"""Re-check after a frame correction on the simulated cell: map configs/sim-cell.yaml once, apply
the proposed correction to the simulated plate (simulation.frame_correction_deg), then re-check
with --prior-from over several noise seeds. Prints, per seed, the touches, how stopped, the
remaining tilt in units of its own std (|rx| / std, |ry| / std: within 1.96 means zero is inside
the 95 % interval), the true residual tilt and the 95 % band's coverage of the true plate; then
the same re-checks assuming no correction ('none') on the corrected plate.

    python benchmarks/bench_recheck.py [--quick] [--seeds 2-9]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="2-9", help="re-check noise seeds, FIRST-LAST")
    ap.add_argument("--quick", action="store_true", help="seeds 2-4 only (about a minute)")
    args = ap.parse_args()
    first, last = (int(v) for v in ("2-4" if args.quick else args.seeds).split("-"))
    sys.path.insert(0, str(ROOT / "tests"))
    sys.path.insert(0, str(ROOT))
    import adaptive_cal

    adaptive_cal.use_float64()
    from helpers import sim_cell

    from adaptive_cal.analysis.flatness import plane_tilt
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.run import session
    from adaptive_cal.simulation.cell import SimulatedCell

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        m = session.run(sim_cell(), Path(tmp) / "map", progress=False)
        t0 = m["tilt"]
        print(f"map: {m['touches']} touches, proposed rx {t0['rx_deg']:+.4f} deg, ry "
              f"{t0['ry_deg']:+.4f} deg ({time.perf_counter() - start:.1f} s)")
        print("assumed   seed touches stopped                         |rx|/std |ry|/std "
              "true rx deg true ry deg coverage")
        for assumed in ("proposed", "none"):
            for seed in range(first, last + 1):
                cell = sim_cell(simulation={"seed": seed, "frame_correction_deg": {
                    "rx_deg": t0["rx_deg"], "ry_deg": t0["ry_deg"]}})
                r = session.run(cell, Path(tmp) / f"{assumed}{seed}", prior_from=Path(tmp) / "map",
                                correction_applied=assumed, progress=False)
                x, y = survey_plan(cell).eval_xy.T
                true = plane_tilt(x, y, SimulatedCell.from_cell(cell).surface_mm(x, y))
                t = r["tilt"]
                print(f"{assumed:9s} {seed:4d} {r['touches']:7d} {r['stopped_because']:31s} "
                      f"{abs(t['rx_deg']) / t['rx_std_deg']:8.2f} "
                      f"{abs(t['ry_deg']) / t['ry_std_deg']:8.2f} {true['rx_deg']:+11.5f} "
                      f"{true['ry_deg']:+11.5f} {r['truth']['coverage95']:8.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
