"""Decision latency: which touch next, on the same problem, by three implementations.

* ours: ``planner.variance_drop`` (one jit-compiled (N x K)(K x 2K) product) + argmax, and the
  whole ``ask()`` (planning.ask) (stroke check and gradient refinement included);
* numpy: the same closed form in plain numpy (``planner.variance_drop_numpy``);
* BoTorch: ``qNegIntegratedPosteriorVariance`` (256 scrambled Sobol integration points)
  maximised by ``optimize_acqf`` (5 restarts) at its customary 256 raw samples and at raw
  samples = the candidate count, on a GPyTorch exact GP whose kernel is our spline prior
  k(p, p') = h(p)^T C0 h(p') with the same fixed noise -- the same posterior as our belief
  (checked) -- on BoTorch's customary unit-square inputs; and, on our candidate set,
  ``optimize_acqf_discrete``.

Each choice is scored by the exact integrated variance J = trace(Q C') it leaves.

Sequential: from the same 5 readings of the seeded simulated plate, each method chooses its
touches in turn (readings from the same truth and noise stream, the belief / GP updated after
each); J after every touch and the decision seconds; the time each method needs to reach the J
ours (scoring + argmax) reaches after ``--touches`` touches, and its ratio to ours.

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
import warnings  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

from adaptive_cal.gaussian import belief as bl  # noqa: E402
from adaptive_cal.gaussian.belief import covariance_after, integrated_variance  # noqa: E402
from adaptive_cal.cell.schema import load_yaml, parse_cell  # noqa: E402
from adaptive_cal.cell.build import survey_plan  # noqa: E402
from adaptive_cal.planning.shell import Survey  # noqa: E402
from adaptive_cal.planning.scoring import variance_drop, variance_drop_numpy  # noqa: E402
from adaptive_cal.planning.route import robot_time_s  # noqa: E402
from adaptive_cal.formats.recording import surface_height_mm  # noqa: E402
from adaptive_cal.simulation.cell import SimulatedCell  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RTOL = 1e-3  # "the same integrated variance": within 0.1 %
CUSTOMARY_RAW = 256  # BoTorch's customary raw samples (its tutorials use 256 or 512)


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


def botorch_gp(plan, prior_cov, xy, heights, noise_var: float, frame):
    """A GPyTorch exact GP whose kernel is our spline prior k(p, p') = h(p)^T C0 h(p'), with
    our fixed noise and zero mean: the same posterior as our belief. Its inputs are BoTorch's
    customary unit square, u = (p - lo) / span with ``frame`` = (lo, span) of the plate (mm).
    Nothing is fitted (the kernel has no free parameters), so "refitting" to a new reading is
    building it again."""
    import gpytorch
    import torch
    from botorch.models import SingleTaskGP

    surface, c0 = plan.model.surface, torch.as_tensor(np.asarray(prior_cov))
    lo, span = (torch.as_tensor(np.asarray(v, float)) for v in frame)

    class SplineKernel(gpytorch.kernels.Kernel):
        """k(p, p') = h(p)^T C0 h(p'): the spline prior as a GP kernel."""

        def forward(self, x1, x2, diag=False, **params):
            p1, p2 = lo + x1 * span, lo + x2 * span  # mm
            h1 = surface.basis(p1[..., 0].contiguous(), p1[..., 1].contiguous(), torch)
            h2 = surface.basis(p2[..., 0].contiguous(), p2[..., 1].contiguous(), torch)
            if diag:
                return ((h1 @ c0) * h2).sum(-1)
            return h1 @ c0 @ h2.transpose(-1, -2)

    x = torch.tensor((np.asarray(xy, float).reshape(-1, 2) - frame[0]) / frame[1],
                     dtype=torch.float64)
    y = torch.tensor(np.asarray(heights, float), dtype=torch.float64)[:, None]
    model = SingleTaskGP(x, y, train_Yvar=torch.full_like(y, noise_var),
                         covar_module=SplineKernel(), mean_module=gpytorch.means.ZeroMean(),
                         outcome_transform=None)
    model.eval()
    return model


def botorch_setup(workplane, mc_points: int = 256, seed: int = 0):
    """(frame = (lo, span) of the plate in mm, bounds inside the edge margin and mc_points
    scrambled Sobol integration points over the plate, both in the unit square, as torch
    tensors) for qNegIntegratedPosteriorVariance."""
    import torch

    wp, m = workplane, workplane.edge_margin_mm
    lo = np.array([wp.x_mm[0], wp.y_mm[0]])
    span = np.array([wp.x_mm[1], wp.y_mm[1]]) - lo
    bounds = torch.tensor([[m / span[0], m / span[1]], [1 - m / span[0], 1 - m / span[1]]],
                          dtype=torch.float64)
    sobol = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed).draw(mc_points).double()
    return (lo, span), bounds, sobol


def botorch_decide(model, frame, bounds, mc, raw_samples: int, restarts: int = 5,
                   seed: int = 0):
    """One qNIPV decision, the point (mm): optimize_acqf (``restarts`` L-BFGS-B restarts from
    the best of ``raw_samples`` raw points; BoTorch retries from new ones where L-BFGS-B
    fails); seeded, so a repeat makes the same choice."""
    import torch
    from botorch.acquisition.active_learning import qNegIntegratedPosteriorVariance
    from botorch.optim import optimize_acqf

    torch.manual_seed(seed)
    acq = qNegIntegratedPosteriorVariance(model, mc_points=mc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cand, _ = optimize_acqf(acq, bounds=bounds, q=1, num_restarts=restarts,
                                raw_samples=raw_samples,
                                options={"batch_limit": restarts, "init_batch_limit": 512})
    failed = sum("Optimization failed in" in str(w.message) for w in caught)
    return frame[0] + cand[0].detach().numpy() * frame[1], failed


def botorch_choice(mapper: BenchSurvey, repeat: int, mc_points: int = 256, restarts: int = 5,
                   seed: int = 0, customary_only: bool = False) -> dict:
    """One BoTorch decision on the mapper's posterior: optimize_acqf at the customary settings
    (256 raw samples) and, unless ``customary_only``, at raw samples = the candidate count and
    optimize_acqf_discrete on our candidates."""
    import torch
    from botorch.acquisition.active_learning import qNegIntegratedPosteriorVariance
    from botorch.optim import optimize_acqf_discrete

    torch.set_num_threads(1)
    prior_cov = mapper.model.belief(mapper.hyper).cov
    frame, bounds, mc = botorch_setup(mapper.cell.workplane, mc_points, seed)
    model = botorch_gp(mapper.plan, prior_cov, np.column_stack([mapper.xs, mapper.ys]),
                       mapper.heights, mapper.noise_var, frame)
    n = len(mapper.candidates.xy_mm)
    t_f, (xy_f, fail_f) = timeit(lambda: botorch_decide(model, frame, bounds, mc,
                                                        CUSTOMARY_RAW, restarts, seed),
                                 max(repeat, 3))
    out = {"botorch_customary_s": t_f, "botorch_customary_choice": xy_f.tolist(),
           "botorch_customary_J": j_after(mapper, xy_f),
           "botorch_customary_retried": fail_f,
           "botorch_customary_settings": {"raw_samples": CUSTOMARY_RAW, "num_restarts": restarts,
                                          "mc_points": mc_points, "mc": "scrambled Sobol"}}
    if customary_only:
        return out
    t_c, (xy_c, _) = timeit(lambda: botorch_decide(model, frame, bounds, mc, n, restarts, seed),
                            repeat, warm=False)
    acq = qNegIntegratedPosteriorVariance(model, mc_points=mc)
    choices = torch.as_tensor((mapper.candidates.xy_mm - frame[0]) / frame[1])

    def discrete():
        cand, _ = optimize_acqf_discrete(acq, q=1, choices=choices, max_batch_size=512)
        return frame[0] + cand[0].detach().numpy() * frame[1]

    t_d, xy_d = timeit(discrete, repeat, warm=False)
    out.update({"botorch_s": t_c, "botorch_choice": xy_c.tolist(),
                "botorch_J": j_after(mapper, xy_c), "botorch_raw_samples": n,
                "botorch_discrete_s": t_d, "botorch_discrete_choice": xy_d.tolist(),
                "botorch_discrete_J": j_after(mapper, xy_d)})
    return out


def sim_cell(kx: int = 10, ky: int = 9, candidates: int = 10000):
    """The reference simulated cell (its seeded true plate), kx x ky knots, fixed
    hyper-parameters, no keep-outs."""
    data = load_yaml(ROOT / "configs" / "sim-cell.yaml")
    data["workplane"]["keep_outs"] = []
    data["model"].update(knots_x=kx, knots_y=ky, learn_hyper=False)
    data["plan"]["candidates"] = candidates
    return parse_cell(data)


class Track:
    """One method's sequence of touches on its own copy of the seeded true plate (noise drawn
    per touch number, so every method sees the same truth and noise stream): a plain Gaussian
    belief (``fuse``), J = trace(Q C) after each touch, decision seconds per touch."""

    def __init__(self, plan, cell, start):
        self.plan, self.belief, self.noise_var = plan, start.belief, start.noise_var
        self.xy = [tuple(map(float, p)) for p in start.touched_xy_mm]
        self.heights = [float(h) for h in start.heights_mm]
        self.sim = SimulatedCell.from_cell(cell, start_touch=start.touches)
        self.start_xy = self.sim.position()[:2]
        self.J, self.decision_s, self.update_s = [], [], []
        self.retried = 0  # BoTorch decisions whose L-BFGS-B failed and were retried

    def read(self, x: float, y: float, z: float) -> float:
        self.sim.move_to(x, y, z)
        return self.sim.read().reading_mm

    def touch(self, x: float, y: float) -> None:
        """Touch (x, y) at the mid-stroke approach height and fuse the reading's height."""
        h = self.plan.model.surface.basis(np.array([x]), np.array([y]))[0]
        z = self.plan.approach_height(float(h @ self.belief.mean))
        height = surface_height_mm(self.read(x, y, z), z, self.plan.zero_mm)
        self.belief, _ = bl.fuse(self.belief, h, height, self.noise_var)
        self.xy.append((float(x), float(y)))
        self.heights.append(height)
        self.J.append(float(integrated_variance(self.belief.cov, self.plan.gram)))

    def robot_time_s(self, k: int) -> float:
        """Robot time (s) of the first k new touches: travel from the start plus touch time."""
        pts = self.xy[len(self.xy) - len(self.J):][:k]
        return robot_time_s(self.start_xy, pts, self.plan.speed_mm_per_s,
                            self.plan.touch_time_s)[0]


def median_time(fn, repeat: int, warm: bool = True):
    """(median seconds of ``repeat`` calls after one untimed warm-up call, the last result)."""
    return timeit(fn, repeat, warm=warm)


def run_scored(plan, cell, start, n: int, repeat: int) -> Track:
    """ours, bare: variance_drop over the candidates + argmax, then fuse (the J-greedy rule)."""
    path = Track(plan, cell, start)
    rows = plan.candidates.rows
    for _ in range(n):
        t, i = median_time(lambda: int(np.argmax(
            variance_drop(rows, path.belief.cov, plan.gram, path.noise_var)[0])), repeat)
        path.decision_s.append(t)
        path.touch(*plan.candidates.xy_mm[i])
    return path


def run_asked(plan, cell, start, n: int, repeat: int) -> Track:
    """ours, the product: planning.ask from where the probe is, every target of the batch it
    returns taken in order (as run.loop does); the ask's time is charged to the batch's first
    touch; J from the survey's own belief."""
    path = Track(plan, cell, start)
    survey = Survey(plan, state=start)
    while len(path.J) < n:
        t, targets = median_time(lambda: survey.ask(from_xy=path.sim.position()[:2]), repeat)
        if not targets:
            break
        for k, tg in enumerate(targets[: n - len(path.J)]):
            survey.tell(tg.x_mm, tg.y_mm, tg.z_mm, path.read(tg.x_mm, tg.y_mm, tg.z_mm))
            path.xy.append((tg.x_mm, tg.y_mm))
            path.J.append(float(integrated_variance(survey.belief.cov, plan.gram)))
            path.decision_s.append(t if k == 0 else 0.0)
            if survey.retake_pending:
                break
    return path


def run_botorch(plan, cell, start, n: int, repeat: int, raw_samples: int, seed: int) -> Track:
    """BoTorch: qNIPV by optimize_acqf on the GP with our prior as kernel, the GP rebuilt
    with every new reading (update seconds kept apart from the decision's)."""
    import torch

    torch.set_num_threads(1)
    path = Track(plan, cell, start)
    prior_cov = plan.model.belief(start.hyper).cov
    frame, bounds, mc = botorch_setup(cell.workplane, 256, seed)
    for k in range(n):
        t0 = time.perf_counter()
        model = botorch_gp(plan, prior_cov, path.xy, path.heights, path.noise_var, frame)
        path.update_s.append(time.perf_counter() - t0)
        t, (xy, failed) = median_time(lambda: botorch_decide(model, frame, bounds, mc,
                                                             raw_samples, 5, seed),
                                      repeat, warm=k == 0 and raw_samples <= CUSTOMARY_RAW)
        path.decision_s.append(t)
        path.retried += failed > 0
        path.touch(*map(float, xy))
    return path


def time_to_reach(path: Track, j_target: float, rtol: float):
    """(touches, cumulative decision s) at the first touch with J <= j_target (1 + rtol), or
    (None, None) when it is not reached within the path."""
    cum = np.cumsum(path.decision_s)
    for k, j in enumerate(path.J):
        if j <= j_target * (1.0 + rtol):
            return k + 1, float(cum[k])
    return None, None


def sequential(args, botorch: bool) -> dict:
    """From the same 5 readings each method chooses ``args.touches`` touches in turn; the time
    each needs to reach the J ours (scoring + argmax) reaches after the last touch."""
    cell = sim_cell()
    plan = survey_plan(cell)
    survey, sim = Survey(plan), SimulatedCell.from_cell(cell)
    for _ in range(5):
        tg = survey.ask(1)[0]
        sim.move_to(tg.x_mm, tg.y_mm, tg.z_mm)
        survey.tell(tg.x_mm, tg.y_mm, tg.z_mm, sim.read().reading_mm)
    start, n, rep = survey.state, args.touches, 1 if args.quick else 3
    if len(start.heights_mm) != len(start.touched_xy_mm) or np.any(start.fused_weights != 1):
        raise SystemExit("sequential: a start reading was gated or down-weighted; the methods "
                         "would not start from the same Gaussian posterior (try another --seed)")
    n_max = n + n // 2  # every method may go on past n touches to reach the target
    paths = {"ours_score": run_scored(plan, cell, start, n_max, rep),
             "ours_ask": run_asked(plan, cell, start, n_max, rep),
             "ours_ask_j_only": run_asked(replace(plan, time_aware=False), cell, start, n_max,
                                          rep)}
    out = {"touches": n, "max_touches": n_max, "start_readings": 5,
           "J_start": float(integrated_variance(start.belief.cov, plan.gram)), "rtol": RTOL,
           "timing_repeats": rep, "methods": {}}
    if botorch:
        paths["botorch_customary"] = run_botorch(plan, cell, start, n_max, rep, CUSTOMARY_RAW,
                                                 args.seed)
        out["gp_posterior_max_rel_diff"] = gp_agreement(plan, cell, start, args.seed)
        if args.current_touches > 0:
            paths["botorch_current"] = run_botorch(plan, cell, start, args.current_touches, 1,
                                                   len(plan.candidates.xy_mm), args.seed)
    targets = {name: paths[name].J[n - 1] for name in ("ours_score", "botorch_customary")
               if name in paths}
    out["J_target"] = targets["ours_score"]
    out["J_targets"] = targets
    for name, p in paths.items():
        m = out["methods"][name] = {
            "J": p.J, "decision_s": p.decision_s, "update_s": p.update_s,
            "cumulative_decision_s": np.cumsum(p.decision_s).tolist(),
            "J_after_touches": p.J[n - 1] if len(p.J) >= n else None}
        for tname, j in targets.items():
            k, t = time_to_reach(p, j, RTOL)
            base = time_to_reach(paths["ours_score"], j, RTOL)[1]
            m[f"to_{tname}_J"] = {"touches": k, "decision_s": t,
                                  "ratio_to_ours_score": None if t is None else t / base}
        k, t = m["to_ours_score_J"]["touches"], m["to_ours_score_J"]["decision_s"]
        m.update({
            "touches_to_target": k, "time_to_target_s": t,
            "ratio_to_ours_score": m["to_ours_score_J"]["ratio_to_ours_score"],
            "robot_time_s": p.robot_time_s(min(n, len(p.J))),
            "median_decision_s": float(np.median([d for d in p.decision_s if d > 0])),
            "decisions_retried": p.retried})
    if "botorch_current" in paths:  # too slow to run to the target: estimated, and said so
        cur, ours_k = out["methods"]["botorch_current"], out["methods"]["ours_score"]
        t = cur["median_decision_s"] * ours_k["touches_to_target"]
        out["botorch_current_estimate"] = {
            "how": "median decision at raw samples = candidates x the touches ours (scoring + "
                   "argmax) needs: its choices are those of a dense discrete search",
            "time_to_target_s": t, "ratio_to_ours_score": t / ours_k["time_to_target_s"]}
    return out


def gp_agreement(plan, cell, start, seed: int) -> float:
    """Largest relative difference between the BoTorch GP's posterior variance and our
    belief's at 200 candidates, from the start readings: the two must be the same posterior."""
    import torch

    frame = botorch_setup(cell.workplane, 256, seed)[0]
    model = botorch_gp(plan, plan.model.belief(start.hyper).cov, start.touched_xy_mm,
                       start.heights_mm, start.noise_var, frame)
    idx = np.random.default_rng(seed).choice(len(plan.candidates.xy_mm), 200, replace=False)
    u = torch.as_tensor((plan.candidates.xy_mm[idx] - frame[0]) / frame[1])
    with torch.no_grad():
        gp_var = model.posterior(u).variance.squeeze(-1).numpy()
    _, ours_var = bl.predict(start.belief, plan.candidates.rows[idx])
    return float(np.max(np.abs(gp_var - ours_var) / ours_var))


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


SEQ_NAMES = {"ours_score": "ours: variance_drop + argmax (jit)",
             "ours_ask": "ours: ask (the product: time-aware, batches, refinement)",
             "ours_ask_j_only": "ours: ask with time_aware off (J only, refinement)",
             "botorch_customary": "BoTorch qNIPV, customary (256 raw, 5 restarts, 256 MC)",
             "botorch_current": "BoTorch qNIPV, current (raw = candidates, 5 restarts, 256 MC)"}


def print_sequential(seq: dict) -> None:
    n = seq["touches"]
    print(f"sequential: from the same {seq['start_readings']} readings (J {seq['J_start']:.6g} "
          f"mm^4) each method touches in turn; target: J {seq['J_target']:.6g} mm^4, ours "
          f"(scoring + argmax) after {n} touches, reached = within {seq['rtol']:.1%}, each "
          f"method going on to {seq['max_touches']} touches; decision times are medians of "
          f"{seq['timing_repeats']}")
    print(f"| method | median decision (ms) | J after {n} touches (mm^4) | touches to target | "
          f"decision time to target (s) | x ours | robot time of {n} touches (s) |")
    print("|---|---|---|---|---|---|---|")
    for name, m in seq["methods"].items():
        k, t, r = m["touches_to_target"], m["time_to_target_s"], m["ratio_to_ours_score"]
        j = m["J_after_touches"]
        reached = k if k else f"not within {len(m['J'])}"
        print(f"| {SEQ_NAMES[name]} | {m['median_decision_s'] * 1e3:.1f} | "
              f"{'-' if j is None else f'{j:.6g}'} | "
              f"{reached} | "
              f"{'-' if t is None else f'{t:.3f}'} | {'-' if r is None else f'{r:.2g}' if r < 10 else f'{r:.0f}'} | "
              f"{m['robot_time_s']:.0f} |")
    if "botorch_current_estimate" in seq:
        e = seq["botorch_current_estimate"]
        print(f"BoTorch at raw samples = candidates, estimated ({e['how']}): "
              f"{e['time_to_target_s']:.0f} s to the target, {e['ratio_to_ours_score']:.0f} x ours")
    if "botorch_customary" in seq["J_targets"]:
        j = seq["J_targets"]["botorch_customary"]
        print(f"to BoTorch's (customary) J after {n} touches, {j:.6g} mm^4: " + ", ".join(
            f"{name} {m['to_botorch_customary_J']['touches']} touches, "
            f"{m['to_botorch_customary_J']['decision_s'] or float('nan'):.3f} s"
            for name, m in seq["methods"].items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats and shapes, no "
                    "BoTorch run at raw samples = candidates (about 3 minutes)")
    ap.add_argument("--no-botorch", action="store_true")
    ap.add_argument("--seed", type=int, default=0, help="readings, BoTorch restarts and Sobol points")
    ap.add_argument("--touches", type=int, default=None,
                    help="touches of the sequential comparison (default 16, --quick 12)")
    ap.add_argument("--current-touches", type=int, default=None,
                    help="touches BoTorch makes at raw samples = candidates in the sequential "
                         "comparison (about 2 min each; default 1, --quick 0)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "decision.json"))
    args = ap.parse_args()
    if args.touches is None:
        args.touches = 12 if args.quick else 16
    if args.current_touches is None:
        args.current_touches = 0 if args.quick else 1
    if args.touches < 1 or args.current_touches < 0:
        ap.error(f"--touches must be >= 1 (got {args.touches}) and --current-touches >= 0 "
                 f"(got {args.current_touches})")
    botorch = not args.no_botorch
    if botorch:
        try:
            import botorch as _  # noqa: F401
        except ImportError as e:
            print(f"BoTorch not installed ({e}): pip install 'adaptive-cal[bench]'")
            botorch = False
    repeat = 3 if args.quick else 7
    mapper = make_mapper(10, 9, 10000, seed=args.seed)
    res = {"problem": {"coefficients": mapper.model.surface.size,
                       "candidates": len(mapper.candidates.xy_mm), "readings": len(mapper.heights),
                       "noise_std_mm": float(np.sqrt(mapper.noise_var))},
           "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
                      "OPENBLAS_NUM_THREADS=1, torch 1 thread"}
    res.update(ours(mapper, repeat))
    if botorch:
        res.update(botorch_choice(mapper, 1, seed=args.seed, customary_only=args.quick))
    j0 = float(integrated_variance(mapper.belief.cov, mapper.gram))
    print(f"problem: {res['problem']}, J now {j0:.6g} mm^4")
    print("| method | decision time (ms) | J after the touch (mm^4) |\n|---|---|---|")
    rows = [("ours: variance_drop + argmax (jit)", "ours_score_s", "ours_J"),
            ("ours: ask (planning.ask, incl. refinement)", "ours_ask_s", "ours_ask_J"),
            ("plain numpy closed form", "numpy_score_s", "numpy_J"),
            ("BoTorch qNIPV, optimize_acqf, customary (256 raw samples, 5 restarts)",
             "botorch_customary_s", "botorch_customary_J"),
            ("BoTorch qNIPV, optimize_acqf, raw samples = candidates (5 restarts)",
             "botorch_s", "botorch_J"),
            ("BoTorch qNIPV, optimize_acqf_discrete", "botorch_discrete_s", "botorch_discrete_J")]
    for name, t, j in rows:
        if t in res:
            print(f"| {name} | {res[t] * 1e3:.2f} | {res[j]:.6g} |")
    if "botorch_customary_s" in res:
        res["speedup_vs_botorch_customary"] = res["botorch_customary_s"] / res["ours_score_s"]
        res["speedup_ask_vs_botorch_customary"] = res["botorch_customary_s"] / res["ours_ask_s"]
        print(f"one decision vs BoTorch, customary: {res['speedup_vs_botorch_customary']:.0f}x "
              f"(scoring), {res['speedup_ask_vs_botorch_customary']:.0f}x (whole ask)")
    if "botorch_s" in res:
        res["speedup_vs_botorch"] = res["botorch_s"] / res["ours_score_s"]
        res["speedup_ask_vs_botorch"] = res["botorch_s"] / res["ours_ask_s"]
        print(f"one decision vs BoTorch, raw samples = candidates: "
              f"{res['speedup_vs_botorch']:.0f}x (scoring), "
              f"{res['speedup_ask_vs_botorch']:.0f}x (whole ask)")
    seq = sequential(args, botorch)
    res["sequential"] = seq
    print_sequential(seq)
    if "botorch_customary" in seq["methods"]:
        res["fair_ratio_vs_botorch"] = seq["methods"]["botorch_customary"]["ratio_to_ours_score"]
    print("scaling:")
    res["scaling"] = scaling(args.quick)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
