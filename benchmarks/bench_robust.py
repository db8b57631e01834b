"""Robust readings: coverage and error of the posterior band on simulated plates with
heavy-tailed (Student-t, 3 dof) reading noise, and with gross outliers, through the library's
ask/tell (retakes included) to the survey's own stop.

    python benchmarks/bench_robust.py --quick        # 3 plates per family, about 1-2 min

Plates: the prior's own family (form amplitude 0.05 mm, the sim cell's knots), random tilt.
Noise: Student-t(3) scaled to a 5 um std; 'outliers': Gaussian 5 um plus 2 % readings with a
0.5 mm Gaussian gross error. Prints touches, the claimed RMS posterior std, the true RMS error
(um), coverage of the 95 % band over the evaluation grid (mean, min) and flags counted.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def one_plate(plan, sv, ask, bl, seed: int, family: str):
    rng = np.random.default_rng([seed, 14])
    truth = bl.sample(plan.model.belief(plan.model.hyper0), rng, 1)[0]
    state = sv.start(plan)
    gated = flagged = 0
    while sv.stop_reason(plan, state) is None and state.touches < 120:
        t = ask(plan, state)[0]
        h = plan.model.surface.basis(np.array([t.x_mm]), np.array([t.y_mm]))[0]
        if family == "student_t3":
            noise = 0.005 / np.sqrt(3.0) * rng.standard_t(3)
        else:
            noise = 0.005 * rng.standard_normal()
            if rng.random() < 0.02:
                noise += 0.5 * rng.standard_normal()
        reading = float(h @ truth) - t.z_mm + plan.zero_mm + noise
        state, told = sv.tell(plan, state, t.x_mm, t.y_mm, t.z_mm, reading)
        gated += "gated" in told.flags
        flagged += any(f.startswith("outlier=") for f in told.flags)
    mean, var = bl.predict(state.belief, plan.eval_rows)
    err = mean - plan.eval_rows @ truth
    cover = float(np.mean(np.abs(err) <= bl.Z95 * np.sqrt(var)))
    return state.touches, sv.status(plan, state).mean_std_mm, float(np.sqrt(np.mean(err**2))), \
        cover, gated, flagged


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 plates per family")
    ap.add_argument("--plates", type=int, default=8)
    args = ap.parse_args()
    import adaptive_cal
    adaptive_cal.use_float64()
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.gaussian import belief as bl
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.ask import ask
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from helpers import sim_cell
    plan = survey_plan(sim_cell())
    n = 3 if args.quick else args.plates
    print(f"code: {adaptive_cal.__file__}")
    print("family      | touches | claimed RMS std um | true RMS um | coverage95 mean, min | "
          "gated | outlier flags")
    for family in ("student_t3", "outliers_2pct"):
        res = np.array([one_plate(plan, sv, ask, bl, s, family) for s in range(n)])
        print(f"{family:11s} | {res[:, 0].mean():7.1f} | {1e3 * res[:, 1].mean():17.2f} | "
              f"{1e3 * res[:, 2].mean():11.2f} | {res[:, 3].mean():.3f}, {res[:, 3].min():.3f}"
              f"         | {res[:, 4].sum():5.0f} | {res[:, 5].sum():4.0f}", flush=True)


if __name__ == "__main__":
    main()
