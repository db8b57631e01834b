"""Study throughput in plate-runs per second.

1. vmap against a Python loop: a fixed design with fixed hyper-parameters (random touches, a
   different design per plate, figures after every touch), all plates in one ``jax.vmap`` of a
   ``lax.scan`` against one plate and one touch at a time in numpy.
2. Dask 1 against 2 workers (LocalCluster, one thread each): the per-plate strategies (adaptive
   planner on the simulated cell) of a small study.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_study.py [--plates 64] [--dask-plates 8]

Writes benchmarks/results/study.json.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

from adaptive_cal.study.batch import run_fixed  # noqa: E402
from adaptive_cal.study.designs import evaluate_loop, evaluate_vmap, random_points  # noqa: E402
from adaptive_cal.study.plates import heights_at  # noqa: E402
from adaptive_cal.study.config import load_study, parse_study  # noqa: E402
from adaptive_cal.study.plates import plate_cell, sample_plate  # noqa: E402
from adaptive_cal.cli.study import worker_setup  # noqa: E402  (as adaptive-cal study --workers)
from adaptive_cal.study.runner import connect, run_study  # noqa: E402
from adaptive_cal.study.strategies import Context  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def vmap_vs_loop(study, base, plates: int, loop_plates: int) -> dict:
    """The evaluation on prepared inputs (designs, readings, truths): one vmap call against
    the loop; and end to end (inputs and records included) through ``run_fixed``."""
    contexts = []
    for i in range(plates):
        p = sample_plate(study, i)
        contexts.append(Context.create(study, p, plate_cell(study, base, p)))
    n = study.bound.max_touches
    model, ev = contexts[0].model, contexts[0].evaluator
    xys = [random_points(c.cell, n, np.random.default_rng([c.plate.seed, 7])) for c in contexts]
    rows = np.array([model.surface.basis(xy[:, 0], xy[:, 1]) for xy in xys])
    heights = np.array([heights_at(c.cell, xy) for c, xy in zip(contexts, xys)])
    truth = np.array([c.truth_eval for c in contexts])
    touches = np.full(plates, n)
    prior, r = model.belief(model.hyper0), model.hyper0.noise_std_mm**2
    out = {"design": "random", "touches_per_plate": n, "coefficients": model.surface.size,
           "vmap_plates": plates, "loop_plates": loop_plates}
    evaluate_vmap(prior, r, ev, rows, heights, truth, touches)  # compile
    t0 = time.perf_counter()
    (_, rms_v, _), _ = evaluate_vmap(prior, r, ev, rows, heights, truth, touches)
    out["vmap_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    (_, rms_l, _), _ = evaluate_loop(prior, r, ev, rows[:loop_plates], heights[:loop_plates],
                                     truth[:loop_plates], touches[:loop_plates])
    out["loop_s"] = time.perf_counter() - t0
    out["vmap_plates_per_s"] = plates / out["vmap_s"]
    out["loop_plates_per_s"] = loop_plates / out["loop_s"]
    out["max_abs_diff_true_rms_mm"] = float(np.abs(rms_v[:loop_plates] - rms_l).max())
    targets = [study.bound.true_mm] * plates
    run_fixed("random", contexts[:2], targets[:2], how="vmap")
    for how, k in (("vmap", plates), ("loop", loop_plates)):
        t0 = time.perf_counter()
        run_fixed("random", contexts[:k], targets[:k], how=how)
        out[f"end_to_end_{how}_plates_per_s"] = k / (time.perf_counter() - t0)
    return out


def dask_workers(study, base, plates: int) -> dict:
    data = study.model_dump(mode="json")
    data.update(plates=plates, strategies=["adaptive"], lower_bound={"plates": 0})
    s = parse_study(data)
    out = {"strategy": "adaptive", "plates": plates,
           "bound_mean_std_mm": s.bound.mean_std_mm}
    with tempfile.TemporaryDirectory() as tmp:
        run_study(s.model_copy(update={"seed": s.seed + 1, "plates": 1}), base,
                  Path(tmp) / "warm.jsonl")  # compile in this process first
        t0 = time.perf_counter()
        run_study(s, base, Path(tmp) / "inproc.jsonl")
        out["in_process_s"] = time.perf_counter() - t0
        for workers in (1, 2):
            client = connect(None, workers)
            try:  # warm the workers (imports, JAX compilation) on other plates first
                warm = s.model_copy(update={"seed": s.seed + 1, "plates": workers})
                run_study(warm, base, Path(tmp) / f"warm{workers}.jsonl", client=client,
                          worker_setup=worker_setup)
                t0 = time.perf_counter()
                run_study(s, base, Path(tmp) / f"w{workers}.jsonl", client=client,
                          worker_setup=worker_setup)
                out[f"workers_{workers}_s"] = time.perf_counter() - t0
            finally:
                client.close()
    for k in ("in_process", "workers_1", "workers_2"):
        out[f"{k}_plates_per_s"] = plates / out[f"{k}_s"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plates", type=int, default=64)
    ap.add_argument("--loop-plates", type=int, default=8)
    ap.add_argument("--dask-plates", type=int, default=16)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "study.json"))
    args = ap.parse_args()
    study, base = load_study(ROOT / "configs" / "study-smoke.yaml")
    data = study.model_dump(mode="json")
    data["bound"].update(mean_std_mm=0.005, max_touches=100)
    study = parse_study(data)
    res = {"machine": f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start",
           "vmap_vs_loop": vmap_vs_loop(study, base, args.plates, args.loop_plates)}
    v = res["vmap_vs_loop"]
    print(f"evaluation: vmap {v['vmap_plates_per_s']:.1f} plate-runs/s ({args.plates} plates), "
          f"loop {v['loop_plates_per_s']:.2f} -> {v['vmap_plates_per_s'] / v['loop_plates_per_s']:.1f}x; "
          f"end to end: vmap {v['end_to_end_vmap_plates_per_s']:.1f}, loop "
          f"{v['end_to_end_loop_plates_per_s']:.1f} plate-runs/s")
    d = res["dask"] = dask_workers(study, base, args.dask_plates)
    print(f"adaptive planner, {args.dask_plates} plates: in-process {d['in_process_plates_per_s']:.2f}, "
          f"Dask 1 worker {d['workers_1_plates_per_s']:.2f}, 2 workers "
          f"{d['workers_2_plates_per_s']:.2f} plate-runs/s")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
