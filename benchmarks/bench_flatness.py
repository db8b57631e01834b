"""Whole-plate flatness intervals against the true plate's flatness, on plates written
independently of the model's prior (benchmarks/plates/generate.py, numpy/scipy only).

A run's result.json gives the flatness of the whole plate from its map with a 95 % interval
(least squares, Cheng et al. eq. 5, and the ISO 1101 minimum zone). That interval is a claim:
here it is checked against the true plate. Each plate is one `adaptive-cal run` (a subprocess,
the product as a user runs it) on the simulated cell of configs/study-plates.yaml with
``simulation.surface_file`` set to the plate's map, 5 um Gaussian reading noise, the probe's
span stated as 3-8 um, stop at 4 um RMS posterior std or ``--budget`` touches. The true
figures are computed here, not by adaptive_cal: the map is interpolated bilinearly (as
DESIGN.md defines it) onto the run's evaluation grid (41 x 41 nodes over the workplane), the
least-squares plane by numpy's lstsq, the minimum zone as a linear programme (scipy linprog).

Printed per family: how often each 95 % interval holds the true figure, and how often the
truth lay above it (the map missed structure) or below -- for the whole plate and, where the
workplane has an edge margin, within reach of the touches (result.json
``flatness_within_reach_mm``, the truth on a grid spanning the same box) -- how
often the tilt correction's rx, ry +- 2 sd hold those of the true map's least-squares plane,
and how many local features the runs named (a gated reading its retake confirmed); the records also keep each run's largest gap
between touches and its unresolved RMS. The noisy family (``--families noisy``) reads as its
manifest says: Student-t noise of its degrees of freedom (5 um sd) and its gross errors -- the
readings the gate retakes most, so it is where a local feature could be named falsely.

    nice -n 10 python benchmarks/bench_flatness.py --plates 10     # about 25 min on 2 cores
    nice -n 10 python benchmarks/bench_flatness.py --quick         # 2 plates a family

Writes benchmarks/results/flatness-<date>.json.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import datetime
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import linprog

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "plates"))
import generate  # noqa: E402  (the independent plate generator)

FAMILIES = ("smooth", "rough", "dent", "edge", "ripple", "seam")  # and "noisy" on request
EVAL_NODES = 41  # the run's evaluation grid per side (adaptive_cal.cell.build.EVAL_POINTS)


def _interpolator(map_path: Path) -> RegularGridInterpolator:
    """The true map, bilinear between its nodes (DESIGN.md's height-map format)."""
    a = np.loadtxt(map_path, delimiter=",", skiprows=1)
    xs, ys = np.unique(a[:, 0]), np.unique(a[:, 1])
    h = np.full((len(xs), len(ys)), np.nan)
    h[np.searchsorted(xs, a[:, 0]), np.searchsorted(ys, a[:, 1])] = a[:, 2]
    return RegularGridInterpolator((xs, ys), h)


def true_figures(map_path: Path, x_mm, y_mm, box_mm=None) -> dict:
    """Least-squares and minimum-zone flatness (mm) of the true map on the evaluation grid (with
    ``box_mm`` ((x0, x1), (y0, y1)): on a grid of as many nodes spanning that box, its edges
    included -- until 2026-11-29 the whole plate's nodes inside the box, which stop short of its
    edges, as the product did), each measured normal to its plane as the run measures it
    (``plane_figures``), and the tilt correction of the least-squares plane."""
    if box_mm is not None:
        x_mm, y_mm = box_mm
    gx, gy = np.meshgrid(np.linspace(*x_mm, EVAL_NODES), np.linspace(*y_mm, EVAL_NODES),
                         indexing="ij")
    x, y = gx.ravel(), gy.ravel()
    f = plane_figures(x, y, _interpolator(map_path)(np.c_[x, y]))
    a, b = f["a"], f["b"]
    # the tilt correction of that plane (README: frame_new = frame_nominal rotx(rx) roty(ry)
    # puts z on the plate normal (-a, -b, 1) / N: rotx(rx) roty(ry) e_z = (sin ry,
    # -sin rx cos ry, cos rx cos ry), so rx = atan(b), ry = asin(-a / N))
    tilt = {"rx_deg": float(np.degrees(np.arctan(b))),
            "ry_deg": float(np.degrees(np.arcsin(-a / np.sqrt(1.0 + a * a + b * b))))}
    return {"least_squares": f["least_squares"], "minimum_zone": f["minimum_zone"],
            "tilt": tilt}


def plane_figures(x, y, z) -> dict:
    """Least-squares and minimum-zone flatness (mm) of heights z at (x, y), each measured normal
    to its plane (Cheng eq. 5, ISO 1101), by numpy lstsq and scipy linprog; ``a``, ``b``: the
    least-squares plane's slopes."""
    A = np.c_[x, y, np.ones_like(x)]
    a, b, c = np.linalg.lstsq(A, z, rcond=None)[0]
    ls = np.ptp(z - A @ (a, b, c)) / np.sqrt(1.0 + a * a + b * b)
    n = len(z)  # minimum zone: min w s.t. |z - (a x + b y + c)| <= w / 2
    res = linprog(np.r_[0.0, 0.0, 0.0, 1.0],
                  A_ub=np.r_[np.c_[A, -np.ones(n)], np.c_[-A, -np.ones(n)]], b_ub=np.r_[z, -z],
                  bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    am, bm = res.x[:2]
    return {"least_squares": float(ls),
            "minimum_zone": float(2.0 * res.x[3] / np.sqrt(1.0 + am * am + bm * bm)),
            "a": float(a), "b": float(b)}


REPEATS = 50  # fresh repeat measurements of a run's touched points, for its touched interval
NOT_FUSED = {"gated", "rejected", "invalid"}  # docs/recording.md: rows the map does not fuse


def fused_touches(rec_path: Path) -> np.ndarray:
    """(N, 2) x, y (mm) of a recording's fused rows, read with the csv module (recording v1)."""
    with open(rec_path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    keep = [r for r in rows if not NOT_FUSED & set((r.get("flags") or "").split(";"))]
    return np.array([[float(r["x_mm"]), float(r["y_mm"])] for r in keep])


def repeat_noise_mm(noise: dict, rng: np.random.Generator, n: int) -> np.ndarray:
    """Reading noise as the cell draws it: 5 um Gaussian, or the manifest's Student-t at the
    same sd. Its gross errors (10 sd) are left out: a run gates them and takes the point again,
    so a repeat's fused readings would not hold them either."""
    if noise.get("kind") != "student_t":
        return 0.005 * rng.standard_normal(n)
    dof = float(noise["dof"])
    return 0.005 * np.sqrt((dof - 2.0) / dof) * rng.standard_t(dof, n)


def touched_repeats(map_path: Path, rec_path: Path, touched: dict, noise: dict,
                    seed: int) -> dict:
    """The share of REPEATS fresh measurements of the run's fused touches (the true map there
    plus the cell's noise) whose figures lie inside the run's touched-points intervals -- what
    those intervals claim: the figure over predicted repeat measurements at the same touches."""
    xy = fused_touches(rec_path)
    h = _interpolator(map_path)(xy)
    rng = np.random.default_rng(seed)
    inside = {"least_squares": 0, "minimum_zone": 0}
    for _ in range(REPEATS):
        figs = plane_figures(xy[:, 0], xy[:, 1], h + repeat_noise_mm(noise, rng, len(h)))
        for k in inside:
            lo, hi = touched[k]["ci95"]
            inside[k] += lo <= figs[k] <= hi
    return {"points": len(xy), **{k: v / REPEATS for k, v in inside.items()}}


def plate_cell(cell: dict, map_path: Path, seed: int, noise: dict, budget: int) -> dict:
    """The study's cell with the plate's map as its true surface, 5 um readings (Student-t and
    gross errors where the generator's manifest says so), a 4 um RMS stop and ``budget``."""
    cell = json.loads(json.dumps(cell))
    cell["simulation"] = {"seed": seed, "noise_std_mm": 0.005, "repeatability_mm": 0.0,
                          "surface_file": str(map_path)}
    if noise.get("kind") == "student_t":  # the generator's manifest: the sd stays 5 um
        cell["simulation"].update(noise_dof=float(noise["dof"]),
                                  outlier_rate=float(noise["outlier_rate"]),
                                  outlier_mm=float(noise["outlier_mm"]))
    cell["plan"] = {"stop": {"mean_std_mm": 0.004, "max_touches": budget}, "candidates": 10000}
    return cell


def run_plate(cell: dict, folder: Path) -> subprocess.CompletedProcess:
    """``adaptive-cal run`` on ``cell`` into ``folder``/run, as a user runs it (a subprocess).
    ``returncode`` 0 also for a budget spent with the bound unmet (exit 1 since 2026-11-24: not
    a result for a user, a run the benchmark counts as it did); drift, rejected touches or
    readings stay errors."""
    path = folder / "cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    p = subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot", str(path),
                        "--out", str(folder / "run"), "--no-progress", "--yes"],
                       capture_output=True, text=True)
    result = folder / "run" / "result.json"
    if p.returncode == 1 and result.is_file() and json.loads(result.read_text())[
            "stopped_because"] in ("touch_budget", "no_admissible_point"):
        p.returncode = 0
    return p


def plate_jobs(families: list[str], plates: int) -> list[tuple]:
    """(family, index, map path, the study's cell, the manifest's noise) of the first ``plates``
    plates of each family, the maps generated first where missing."""
    maps = ROOT / "benchmarks" / "plates" / "out"
    if not all((maps / f / f"plate-{plates - 1:03d}.csv").exists() for f in families):
        generate.generate(maps, max(plates, 20))
    cell = yaml.safe_load((ROOT / "configs" / "study-plates.yaml").read_text())["cell"]
    manifest = json.loads((maps / "manifest.json").read_text())["plates"]
    return [(f, i, maps / f / f"plate-{i:03d}.csv", cell,
             manifest.get(f"{f}/plate-{i:03d}.csv", {}).get("noise", {}))
            for f in families for i in range(plates)]


def run_jobs(one, jobs: list, workers: int, line) -> list[dict]:
    """``one`` on every job in ``workers`` processes, a line per plate as it ends (``line`` of
    its record, or FAILED with the error's tail); the records in the jobs' order."""
    records = []
    with cf.ProcessPoolExecutor(workers) as pool:
        for rec in pool.map(one, jobs):
            records.append(rec)
            what = f"FAILED {rec['error'][-200:]}" if "error" in rec else line(rec)
            print(f"{rec['family']:7s} {rec['plate']:2d}: {what}", flush=True)
    return records


def one_plate(job: tuple) -> dict:
    family, index, map_path, cell, budget, seed, noise = job
    cell = plate_cell(cell, map_path, seed + index, noise, budget)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        p = run_plate(cell, Path(tmp))
        if p.returncode:
            return {"family": family, "plate": index, "error": p.stderr[-800:]}
        r = json.loads((Path(tmp) / "run" / "result.json").read_text())
        repeats = (touched_repeats(map_path, Path(tmp) / "run" / "recording.csv",
                                   r["touched_flatness_mm"], noise, seed + 1000 + index)
                   if r.get("touched_flatness_mm") else None)
    truth = true_figures(map_path, cell["workplane"]["x_mm"], cell["workplane"]["y_mm"])
    out = {"family": family, "plate": index, "touches": r["touches"],
           "stopped_because": r["stopped_because"], "wall_s": time.perf_counter() - t0,
           "unresolved_rms_mm": (r.get("model") or {}).get("unresolved_rms_mm"),
           "largest_gap": r.get("largest_gap"), "local_features": r.get("local_features", []),
           "touched_repeats": repeats,
           "touched_points": (r.get("touched_flatness_mm") or {}).get("points")}
    t = r["tilt"]  # the tilt correction's 2-sd interval against the true map's plane
    out["tilt"] = {k: {"true": truth["tilt"][k], "value": t[k], "std": t[f"{k[:2]}_std_deg"],
                       "in_2sd": abs(t[k] - truth["tilt"][k]) <= 2.0 * t[f"{k[:2]}_std_deg"]}
                   for k in ("rx_deg", "ry_deg")}
    within = r.get("flatness_within_reach_mm")
    inner = (true_figures(map_path, cell["workplane"]["x_mm"], cell["workplane"]["y_mm"],
                          within["box_mm"]) if within else None)
    for k in ("least_squares", "minimum_zone"):
        out[k] = _judged(r["flatness_mm"][k], truth[k])
        if within:  # the figures of the part touches could reach (the plate less its margin)
            out[f"{k}_within_reach"] = _judged(within[k], inner[k])
    return out


def _judged(f: dict, true: float) -> dict:
    lo, hi = f["ci95"]
    return {"true": true, "value": f["value"], "ci95": [lo, hi],
            "where": "in" if lo <= true <= hi else ("above" if true > hi else "below")}


def _families(ok: list[dict]) -> list[str]:
    return [f for f in FAMILIES + ("noisy",) if any(r["family"] == f for r in ok)] + ["all"]


def _where(rr: list[dict], key: str) -> str:
    """in / above / below of the records' figure ``key``."""
    w = [r[key]["where"] for r in rr]
    return f"{w.count('in')}/{len(w)} = {w.count('in') / len(w):.2f} / " \
           f"{w.count('above')} / {w.count('below')}"


def report(records: list[dict]) -> list[str]:
    lines = ["family    plates  touches  least squares: in / above / below   minimum zone: "
             "in / above / below   true MZ um (median)  claimed MZ um (median)  local features"]
    ok = [r for r in records if "error" not in r]
    for family in _families(ok):
        rr = [r for r in ok if family in ("all", r["family"])]
        lines.append(f"{family:8s}  {len(rr):6d}  {np.mean([r['touches'] for r in rr]):7.1f}  "
                     f"{_where(rr, 'least_squares'):>33s}   {_where(rr, 'minimum_zone'):>32s}   "
                     f"{1e3 * np.median([r['minimum_zone']['true'] for r in rr]):8.1f}"
                     f"             {1e3 * np.median([r['minimum_zone']['value'] for r in rr]):8.1f}"
                     f"          {sum(len(r.get('local_features') or ()) for r in rr):3d}")
    if any("minimum_zone_within_reach" in r for r in ok):
        lines.append("within reach of the touches (the plate less its edge margin):")
        for family in _families(ok):
            rr = [r for r in ok if family in ("all", r["family"])
                  and "minimum_zone_within_reach" in r]
            mz = [r["minimum_zone_within_reach"] for r in rr]
            lines.append(f"{family:8s}  {len(rr):6d}  {'':7s}  "
                         f"{_where(rr, 'least_squares_within_reach'):>33s}   "
                         f"{_where(rr, 'minimum_zone_within_reach'):>32s}   "
                         f"{1e3 * np.median([m['true'] for m in mz]):8.1f}             "
                         f"{1e3 * np.median([m['value'] for m in mz]):8.1f}")
    if any(r.get("touched_repeats") for r in ok):
        lines.append(f"touched points: share of {REPEATS} fresh repeat measurements at the "
                     "fused touches whose figure lies in the run's 95 % interval (mean, min)")
        for family in _families(ok):
            rr = [r["touched_repeats"] for r in ok
                  if family in ("all", r["family"]) and r.get("touched_repeats")]
            cells = [f"{k} {np.mean([q[k] for q in rr]):.3f}, {min(q[k] for q in rr):.2f}"
                     for k in ("least_squares", "minimum_zone")]
            lines.append(f"{family:8s}  {len(rr):6d}  " + "   ".join(cells))
    if any("tilt" in r for r in ok):
        lines.append("tilt correction: the true map's plane inside the run's rx, ry +- 2 sd "
                     "(95.4 % if calibrated); median |error| / sd (0.67 if calibrated); RMS "
                     "error / sd over both angles (1.0)")
        for family in _families(ok):
            rr = [r for r in ok if family in ("all", r["family"]) and "tilt" in r]
            cells = []
            for k in ("rx_deg", "ry_deg"):
                inside = sum(r["tilt"][k]["in_2sd"] for r in rr)
                z = np.median([abs(r["tilt"][k]["value"] - r["tilt"][k]["true"])
                               / r["tilt"][k]["std"] for r in rr])
                cells.append(f"{k[:2]} {inside}/{len(rr)} = {inside / len(rr):.2f}, {z:.2f}")
            rms = np.sqrt(np.mean([((r["tilt"][k]["value"] - r["tilt"][k]["true"])
                                    / r["tilt"][k]["std"]) ** 2
                                   for r in rr for k in ("rx_deg", "ry_deg")]))
            lines.append(f"{family:8s}  {len(rr):6d}  " + "   ".join(cells) + f"   RMS {rms:.2f}")
    errors = [r for r in records if "error" in r]
    if errors:
        lines.append(f"{len(errors)} runs failed, first: {errors[0]['error']}")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--plates", type=int, default=10, help="plates per family")
    p.add_argument("--quick", action="store_true", help="2 plates per family")
    p.add_argument("--families", default=",".join(FAMILIES))
    p.add_argument("--budget", type=int, default=120, help="touch budget per run")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=100, help="the simulated cell's noise seed base")
    p.add_argument("--out", default=None, help="JSON of the records")
    args = p.parse_args(argv)
    plates = 2 if args.quick else args.plates
    families = [f for f in args.families.split(",") if f]
    jobs = [(f, i, m, cell, args.budget, args.seed, noise)
            for f, i, m, cell, noise in plate_jobs(families, plates)]
    t0 = time.perf_counter()

    def line(rec):
        mz = rec["minimum_zone"]
        return (f"{rec['touches']:3d} touches, true MZ {1e3 * mz['true']:6.1f} um, claimed "
                f"{1e3 * mz['value']:6.1f} um (95 % {1e3 * mz['ci95'][0]:.1f} .. "
                f"{1e3 * mz['ci95'][1]:.1f}) {mz['where']}")

    records = run_jobs(one_plate, jobs, args.workers, line)
    lines = report(records)
    print("\n".join(lines))
    print(f"wall time {time.perf_counter() - t0:.0f} s for {len(jobs)} runs ({args.workers} workers)")
    out = Path(args.out or ROOT / "benchmarks" / "results" /
               f"flatness-{datetime.date.today().isoformat()}.json")
    out.write_text(json.dumps({"plates": plates, "budget": args.budget, "seed": args.seed,
                               "records": records, "report": lines}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
