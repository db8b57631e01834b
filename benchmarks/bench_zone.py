"""Minimum zone speed: the solver-free narrowest slab (``zone.narrowest_normal``) against the
vertical-zone LP it falls back to, on what a run computes -- 200 posterior draws of a 41 x 41 map
and of 31 touched points -- with their widths compared (the LP is the oracle).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_zone.py [--draws 200]

Prints seconds per zone for each, their ratio, and the largest relative difference in width.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from adaptive_cal.analysis import flatness as fl  # noqa: E402


def by_lp(x, y, z):
    return fl.minimum_zone_mm(x, y, z, lp_only=True)


def draws_of(x, y, rng, draws):
    """A tilted, bowed, twisted plate with smooth per-draw wiggles (um-scale) and noise."""
    base = 0.014 * x + 0.002 * y + 0.1 * (y / 185) ** 2 + 0.05 * x * y / 4e4
    wiggle = rng.normal(0, 3e-3, (draws, 4))
    return (base + wiggle[:, :1] * np.sin(x / 60) + wiggle[:, 1:2] * np.cos(y / 45)
            + wiggle[:, 2:3] * np.sin((x + y) / 90) + rng.normal(0, 1e-3, (draws, x.size)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    g = np.linspace(-225, 225, 41)
    grid = [v.ravel() for v in np.meshgrid(g, g * 185 / 225)]
    touched = [rng.uniform(-215, 215, 31), rng.uniform(-175, 175, 31)]
    print(f"{'points':>7} {'draws':>5} {'slab s/zone':>12} {'LP s/zone':>10} {'LP / slab':>9} "
          f"{'max |rel diff|':>14}")
    for x, y in (grid, touched):
        zs = draws_of(x, y, rng, args.draws)
        t0 = time.perf_counter()
        fast = [fl.minimum_zone_mm(x, y, z).value_mm for z in zs]
        t1 = time.perf_counter()
        slow = [by_lp(x, y, z).value_mm for z in zs]
        t2 = time.perf_counter()
        diff = np.max(np.abs(np.subtract(fast, slow)) / np.abs(slow))
        a, b = (t1 - t0) / len(zs), (t2 - t1) / len(zs)
        print(f"{x.size:7d} {len(zs):5d} {a:12.5f} {b:10.5f} {b / a:9.1f} {diff:14.2e}")


if __name__ == "__main__":
    main()
