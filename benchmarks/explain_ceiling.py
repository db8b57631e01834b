"""The ideal observer's ceiling on the independent benchmark's single-effect cases (issue 15).

"At least 97 % right at >= 6 sigma" is a claim about explain; whether any method can reach it on
benchmarks/explain_indep depends on how often two of the generator's own effects look alike
there. This script answers that with the Bayes-optimal classifier *of the generator itself*: it
knows everything explain does not -- the five effects' exact shapes and how the generator draws
their parameters (form kind and weights, sag exponent, bump place and radius, signs), the noise sd
and even k (the pattern's size after the tilt, fixed by the case) -- and it picks the effect of
largest marginal likelihood, every effect at prior 1/5 as the generator makes them. The tilt
(a x + b y + c, flat prior) is projected out, as the generator's k sigma does. For a pattern of
direction u (unit, after the projection) and size k sigma, log p(y | u) = k <M y, u> / sigma
+ const, the constant the same for every effect; each effect's likelihood is averaged over its
parameters (exactly over the finite ones: bow axis, sign, sag exponent; by Monte Carlo over
``--draws`` draws from the generator's own functions for the mixed form and the bump).

No method that does not know the generator's parameter distributions does better on average,
so its rate bounds every explain-like tool's on these cases (up to the Monte Carlo error, printed).
Imports numpy and benchmarks/explain_indep only (no adaptive_cal).

    python benchmarks/explain_ceiling.py --n 30 --seed 0 \
        [--from benchmarks/results/explain-indep-2026-11-22.json]   # explain's verdicts beside it
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from explain_indep import cases as C  # noqa: E402
from explain_indep import generate as G  # noqa: E402

EFFECTS = ("form", "arm_sag", "reversal", "thermal_drift", "local_defect")


def _logmeanexp(v: np.ndarray) -> float:
    m = float(np.max(v))
    return m + float(np.log(np.mean(np.exp(v - m))))


def _directions(patterns: list[np.ndarray], M: np.ndarray) -> np.ndarray:
    """Unit directions (rows) of the patterns after the tilt's projection; both signs."""
    P = np.array([M @ g for g in patterns])
    P = P / np.linalg.norm(P, axis=1, keepdims=True)
    return np.vstack([P, -P])


def effect_directions(case, rng: np.random.Generator, draws: int) -> dict[str, np.ndarray]:
    """Each effect's pattern directions on this case's touches, drawn as the generator draws."""
    r = case.rounds[0]
    x, y, t = r["x"], r["y"], r["t"]
    A = np.stack([x, y, np.ones_like(x)], 1)
    M = np.eye(x.size) - A @ np.linalg.pinv(A)
    form = {}
    for kind, w_list in (("bow", [np.array([1.0, 0, 0]), np.array([0, 1.0, 0])]),
                         ("twist", [np.array([0, 0, 1.0])]),
                         ("mixed", list(rng.normal(size=(draws, 3))))):
        form[kind] = _directions([G.form_shape(w, x, y, case.plate) for w in w_list], M)
    sag = _directions([(np.hypot(x - G.BASE[0], y - G.BASE[1]) / 1000.0) ** p
                       for p in (1.5, 2.0, 2.5)], M)
    rev = _directions([0.5 * G.arrival(x)], M)
    drift = _directions([t.astype(float)], M) if np.linalg.norm(M @ t) > 1e-9 * np.linalg.norm(t) else None
    bumps = []
    for _ in range(draws):
        cx, cy, rad = G.defect_place(x, y, rng)
        bumps.append(np.clip(1.0 - (np.hypot(x - cx, y - cy) / rad) ** 2, 0.0, None))
    out = {"form": form, "arm_sag": sag, "reversal": rev, "local_defect": _directions(bumps, M)}
    if drift is not None:
        out["thermal_drift"] = drift
    return out


def log_marginals(case, k: float, rng, draws: int) -> dict[str, float]:
    r = case.rounds[0]
    x, yv = r["x"], r["reading"]
    A = np.stack([x, r["y"], np.ones_like(x)], 1)
    My = yv - A @ np.linalg.lstsq(A, yv, rcond=None)[0]
    s = case.noise_mm
    dirs = effect_directions(case, rng, draws)
    out = {}
    for name, D in dirs.items():
        if name == "form":  # bow, twist, mixed: a third each, as cases.build draws them
            parts = [_logmeanexp(k * (U @ My) / s) for U in D.values()]
            out[name] = _logmeanexp(np.array(parts))
        else:
            out[name] = _logmeanexp(k * (D @ My) / s)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--draws", type=int, default=2000, help="Monte Carlo draws (mixed form, bump)")
    ap.add_argument("--sigmas", default="6,10")
    ap.add_argument("--from", dest="results", type=Path, default=None,
                    help="an indep benchmark results JSON (same n, seed): explain's verdicts beside")
    args = ap.parse_args(argv)
    sigmas = {float(v) for v in args.sigmas.split(",")}
    specs = [s for s in C.table(args.n) if s["family"] == "single" and s["sigma"] in sigmas]
    explain = {}
    if args.results:
        explain = {c["key"]: c["verdict"] for c in json.loads(args.results.read_text())["cases"]}
    rng = np.random.default_rng(12345)
    right, prob, top, confusion, by = 0, [], [], Counter(), Counter()
    ex_right = ex_n = 0
    for spec in specs:
        case = C.build(spec, args.seed)
        truth = case.truth["effects"][0]["effect"]
        lm = log_marginals(case, spec["sigma"], rng, args.draws)
        names = list(lm)
        v = np.array([lm[n] for n in names])
        post = np.exp(v - v.max()) / np.exp(v - v.max()).sum()
        best = names[int(np.argmax(v))]
        right += best == truth
        prob.append(float(post[names.index(truth)]))
        top.append(float(post.max()))
        by[(truth, spec["design"], best == truth)] += 1
        if best != truth:
            confusion[(truth, best)] += 1
        key = C.spec_key(spec)
        if key in explain:
            ex_n += 1
            ex_right += explain[key] == truth
    n = len(specs)
    p, q = np.array(prob), np.array(top)
    print(f"ideal observer (knows the generator), single effects at {sorted(sigmas)} sigma, "
          f"seed {args.seed}, n {args.n}: {right}/{n} = {100 * right / n:.1f} % right "
          f"(its expected rate, the mean of its largest posterior: {100 * q.mean():.1f} %; "
          f"mean posterior of the truth {100 * p.mean():.1f} %)")
    for (t, b), c in confusion.most_common():
        print(f"  {t} -> {b}: {c}")
    for eff in EFFECTS:
        for design in C.SINGLE_DESIGNS:
            ok, bad = by[(eff, design, True)], by[(eff, design, False)]
            if ok + bad and bad:
                print(f"  {eff:13s} {design:7s} {ok}/{ok + bad}")
    if ex_n:
        print(f"explain on the same cases: {ex_right}/{ex_n} = {100 * ex_right / ex_n:.1f} % right")


if __name__ == "__main__":
    main()
