"""Batches and travel order: the covariance after a reading does not depend on its value, so a
batch is chosen greedily without readings and may then be taken in any order (Brunn, sec. IV)."""
from __future__ import annotations

from typing import Callable

import numpy as np

from adaptive_cal.gaussian.belief import covariance_after


def plan_batch(pick: Callable[[np.ndarray], int], rows, cov, noise_var, k: int) -> list[int]:
    """k candidate indices chosen greedily; the covariance is updated after each pick without
    readings (it does not depend on them), so the batch can be taken in any order."""
    chosen = []
    for _ in range(k):
        i = pick(cov)
        chosen.append(i)
        cov = covariance_after(cov, rows[i : i + 1], noise_var)
    return chosen


def travel_order(start_xy, points_xy: np.ndarray) -> list[int]:
    """Order points for a short path from ``start_xy``: nearest neighbour, then 2-opt."""
    pts = np.asarray(points_xy, float)
    n = len(pts)
    left, order, here = set(range(n)), [], np.asarray(start_xy, float)
    while left:
        j = min(left, key=lambda i: np.hypot(*(pts[i] - here)))
        order.append(j)
        left.remove(j)
        here = pts[j]
    path = [np.asarray(start_xy, float)] + [pts[i] for i in order]

    def d(a, b):
        return float(np.hypot(*(a - b)))

    improved = True
    while improved:
        improved = False
        for i in range(1, n):
            for j in range(i + 1, n + 1):
                a, b = path[i - 1], path[i]
                c = path[j]
                e = path[j + 1] if j + 1 <= n else None
                before = d(a, b) + (d(c, e) if e is not None else 0.0)
                after = d(a, c) + (d(b, e) if e is not None else 0.0)
                if after < before - 1e-9:
                    path[i : j + 1] = path[i : j + 1][::-1]
                    order[i - 1 : j] = order[i - 1 : j][::-1]
                    improved = True
    return order


def path_length_mm(start_xy, points_xy) -> float:
    pts = np.vstack([np.asarray(start_xy, float)[None], np.asarray(points_xy, float)])
    return float(np.hypot(*np.diff(pts, axis=0).T).sum())
