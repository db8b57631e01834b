"""Decision latency: which touch next, on the same problem, by three implementations.

* ours: ``planner.variance_drop`` (one jit-compiled (N x K)(K x 2K) product) + argmax, and the
  whole ``ask()`` (planning.ask) (stroke check and gradient refinement included);
* numpy: the same closed form in plain numpy (``planner.variance_drop_numpy``);
* BoTorch: ``qNegIntegratedPosteriorVariance`` (256 integration points) maximised by
  ``optimize_acqf`` (5 restarts, raw samples = the candidate count) on a GPyTorch exact GP whose
  kernel is our spline prior k(p, p') = h(p)^T C0 h(p') with the same fixed noise -- the same
  posterior as our belief -- and, on our candidate set, ``optimize_acqf_discrete``.

Each choice is scored by the exact integrated variance J = trace(Q C') it leaves.
Then: how our decision time grows with the coefficients (8 x 6 .. 24 x 20) and candidates.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_decision.py [--quick] [--no-botorch]

Writes benchmarks/results/decision.json. BoTorch is the optional ``bench`` extra (CPU torch).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

from adaptive_cal.gaussian.belief import covariance_after, integrated_variance  # noqa: E402
from adaptive_cal.cell.schema import load_yaml, parse_cell  # noqa: E402
from adaptive_cal.cell.build import survey_plan  # noqa: E402
from adaptive_cal.planning.shell import Survey  # noqa: E402
from adaptive_cal.planning.scoring import variance_drop, variance_drop_numpy  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class BenchSurvey(Survey):
    """The survey shell with the names this benchmark reads (cell, candidates, gram, ...)."""

    candidates = property(lambda self: self.plan.candidates)
    gram = property(lambda self: self.plan.gram)
    model = property(lambda self: self.plan.model)
    noise_var = property(lambda self: self.state.noise_var)
    heights = property(lambda self: self.state.heights_mm)
    xs = property(lambda self: [p[0] for p in self.touched_xy_mm])  # never gated here: all fused
    ys = property(lambda self: [p[1] for p in self.touched_xy_mm])


def make_mapper(kx: int, ky: int, candidates: int, readings: int = 20, seed: int = 0) -> BenchSurvey:
    """The simulated reference cell with kx x ky knots, ``readings`` touches fused (fixed
    hyper-parameters, so every implementation sees the same Gaussian posterior)."""
    data = load_yaml(ROOT / "configs" / "sim-cell.yaml")
    data["workplane"]["keep_outs"] = []
    data["model"].update(knots_x=kx, knots_y=ky, learn_hyper=False)
    data["plan"]["candidates"] = candidates
    cell = parse_cell(data)
    mapper = BenchSurvey(survey_plan(cell))
    mapper.cell = cell
    rng = np.random.default_rng(seed)
    for _ in range(readings):
        t = mapper.ask()[0]
        mapper.tell(t.x_mm, t.y_mm, t.z_mm, t.expected_reading_mm + 0.005 * rng.standard_normal())
    return mapper


def timeit(fn, repeat: int = 7, warm: bool = True) -> tuple[float, object]:
    if warm:
        fn()  # warm-up (compile)
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def j_after(mapper: BenchSurvey, xy) -> float:
    h = mapper.model.surface.basis(np.array([xy[0]]), np.array([xy[1]]))
    return float(integrated_variance(covariance_after(mapper.belief.cov, h, mapper.noise_var),
                                     mapper.gram))


def ours(mapper: BenchSurvey, repeat: int) -> dict:
    rows, cov, gram, r = mapper.candidates.rows, mapper.belief.cov, mapper.gram, mapper.noise_var

    def score():
        d, _ = variance_drop(rows, cov, gram, r)
        return int(np.argmax(d))

    def score_np():
        return int(np.argmax(variance_drop_numpy(rows, cov, gram, r)))

    t_jax, i = timeit(score, repeat)
    t_np, i_np = timeit(score_np, repeat)
    t_ask, target = timeit(lambda: mapper.ask()[0], repeat)
    xy = mapper.candidates.xy_mm
    return {"ours_score_s": t_jax, "ours_ask_s": t_ask, "numpy_score_s": t_np,
            "ours_choice": xy[i].tolist(), "ours_J": j_after(mapper, xy[i]),
            "ours_ask_choice": [target.x_mm, target.y_mm],
            "ours_ask_J": j_after(mapper, (target.x_mm, target.y_mm)),
            "numpy_J": j_after(mapper, xy[i_np])}


def botorch_choice(mapper: BenchSurvey, repeat: int, mc_points: int = 256, restarts: int = 5,
                   seed: int = 0) -> dict:
    import gpytorch
    import torch
    from botorch.acquisition.active_learning import qNegIntegratedPosteriorVariance
    from botorch.models import SingleTaskGP
    from botorch.optim import optimize_acqf, optimize_acqf_discrete

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    surface = mapper.model.surface
    prior_cov = torch.as_tensor(mapper.model.belief(mapper.hyper).cov)

    class SplineKernel(gpytorch.kernels.Kernel):
        """k(p, p') = h(p)^T C0 h(p'): the spline prior as a GP kernel."""

        def forward(self, x1, x2, diag=False, **params):
            h1 = surface.basis(x1[..., 0].contiguous(), x1[..., 1].contiguous(), torch)
            h2 = surface.basis(x2[..., 0].contiguous(), x2[..., 1].contiguous(), torch)
            if diag:
                return ((h1 @ prior_cov) * h2).sum(-1)
            return h1 @ prior_cov @ h2.transpose(-1, -2)

    x = torch.tensor(np.column_stack([mapper.xs, mapper.ys]), dtype=torch.float64)
    y = torch.tensor(mapper.heights, dtype=torch.float64)[:, None]
    model = SingleTaskGP(x, y, train_Yvar=torch.full_like(y, mapper.noise_var),
                         covar_module=SplineKernel(), mean_module=gpytorch.means.ZeroMean(),
                         outcome_transform=None)
    model.eval()
    wp, m = mapper.cell.workplane, mapper.cell.workplane.edge_margin_mm
    lo = torch.tensor([wp.x_mm[0] + m, wp.y_mm[0] + m], dtype=torch.float64)
    hi = torch.tensor([wp.x_mm[1] - m, wp.y_mm[1] - m], dtype=torch.float64)
    full_lo = torch.tensor([wp.x_mm[0], wp.y_mm[0]], dtype=torch.float64)
    full_hi = torch.tensor([wp.x_mm[1], wp.y_mm[1]], dtype=torch.float64)
    sobol = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed).draw(mc_points).double()
    mc = full_lo + (full_hi - full_lo) * sobol
    acq = qNegIntegratedPosteriorVariance(model, mc_points=mc)
    bounds = torch.stack([lo, hi])
    n = len(mapper.candidates.xy_mm)

    def continuous():
        cand, _ = optimize_acqf(acq, bounds=bounds, q=1, num_restarts=restarts, raw_samples=n,
                                options={"batch_limit": restarts, "init_batch_limit": 512})
        return cand[0].detach().numpy()

    choices = torch.as_tensor(mapper.candidates.xy_mm)

    def discrete():
        cand, _ = optimize_acqf_discrete(acq, q=1, choices=choices, max_batch_size=512)
        return cand[0].detach().numpy()

    t_c, xy_c = timeit(continuous, repeat, warm=False)
    t_d, xy_d = timeit(discrete, repeat, warm=False)
    return {"botorch_s": t_c, "botorch_choice": xy_c.tolist(), "botorch_J": j_after(mapper, xy_c),
            "botorch_discrete_s": t_d, "botorch_discrete_choice": xy_d.tolist(),
            "botorch_discrete_J": j_after(mapper, xy_d)}


def scaling(quick: bool) -> list[dict]:
    shapes = [(8, 6), (12, 10), (16, 14), (24, 20)] if not quick else [(8, 6), (12, 10)]
    counts = [1000, 10000, 40000] if not quick else [1000, 10000]
    out = []
    for kx, ky in shapes:
        for n in counts:
            mapper = make_mapper(kx, ky, n, readings=5)
            rows, cov, gram, r = (mapper.candidates.rows, mapper.belief.cov, mapper.gram,
                                  mapper.noise_var)
            t_j, _ = timeit(lambda: np.argmax(variance_drop(rows, cov, gram, r)[0]), 5)
            t_n, _ = timeit(lambda: np.argmax(variance_drop_numpy(rows, cov, gram, r)), 3)
            out.append({"knots": [kx, ky], "coefficients": kx * ky, "candidates": len(rows),
                        "ours_score_s": t_j, "numpy_score_s": t_n})
            print(f"  {kx:2d} x {ky:2d} = {kx * ky:3d} coefficients, {len(rows):6d} candidates: "
                  f"ours {t_j * 1e3:8.2f} ms, numpy {t_n * 1e3:8.2f} ms", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-botorch", action="store_true")
    ap.add_argument("--seed", type=int, default=0, help="readings, BoTorch restarts and Sobol points")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "decision.json"))
    args = ap.parse_args()
    repeat = 3 if args.quick else 7
    mapper = make_mapper(10, 9, 10000, seed=args.seed)
    res = {"problem": {"coefficients": mapper.model.surface.size,
                       "candidates": len(mapper.candidates.xy_mm), "readings": len(mapper.heights),
                       "noise_std_mm": float(np.sqrt(mapper.noise_var))},
           "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                      "OPENBLAS_NUM_THREADS=1, torch 1 thread"}
    res.update(ours(mapper, repeat))
    if not args.no_botorch:
        try:
            res.update(botorch_choice(mapper, 1, seed=args.seed))
        except ImportError as e:
            print(f"BoTorch not installed ({e}): pip install 'adaptive-cal[bench]'")
    j0 = float(integrated_variance(mapper.belief.cov, mapper.gram))
    print(f"problem: {res['problem']}, J now {j0:.6g} mm^4")
    print("| method | decision time (ms) | J after the touch (mm^4) |\n|---|---|---|")
    rows = [("ours: variance_drop + argmax (jit)", "ours_score_s", "ours_J"),
            ("ours: ask (planning.ask, incl. refinement)", "ours_ask_s", "ours_ask_J"),
            ("plain numpy closed form", "numpy_score_s", "numpy_J"),
            ("BoTorch qNIPV, optimize_acqf (5 restarts)", "botorch_s", "botorch_J"),
            ("BoTorch qNIPV, optimize_acqf_discrete", "botorch_discrete_s", "botorch_discrete_J")]
    for name, t, j in rows:
        if t in res:
            print(f"| {name} | {res[t] * 1e3:.2f} | {res[j]:.6g} |")
    if "botorch_s" in res:
        res["speedup_vs_botorch"] = res["botorch_s"] / res["ours_score_s"]
        res["speedup_ask_vs_botorch"] = res["botorch_s"] / res["ours_ask_s"]
        print(f"speed-up vs BoTorch: {res['speedup_vs_botorch']:.0f}x (scoring), "
              f"{res['speedup_ask_vs_botorch']:.0f}x (whole ask)")
    print("scaling:")
    res["scaling"] = scaling(args.quick)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
