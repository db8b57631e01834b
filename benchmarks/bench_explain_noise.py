"""explain on null recordings whose noise the independent benchmark does not draw (issue 15).

A real probe's noise is not always Gaussian, independent and as stated. The plates, designs and
tilts come from the independent generator (benchmarks/explain_indep, numpy only, no adaptive_cal
code); only the noise of each null recording is replaced, here, by one of:

- ``gauss``: the control, Gaussian noise of the stated sd as the benchmark draws it;
- ``ar1``: a disturbance lasting from touch to touch (vibration, a wandering temperature, a gauge
  that settles): AR(1), lag-1 correlation 0.5 per touch, marginal sd the stated one;
- ``laplace``: double-exponential noise of the stated sd (kurtosis 6);
- ``quant1``: Gaussian noise read on a gauge with 1 um steps;
- ``quant_coarse``: steps of 1.5 sd (a 10 um display on a 7 um probe), the sd of the rounded noise
  stated;
- ``hetero``: the sd grows with reach from the robot base (its mean stated);
- ``misstated``: Gaussian noise 1.5 x the stated sd;
- ``few``: 16 touches drawn from the design.

Each case is written as a cell file and a v1 recording and read back, as a real one reaches
explain. A library effect named is a false positive (``unexplained`` is counted beside it).
``--effects 6,10``: also single library effects (form bow, sag, drift, defect, reversal; S-path
and random designs in turn) at those k sigma, their noise AR(1) as above and, beside it, the
generator's own white noise: how often each is still named.

    python benchmarks/bench_explain_noise.py [--n 40] [--kinds ar1,laplace,...] [--seed 7]
        [--effects 6,10] [--n-effects 30]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from explain_indep import generate as G  # noqa: E402

KINDS = ("gauss", "ar1", "laplace", "quant1", "quant_coarse", "hetero", "misstated", "few")


def null_case(kind: str, rng: np.random.Generator) -> G.Case:
    """A null of the independent generator (random design and noise sd), its noise replaced."""
    design = str(rng.choice(["s_path", "raster", "random", "edge"]))
    case = G.generate("null", (), 0.0, design, rng)
    r = case.rounds[0]
    x, y, t, s = r["x"], r["y"], r["t"], case.noise_mm
    n = x.size
    base = 5.0 + rng.normal(0, 2e-3) * x + rng.normal(0, 2e-3) * y + rng.normal(0, 0.2)
    e = rng.standard_normal(n)
    if kind == "gauss":  # the control: Gaussian noise of the stated sd
        read = base + s * e
    elif kind == "quant1":
        read = np.round((base + s * e) / 0.001) * 0.001
    elif kind == "quant_coarse":
        q = 1.5 * s
        read = base + q * np.round(s * e / q)
        case.noise_mm = float(np.std(read - base))
    elif kind == "ar1":
        z = np.empty(n)
        z[0] = e[0]
        for i in range(1, n):
            z[i] = 0.5 * z[i - 1] + np.sqrt(0.75) * e[i]
        read = base + s * z
    elif kind == "hetero":
        reach = np.hypot(x - G.BASE[0], y - G.BASE[1])
        read = base + s * (reach / reach.mean()) * e
    elif kind == "laplace":
        read = base + s * rng.laplace(0.0, 1.0 / np.sqrt(2.0), n)
    elif kind == "misstated":
        read = base + 1.5 * s * e
    elif kind == "few":
        keep = np.sort(rng.choice(n, 16, replace=False))
        r["x"], r["y"], r["t"] = x[keep], y[keep], t[keep]
        read = (base + s * e)[keep]
    else:
        raise ValueError(f"unknown noise kind {kind!r}; known: {', '.join(KINDS)}")
    r["reading"] = read
    case.suspects.clear()
    return case


class AR1Draws:
    """A Generator whose noise draw is AR(1): the independent generator draws a recording's
    noise last, as ``standard_normal(n)`` with n the touches; that draw (an int size above 20)
    is made correlated, lag-1 ``rho``, unit marginal sd. Everything else is the Generator's."""

    def __init__(self, rng: np.random.Generator, rho: float):
        self.rng, self.rho = rng, rho

    def __getattr__(self, name):
        return getattr(self.rng, name)

    def standard_normal(self, size=None, *args, **kw):
        e = self.rng.standard_normal(size, *args, **kw)
        if not (isinstance(size, (int, np.integer)) and size > 20 and self.rho):
            return e
        z = np.empty(size)
        z[0] = e[0]
        for i in range(1, size):
            z[i] = self.rho * z[i - 1] + np.sqrt(1.0 - self.rho ** 2) * e[i]
        return z


EFFECTS = ("form:bow", "arm_sag", "thermal_drift", "local_defect", "reversal")


def effects_table(sigmas: list[float], n: int, seed: int, run) -> None:
    """Single effects named right under AR(1) noise (rho 0.5) and under white noise."""
    for k in sigmas:
        for rho in (0.0, 0.5):
            for eff in EFFECTS:
                name = eff.split(":")[0]
                got, scaled = Counter(), 0
                for i in range(n):
                    rng = AR1Draws(np.random.default_rng([seed, i, *eff.encode()]), rho)
                    case = G.generate("single", (eff,), k, ("s_path", "random")[i % 2], rng)
                    f = run(case)
                    v = f["verdict"]
                    got["right" if v == name else v if v in ("none", "unexplained") else "other"] += 1
                    scaled += "serial" in f["readings"]["noise"]
                print(f"{k:g} sigma, {'AR(1) 0.5' if rho else 'white    '} {name:14s} right "
                      f"{got['right']}/{n}, unexplained {got['unexplained']}, none {got['none']}, "
                      f"another effect {got['other']}; evidence scaled in {scaled}", flush=True)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(mid - half, 0.0), min(mid + half, 1.0)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="recordings per noise kind")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--effects", default="", help="k sigma of single effects, e.g. 6,10")
    ap.add_argument("--n-effects", type=int, default=30, help="recordings per effect and k")
    args = ap.parse_args(argv)
    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording

    def run(case):
        with tempfile.TemporaryDirectory() as tmp:
            cell, recs = G.write(case, Path(tmp))
            return explain([read_recording(p) for p in recs], load_cell(cell)).findings

    t0 = time.perf_counter()
    for kind in [k for k in args.kinds.split(",") if k]:
        rng = np.random.default_rng([args.seed, *kind.encode()])
        verdicts, named, high = Counter(), 0, 0
        for _ in range(args.n):
            f = run(null_case(kind, rng))
            verdicts[f["verdict"]] += 1
            if f["verdict"] not in ("none", "unexplained"):
                named += 1
                high += f["verdict_probability"] >= 0.9
        lo, hi = wilson(named, args.n)
        print(f"{kind:13s} library effect named {named}/{args.n} = {100 * named / args.n:.1f} % "
              f"[{100 * lo:.1f}, {100 * hi:.1f}], at p >= 0.9: {high}; verdicts "
              + ", ".join(f"{k} {v}" for k, v in verdicts.most_common()), flush=True)
    if args.effects:
        effects_table([float(v) for v in args.effects.split(",")], args.n_effects, args.seed, run)
    print(f"wall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
