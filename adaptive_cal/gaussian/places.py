"""Readings at one place in the hyper-parameters' fit (``prior.learned_belief``): their mean with
the summed weight, and their scatter about it as a floor under the learned noise."""
from __future__ import annotations

import numpy as np

from adaptive_cal.gaussian.checks import row_places


def pooled(rows, readings, weights=None):
    """Readings at one place (``checks.row_places``) as one: their weighted mean, with the sum of
    their weights (noise sigma_n^2 / w: the same information about the surface), at the place's
    first row, places in the order first read; and (ss, dof) of the scatter about each place's
    mean, sum w_i (y_i - mean)^2 over readings of weight >= 1/2 (a reading weighted out as a
    gross error is no measure of the probe) and their count less their places', or None where
    no place is read twice."""
    rows = np.asarray(rows, float)
    y = np.asarray(readings, float)
    w = np.ones(len(y)) if weights is None else np.asarray(weights, float)
    label, count = row_places(rows)
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
