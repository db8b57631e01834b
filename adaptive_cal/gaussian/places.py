"""Readings at one place: one definition (``places``, on the readings' x, y) for everything that
asks -- the repeats check (``checks.repeats``), the planner's repeat touches
(``planning.repeats``) and the hyper-parameters' fit (``prior.learned_belief``), where readings at
one place enter as their mean with the summed weight, and their scatter about it as a floor
under the learned noise (``pooled``)."""
from __future__ import annotations

import numpy as np

#: readings closer than this (mm) are taken at one place (a repeat sent to the same x, y): a
#: repeat sent to a position rebuilt from the first reading's basis row lands about 1e-10 mm
#: off it, a recording keeps 4 decimals (5e-5 mm), and two places the planner picks apart are
#: a millimetre or more apart
SAME_PLACE_MM = 0.01


def positions_mm(surface, rows: np.ndarray) -> np.ndarray:
    """(x, y) of readings from their basis rows: a row is m_x(x) kron m_y(y) and a spline
    reproduces constants and straight lines (sum m = 1, m . knots = t), so x = m_x . knots_x.
    Exact for natural and not-a-knot ends."""
    rows = np.asarray(rows, float)
    r = rows.reshape(len(rows), surface.sx.size, surface.sy.size)
    mx, my = r.sum(axis=2), r.sum(axis=1)
    return np.stack([mx @ surface.sx.knots, my @ surface.sy.knots], 1)


def places(xy_mm) -> tuple[np.ndarray, np.ndarray]:
    """(label of each point's place, readings per place): points within ``SAME_PLACE_MM`` of one
    another in x and in y, chained, are one place (single linkage: no rounding grid that two
    readings a hair apart could straddle), labelled in the order first read."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    n = len(xy)
    if n < 2:
        return np.zeros(n, int), np.ones(n, int)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(xy).query_pairs(SAME_PLACE_MM, p=np.inf, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    rank = np.empty(len(first), int)
    rank[np.argsort(first)] = np.arange(len(first))
    label = rank[label]
    return label, np.bincount(label)


def pooled(surface, rows, readings, weights=None):
    """Readings at one place (``places`` of their positions on ``surface``) as one: their
    weighted mean, with the sum of their weights (noise sigma_n^2 / w: the same information
    about the surface), at the place's first row, places in the order first read; and (ss, dof)
    of the scatter about each place's mean, sum w_i (y_i - mean)^2 over readings of weight
    >= 1/2 (a reading weighted out as a gross error is no measure of the probe) and their count
    less their places', or None where no place is read twice."""
    rows = np.asarray(rows, float)
    y = np.asarray(readings, float)
    w = np.ones(len(y)) if weights is None else np.asarray(weights, float)
    label, counts = places(positions_mm(surface, rows))
    count = len(counts)
    if count == len(y):
        return rows, y, w, None
    first = np.full(count, len(y))
    np.minimum.at(first, label, np.arange(len(y)))
    wsum = np.bincount(label, w, count)
    mean = np.bincount(label, w * y, count) / np.maximum(wsum, 1e-300)
    keep = w >= 0.5
    kw = np.bincount(label[keep], w[keep], count)
    kmean = np.bincount(label[keep], w[keep] * y[keep], count) / np.maximum(kw, 1e-300)
    k = np.bincount(label[keep], minlength=count)
    dof = int(np.sum(np.maximum(k - 1, 0)))
    ss = float(np.sum(w[keep] * (y[keep] - kmean[label[keep]]) ** 2))
    return rows[first], mean, wsum, ((ss, dof) if dof else None)


def floor_penalty(log_sigma: float, ss: float, dof: int) -> tuple[float, float]:
    """-log of the readings' scatter at their places, ss ~ p^2 chi2(dof), profiled over the
    probe's share p <= sigma_n = exp(log_sigma), less its maximum, and its derivative in
    log_sigma: 0 where sigma_n^2 >= ss / dof, else dof u + ss e^(-2u) / 2 less its value at the
    scatter's own variance (C1 at the join)."""
    if dof <= 0 or ss <= 0:
        return 0.0, 0.0
    u0 = 0.5 * np.log(ss / dof)
    if log_sigma >= u0:
        return 0.0, 0.0
    f = lambda u: dof * u + 0.5 * ss * np.exp(-2.0 * u)
    return float(f(log_sigma) - f(u0)), float(dof - ss * np.exp(-2.0 * log_sigma))
