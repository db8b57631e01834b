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
        [--from benchmarks/results/explain-indep-2026-11-23.json]   # explain's verdicts beside it
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


def effect_directions(case, M: np.ndarray, rng: np.random.Generator,
                      draws: int) -> dict[str, np.ndarray]:
    """Each effect's pattern directions on this case's touches (``M``: the tilt's residual
    maker), made by the generator's own ``pattern`` and drawn as the generator draws."""
    r = case.rounds[0]
    one = [r]
    # ``pattern`` pins a draw through ``shared`` but evaluates setdefault's default all the same:
    # the pinned patterns get a generator of their own, so ``rng`` draws only the mixed forms
    # and the bumps
    pinned = np.random.default_rng(0)

    def pat(effect, gen=pinned, **shared):
        return G.pattern(effect, gen, one, case.plate, shared)[0][0]

    form = {}
    for kind, w_list in (("bow", [np.array([1.0, 0, 0]), np.array([0, 1.0, 0])]),
                         ("twist", [np.array([0, 0, 1.0])]),
                         ("mixed", list(rng.normal(size=(draws, 3))))):
        form[kind] = _directions([G.form_shape(w, r["x"], r["y"], case.plate) for w in w_list], M)
    out = {"form": form,
           "arm_sag": _directions([pat("arm_sag", p=p) for p in (1.5, 2.0, 2.5)], M),
           "reversal": _directions([pat("reversal")], M),
           "local_defect": _directions([pat("local_defect", rng) for _ in range(draws)], M)}
    t = pat("thermal_drift")
    if np.linalg.norm(M @ t) > 1e-9 * np.linalg.norm(t):  # else a plane (a raster): no drift
        out["thermal_drift"] = _directions([t], M)
    return out


def log_marginals(case, k: float, rng, draws: int) -> dict[str, float]:
    r = case.rounds[0]
    A = np.stack([r["x"], r["y"], np.ones_like(r["x"])], 1)
    M = np.eye(A.shape[0]) - A @ np.linalg.pinv(A)
    My = M @ r["reading"]
    s = case.noise_mm
    out = {}
    for name, D in effect_directions(case, M, rng, draws).items():
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
