"""Realistic plates (issue 14, item 7): the product's own study loop on plates written
independently of its prior, against the issue's targets.

The maps come from benchmarks/plates/generate.py (numpy/scipy only; written if missing). Each
family runs as a study of configs/study-plates.yaml with ``plate.surface_files`` set to that
family's maps, through ``adaptive_cal.study.tasks.plate_task`` (strategies adaptive, grid,
paper: the loop, the serpentine grid and the reference procedure of strategies.py). The
``noisy`` family's readings follow the generator's manifest: Student-t noise of its degrees of
freedom (``simulation.noise_dof``; the study's 5 um stays the standard deviation, as the
generator's) and its gross errors (``simulation.outlier_rate`` / ``outlier_mm``, the mean rate).

Printed per family and strategy: touches and robot time (s; xy travel from the plate centre at
robot.speed_mm_per_s + touch_time_s per touch) at the strategy's own stop, the claimed RMS
posterior std, the true RMS error, coverage95 (mean, min; share of evaluation-grid points with
|true - mean| <= 1.96 std), touches and robot time to the true-RMS target (first point of the
trajectory at or below bound.true_rms_mm; a plate that never gets there counts the touch
budget), then the issue's targets with PASS / MISS.

    nice -n 10 python benchmarks/bench_plates.py --quick        # 2 plates per family, ~3 min
    nice -n 10 python benchmarks/bench_plates.py                # 20 plates per family
    nice -n 10 python benchmarks/bench_plates.py --workers 2    # the same, on two processes
    nice -n 10 python benchmarks/bench_plates.py --quick --doc  # also rewrite docs/plates.md
    python benchmarks/bench_plates.py --doc --from-json benchmarks/results/plates-DATE.json

Writes benchmarks/results/plates-<date>.json (and docs/plates.md + docs/plates-*.png with --doc).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from multiprocessing import get_context  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import adaptive_cal  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "plates"))
import generate  # noqa: E402  (benchmarks/plates/generate.py: the independent generator)

from adaptive_cal.planning.route import path_length_mm  # noqa: E402
from adaptive_cal.study.config import load_study  # noqa: E402
from adaptive_cal.study.tasks import plate_task  # noqa: E402

STUDY = ROOT / "configs" / "study-plates.yaml"
STRATEGIES = ("adaptive", "grid", "paper")
TOUCH_TARGET = {"dent": 0.6, "edge": 0.6, "seam": 0.6, "smooth": 1.05, "rough": 1.05}
COVERAGE = (0.90, 0.98)
TRUE_OVER_BOUND = 1.25


def family_study(study, family: str, maps: Path, plates: int):
    plate = study.plate.model_copy(update={"surface_files": str(maps / family / "plate-*.csv")})
    return study.model_copy(update={"plate": plate, "plates": plates})


def _job(job: tuple) -> list[dict]:
    """One plate's strategies (a worker process: float64 set there too)."""
    study_data, base, family, i = job
    adaptive_cal.use_float64()
    return [dict(rec, family=family) for rec in plate_task(study_data, base, i, STRATEGIES)]


def family_base(base: dict, family: str, manifest: dict) -> dict:
    """The base cell; for the noisy family with the manifest's Student-t degrees of freedom and
    gross errors (mean rate)."""
    specs = [d["noise"] for k, d in manifest["plates"].items() if k.startswith(family + "/")]
    specs = [s for s in specs if s["kind"] == "student_t"]
    if not specs:
        return base
    sim = dict(base.get("simulation") or {})
    sim.update(noise_dof=float(specs[0]["dof"]),
               outlier_rate=float(np.mean([s["outlier_rate"] for s in specs])),
               outlier_mm=float(specs[0]["outlier_mm"]))
    return {**base, "simulation": sim}


def to_target(rec: dict, target_mm: float, budget: int, start, speed, touch_s):
    """(touches, robot time s, reached) to the first trajectory point at or below the target."""
    for t, _, rms in rec["trajectory"]:
        if rms <= target_mm:
            if rec["strategy"] == "grid":  # each grid is its own run
                return t, rec.get("robot_time_true_s"), True
            xy = np.asarray(rec["xy"], float)[:t]
            return t, path_length_mm(start, xy) / speed + t * touch_s, True
    return budget, None, False


KEEP = ("family", "strategy", "plate", "seed", "noise_std_mm", "touches", "stop_reason",
        "robot_time_s", "mean_std_mm", "true_rms_mm", "true_max_mm", "coverage95",
        "native_true_rms_mm")


def slim(rec: dict, target_mm: float, budget: int) -> dict:
    """A record for the results file: the figures at the own stop and the touches to the
    true-RMS target (trajectories, touch positions and hyper-parameters left out)."""
    reached = [t for t, _, rms in rec["trajectory"] if rms <= target_mm]
    return {**{k: rec[k] for k in KEEP if k in rec},
            "touches_to_target": reached[0] if reached else None, "budget": budget}


def summarise(records: list[dict], study, base: dict) -> dict:
    wp, robot = base["workplane"], base["robot"]
    start = (0.5 * sum(wp["x_mm"]), 0.5 * sum(wp["y_mm"]))
    target, budget = study.bound.true_mm, study.bound.max_touches
    out = {}
    for family in sorted({r["family"] for r in records}, key=generate.FAMILIES.index):
        for s in STRATEGIES:
            rs = [r for r in records if r["family"] == family and r["strategy"] == s]
            if not rs:
                continue
            tt = [to_target(r, target, budget, start, robot["speed_mm_per_s"],
                            robot["touch_time_s"]) for r in rs]
            times = [t[1] for t in tt if t[1] is not None]
            out.setdefault(family, {})[s] = {
                "plates": len(rs),
                "touches": float(np.mean([r["touches"] for r in rs])),
                "robot_time_s": float(np.mean([r["robot_time_s"] for r in rs])),
                "claimed_rms_std_um": 1e3 * float(np.mean([r["mean_std_mm"] for r in rs])),
                "true_rms_um": 1e3 * float(np.mean([r["true_rms_mm"] for r in rs])),
                "coverage95_mean": float(np.mean([r["coverage95"] for r in rs])),
                "coverage95_min": float(np.min([r["coverage95"] for r in rs])),
                "touches_to_target": float(np.mean([t[0] for t in tt])),
                "reached_target": int(sum(t[2] for t in tt)),
                "robot_time_to_target_s": float(np.mean(times)) if times else None}
    return out


def intervals(records: list[dict], bound_um: float, draws: int = 2000,
              seed: int = 0) -> dict[str, list[float]]:
    """A 95 % percentile-bootstrap interval for each target's figure (``verdicts``' names):
    plates resampled with replacement within each family, the same plates for every strategy
    (the strategies ran on the same plates: a paired comparison), ``draws`` times. The figures
    are means over 20 plates a family; the interval says how far another 20 plates drawn the
    same way could move them, i.e. whether a PASS or MISS is the plates' draw. A plate that
    never reached the true-RMS target counts the touch budget, as in ``summarise``."""
    rng = np.random.default_rng(seed)
    fams: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for fam in dict.fromkeys(r["family"] for r in records):
        for s in ("adaptive", "grid"):
            rs = sorted((r for r in records if r["family"] == fam and r["strategy"] == s),
                        key=lambda r: r["plate"])
            if rs:
                fams.setdefault(fam, {})[s] = {
                    k: np.array([r[k] for r in rs], float)
                    for k in ("coverage95", "true_rms_mm", "touches", "robot_time_s")}
                fams[fam][s]["to_target"] = np.array(
                    [r["touches_to_target"] if r["touches_to_target"] is not None
                     else r["budget"] for r in rs], float)
    stats: dict[str, list[float]] = {}
    paired = {f: v for f, v in fams.items() if "grid" in v
              and len(v["grid"]["touches"]) == len(v["adaptive"]["touches"])}
    for _ in range(draws):
        idx = {f: rng.integers(0, len(v["adaptive"]["touches"]), len(v["adaptive"]["touches"]))
               for f, v in fams.items() if "adaptive" in v}
        for f, i in idx.items():
            a = fams[f]["adaptive"]
            stats.setdefault(f"{f}: coverage95 (adaptive)", []).append(a["coverage95"][i].mean())
            stats.setdefault(f"{f}: true RMS / stated bound (adaptive)", []).append(
                1e3 * a["true_rms_mm"][i].mean() / bound_um)
            if f in paired and f in TOUCH_TARGET:
                stats.setdefault(f"{f}: touches to true-RMS target vs grid", []).append(
                    a["to_target"][i].mean() / paired[f]["grid"]["to_target"][i].mean())
        if paired and len(paired) == len(idx):
            for key, name in (("robot_time_s", "mix: robot time at own stop vs grid"),
                              ("touches", "mix: touches at own stop vs grid")):
                a = np.mean([fams[f]["adaptive"][key][idx[f]].mean() for f in paired])
                g = np.mean([fams[f]["grid"][key][idx[f]].mean() for f in paired])
                stats.setdefault(name, []).append(a / g)
    return {k: [round(float(v), 3) for v in np.percentile(x, [2.5, 97.5])]
            for k, x in stats.items()}


def verdicts(summary: dict, bound_um: float, ci: dict | None = None) -> list[dict]:
    """The issue's targets, each with its figure and PASS / MISS (and, given ``ci`` from
    ``intervals``, its 95 % bootstrap interval over plates)."""
    out = []

    def add(what, value, ok, target, bounds):
        out.append({"target": what, "value": value, "target_text": target, "bounds": bounds,
                    "verdict": "PASS" if ok else "MISS", "interval": (ci or {}).get(what)})

    mix = {s: [summary[f][s] for f in summary if s in summary[f]] for s in ("adaptive", "grid")}
    for family, row in summary.items():
        a, g = row.get("adaptive"), row.get("grid")
        if a is None:
            continue
        c = a["coverage95_mean"]
        add(f"{family}: coverage95 (adaptive)", round(c, 3), COVERAGE[0] <= c <= COVERAGE[1],
            f"{COVERAGE[0]}-{COVERAGE[1]}", list(COVERAGE))
        ratio = a["true_rms_um"] / bound_um
        add(f"{family}: true RMS / stated bound (adaptive)", round(ratio, 3),
            ratio <= TRUE_OVER_BOUND, f"<= {TRUE_OVER_BOUND}", [TRUE_OVER_BOUND])
        if g is not None and family in TOUCH_TARGET:
            r = a["touches_to_target"] / g["touches_to_target"]
            none = a["reached_target"] == 0 and g["reached_target"] == 0  # nothing measured
            add(f"{family}: touches to true-RMS target vs grid", round(r, 3),
                r <= TOUCH_TARGET[family] and not none, f"<= {TOUCH_TARGET[family]}"
                + (" (neither reached the target on any plate)" if none else ""),
                [TOUCH_TARGET[family]])
    if mix["adaptive"] and len(mix["adaptive"]) == len(mix["grid"]):
        rt = (np.mean([x["robot_time_s"] for x in mix["adaptive"]])
              / np.mean([x["robot_time_s"] for x in mix["grid"]]))
        add("mix: robot time at own stop vs grid", round(float(rt), 3), rt <= 1.0, "<= 1.0",
            [1.0])
        tr = (np.mean([x["touches"] for x in mix["adaptive"]])
              / np.mean([x["touches"] for x in mix["grid"]]))
        add("mix: touches at own stop vs grid", round(float(tr), 3), tr <= 0.92, "<= 0.92",
            [0.92])
    return out


def table(summary: dict, checks: list[dict]) -> str:
    def f(v, fmt):
        return "-" if v is None else fmt.format(v)

    lines = ["| family | strategy | plates | touches | robot time s | claimed RMS std um | "
             "true RMS um | coverage95 mean, min | touches to target (reached) | "
             "robot time to target s |", "|" + "---|" * 10]
    for family, row in summary.items():
        for s, x in row.items():
            lines.append(
                f"| {family} | {s} | {x['plates']} | {x['touches']:.1f} | {x['robot_time_s']:.0f} "
                f"| {x['claimed_rms_std_um']:.1f} | {x['true_rms_um']:.1f} | "
                f"{x['coverage95_mean']:.2f}, {x['coverage95_min']:.2f} | "
                f"{x['touches_to_target']:.1f} ({x['reached_target']}/{x['plates']}) | "
                f"{f(x['robot_time_to_target_s'], '{:.0f}')} |")
    lines += ["", "| target | value | 95 % interval, plates resampled | wanted | verdict |",
              "|---|---|---|---|---|"]
    lines += [f"| {c['target']} | {c['value']} | {_interval(c.get('interval'))} | "
              f"{c['target_text']} | {c['verdict']}{_settled(c)} |" for c in checks]
    return "\n".join(lines)


def _interval(iv) -> str:
    return "-" if not iv else f"{iv[0]:g} .. {iv[1]:g}"


def _settled(check: dict) -> str:
    """" (the draw)" where the interval reaches across the target's bound: another set of
    plates could turn the verdict; "" where it lies wholly on one side (or is unknown)."""
    iv = check.get("interval")
    if not iv:
        return ""
    return " (the draw)" if any(iv[0] <= b <= iv[1] for b in check["bounds"]) else ""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="2 plates per family (about 3 min)")
    p.add_argument("--plates", type=int, default=None, help="plates per family (default 20)")
    p.add_argument("--families", default=",".join(generate.FAMILIES))
    p.add_argument("--maps", default=str(ROOT / "benchmarks" / "plates" / "out"))
    p.add_argument("--json", default=None, help="default benchmarks/results/plates-<date>.json")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1; the records "
                   "are the same with any number)")
    p.add_argument("--doc", action="store_true", help="rewrite docs/plates.md and its figures")
    p.add_argument("--from-json", metavar="RESULTS.json", help="no run: print (and with --doc "
                   "write the page) from an earlier results file")
    args = p.parse_args(argv)
    if args.from_json:
        old = json.loads(Path(args.from_json).read_text())
        old["targets"] = verdicts(old["summary"], old["bound_um"],
                                  intervals(old["records"], old["bound_um"]))
        text = table(old["summary"], old["targets"])
        print(text)
        if args.doc:
            import plates_doc  # benchmarks/plates/plates_doc.py
            plates_doc.write(ROOT / "docs", old["summary"], old["targets"], text,
                             old["plates_per_family"], old["date"], old["quick"])
        return 0
    plates = args.plates or (2 if args.quick else 20)
    families = [f for f in args.families.split(",") if f]
    adaptive_cal.use_float64()
    maps = Path(args.maps)
    manifest_path = maps / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else None
    have = manifest and all(f"{f}/plate-{plates - 1:03d}.csv" in manifest["plates"]
                            for f in families)
    if not have:
        manifest = generate.generate(maps, max(plates, 20 if not args.quick else plates),
                                     generate.FAMILIES)
    study, base = load_study(STUDY)
    jobs = [(family_study(study, f, maps, plates).model_dump(mode="json"),
             family_base(base, f, manifest), f, i) for f in families for i in range(plates)]
    records, t0 = [], time.perf_counter()
    # each plate is independent and seeded by its index: more workers, the same records sooner
    # (imap keeps the jobs' order: the records as a single process writes them)
    with (get_context("spawn").Pool(args.workers) if args.workers > 1
          else contextlib.nullcontext()) as pool:
        done = pool.imap(_job, jobs) if pool is not None else map(_job, jobs)
        for k, recs in enumerate(done, 1):
            records += recs
            if k % plates == 0:
                print(f"  {jobs[k - 1][2]}: {plates} plates done at "
                      f"{time.perf_counter() - t0:.0f} s", flush=True)
    summary = summarise(records, study, base)
    bound_um = 1e3 * study.bound.mean_std_mm
    slimmed = [slim(r, study.bound.true_mm, study.bound.max_touches) for r in records]
    checks = verdicts(summary, bound_um, intervals(slimmed, bound_um))
    text = table(summary, checks)
    print(text)
    date = datetime.date.today().isoformat()
    out = Path(args.json or ROOT / "benchmarks" / "results" / f"plates-{date}.json")
    out.write_text(json.dumps({"date": date, "plates_per_family": plates, "quick": args.quick,
                               "wall_s": time.perf_counter() - t0, "bound_um":
                               1e3 * study.bound.mean_std_mm, "target_true_um":
                               1e3 * study.bound.true_mm, "summary": summary,
                               "targets": checks, "records": slimmed},
                              indent=None, separators=(",", ":")))
    print(f"wrote {out} ({time.perf_counter() - t0:.0f} s)")
    if args.doc:
        import plates_doc  # benchmarks/plates/plates_doc.py
        plates_doc.write(ROOT / "docs", summary, checks, text, plates, date, args.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
