"""Cost and accuracy of ``compensate`` on a raster engraving over the simulated cell's map:
wall time (s) and moves per second, points added by splitting, the largest departure from the
map at the check samples (um), and the largest error against the TRUE plate (um) at 0.1 mm
steps where the band is within the tolerance.

    nice -n 10 python benchmarks/bench_compensate.py [--quick] [--map RUN_DIR]

Without --map it first maps the simulated cell (configs/sim-cell.yaml) into a temporary folder
(about 30 s). --quick: 40 raster lines instead of 400.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]


def raster(lines: int, depth_mm: float = -0.1) -> str:
    """A zig-zag of ``lines`` cuts across x in [-200, 200], y in [-150, 150] (mm)."""
    out = ["G21 G90", "G0 Z5", "G0 X-200 Y-150", f"G1 Z{depth_mm} F100"]
    for i, y in enumerate(__import__("numpy").linspace(-150, 150, lines)):
        x = 200 if i % 2 == 0 else -200
        out += [f"G1 Y{y:.4f} F600", f"G1 X{x}"]
    return "\n".join(out + ["G0 Z5", "M2"]) + "\n"


def main() -> int:
    sys.path.insert(0, str(ROOT))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="40 raster lines (< 1 min with --map)")
    ap.add_argument("--map", metavar="RUN_DIR", help="a run folder of configs/sim-cell.yaml")
    args = ap.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from adaptive_cal.analysis.compensate import compensate
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.toolpath import read_toolpath, write_toolpath
    from adaptive_cal.gaussian.belief import Z95
    from adaptive_cal.run import session
    from adaptive_cal.run.heightmap import load_map
    from adaptive_cal.simulation.cell import SimulatedCell

    cell_file = ROOT / "configs" / "sim-cell.yaml"
    cell = load_cell(cell_file)
    run_dir = Path(args.map) if args.map else Path(tempfile.mkdtemp()) / "run"
    if not args.map:
        session.run(cell, run_dir, progress=False)
        (run_dir / "cell.yaml").write_text(cell_file.read_text())
    truth = SimulatedCell.from_cell(cell).surface_mm
    hmap = load_map(run_dir)
    T = 0.01
    path = read_toolpath(raster(40 if args.quick else 400), "raster")
    start = time.perf_counter()
    height = hmap.height("nominal")
    res = compensate(path, height, hmap.plate_mm, T, top_mm=hmap.top_mm())
    text = write_toolpath(path, res.pieces)
    wall = time.perf_counter() - start
    out = read_toolpath(text, "out")
    worst, n = 0.0, 0
    for m in out.moves:
        if not m.cut or m.start[:2] == m.end[:2]:
            continue
        p0, p1 = np.array(m.start), np.array(m.end)
        s = np.linspace(0, 1, int(np.hypot(*(p1 - p0)[:2]) / 0.1) + 2)
        xyz = p0 + s[:, None] * (p1 - p0)
        band = Z95 * height(xyz[:, 0], xyz[:, 1])[1]
        err = np.abs(xyz[:, 2] + 0.1 - truth(xyz[:, 0], xyz[:, 1]))[band <= T]
        worst, n = max(worst, err.max(initial=0.0)), n + err.size
    print(f"raster: {len(path.moves)} moves, {res.cuts} cuts; compensate + write {wall:.2f} s "
          f"({len(path.moves) / wall:.0f} moves/s)")
    print(f"points added by splitting: {res.added}; largest departure from the map "
          f"{res.max_deviation_mm * 1e3:.2f} um (budget T - band, T = {T * 1e3:.0f} um); "
          f"moves with band > T: {len(res.wide)}")
    print(f"largest error against the true plate where band <= T: {worst * 1e3:.2f} um over {n} "
          "samples 0.1 mm apart")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
