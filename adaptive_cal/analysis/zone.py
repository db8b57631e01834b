"""The minimum zone's linear programme (``flatness.minimum_zone_mm``): the vertical zone's LP in a
frame aligned with the current normal, on the convex hull's vertices or, for many points, on a
working set grown by the points it leaves outside (constraint generation)."""
from __future__ import annotations

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, QhullError

#: points above which the zone's LP is solved on a working set grown by its violators instead
#: of the convex hull (200,000 touches: 0.2 s a fit, most of it the hull)
MANY_POINTS = 5000


def vertical_zone_slopes(points: np.ndarray) -> tuple[float, float]:
    """(a, b) of min_{a,b,c_lo,c_hi} c_hi - c_lo s.t. c_lo <= z_i - a x_i - b y_i <= c_hi (LP).

    Slopes are bounded to |a|, |b| <= 1: called in a frame aligned with a near-optimal normal.
    Many points: constraint generation -- the LP on the highest and lowest few hundred, then
    again with every point it leaves outside its zone, until none is (that optimum is feasible
    for all points, so it is theirs, to 0.1 nm: the hull LP's own tolerance).
    """
    if len(points) <= MANY_POINTS:
        return _zone_lp(points)[:2]
    z = points[:, 2]
    order = np.argsort(z)
    work = np.unique(np.concatenate([order[:300], order[-300:]]))
    for _ in range(100):
        a, b, lo, hi = _zone_lp(points[work])
        r = z - a * points[:, 0] - b * points[:, 1]
        tol = 1e-7 + 1e-9 * (hi - lo)  # mm: 0.1 nm, inside the LP solver's own tolerance
        out = np.flatnonzero((r > hi + tol) | (r < lo - tol))
        if out.size == 0:
            return a, b
        worst = out[np.argsort(-np.maximum(r[out] - hi, lo - r[out]))[:600]]
        work = np.union1d(work, worst)
    return _zone_lp(points)[:2]  # not settled in 100 rounds: all of them at once


def _zone_lp(points: np.ndarray) -> tuple[float, float, float, float]:
    """(a, b, c_lo, c_hi) of the vertical zone's LP on ``points``."""
    x, y, z = points.T
    ones, zeros = np.ones_like(x), np.zeros_like(x)
    upper = np.column_stack([-x, -y, zeros, -ones])  # z_i - a x_i - b y_i <= c_hi
    lower = np.column_stack([x, y, ones, zeros])  # c_lo <= z_i - a x_i - b y_i
    result = linprog(
        c=[0.0, 0.0, -1.0, 1.0],
        A_ub=np.vstack([upper, lower]),
        b_ub=np.concatenate([-z, z]),
        bounds=[(-1.0, 1.0), (-1.0, 1.0), (None, None), (None, None)],
        method="highs",
    )
    if result.status != 0:
        raise RuntimeError(f"minimum-zone LP failed: {result.message}")
    return tuple(float(v) for v in result.x)


def rotation_onto_z(normal: np.ndarray) -> np.ndarray:
    """R with R n = e_z for a unit n (Rodrigues: R = I + [v]x + [v]x^2 / (1 + n.e_z), v = n x e_z)."""
    v = np.cross(normal, [0.0, 0.0, 1.0])
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + normal[2])


def hull_points(points: np.ndarray) -> np.ndarray:
    """The convex-hull vertices (the zone depends on nothing else); all points if degenerate."""
    if len(points) < 5:
        return points
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:
        return points
