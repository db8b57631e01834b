"""Locate the mismatch: is the calibrated residual structured along an axis, and where is it?

For each axis (position, time/order, direction of arrival, reach from the robot base, indication)
a small smooth basis in that axis is added to the calibrated nuisance model and the classical
nested-model F-test asks whether it explains more than noise would (and, since axes correlate on a
path -- time follows the rows of an S-path -- also whether it adds to the position basis):

    F = ((RSS0 - RSS1) / q) / (RSS1 / (m - q)),   p = P(F(q, m - q) > F),

m = touches - rank(nuisance), q = rank of the added basis after projecting out the nuisance.
The statistic is exact for Gaussian noise. ``where`` lists the places on the plate where the
kernel-smoothed residual is largest.
"""
from __future__ import annotations

import numpy as np
from scipy import special

from adaptive_cal.analysis.explain.candidates import Context
from adaptive_cal.analysis.explain.evidence import Projector
from adaptive_cal.analysis.explain.identify import nearest_distance

ALPHA = 0.01  # an axis is flagged "real" below this p-value
KERNEL_REACH = 9.0  # bandwidths; the kernel beyond it is below exp(-40.5) = 2.6e-18


def _normalised(v: np.ndarray) -> np.ndarray:
    lo, hi = float(np.min(v)), float(np.max(v))
    return np.zeros_like(v, float) if hi <= lo else (2.0 * (v - lo) / (hi - lo) - 1.0)


MIN_GROUP = 3  # readings an arrival direction needs to be tested as a group of its own


def direction_columns(sign: np.ndarray) -> np.ndarray:
    """Indicator columns of the arrival directions (moving +, moving -, not moving along the
    axis) against the largest as the base. A direction taken by fewer than ``MIN_GROUP``
    readings joins the base: the first touch arrives from nowhere, and one reading alone is an
    outlier's place, not a direction (a null's first touch at 2 sd read as structure "arriving
    without moving along y", p 0.007). A zero column where fewer than two directions are left."""
    groups = sorted((g for g in (sign > 0, sign < 0, sign == 0) if g.sum() >= MIN_GROUP),
                    key=lambda g: -int(g.sum()))
    if len(groups) < 2:
        return np.zeros((sign.size, 1))
    return np.stack(groups[1:], 1).astype(float)


def axis_bases(ctx: Context) -> dict[str, np.ndarray | str]:
    """The added basis per axis (n x q), or a string saying why the axis is not testable."""
    d = ctx.design
    f = d.features
    (x0, x1), (y0, y1) = d.geometry.x_range_mm, d.geometry.y_range_mm
    u = (f.x_mm - 0.5 * (x0 + x1)) / (0.5 * (x1 - x0))
    v = (f.y_mm - 0.5 * (y0 + y1)) / (0.5 * (y1 - y0))
    out: dict[str, np.ndarray | str] = {
        "position": np.stack([u * u, u * v, v * v, u ** 3, u * u * v, u * v * v, v ** 3], 1)}
    tau = np.empty(d.n)
    for r in range(d.rounds):
        rows = d.round_index == r
        tau[rows] = _normalised(f.t_s[rows])
    out["time"] = np.stack([tau, 1.5 * tau ** 2 - 0.5, 2.5 * tau ** 3 - 1.5 * tau], 1)
    out["direction"] = direction_columns(f.direction)
    if d.geometry.base_xy_mm is None:
        out["reach"] = ("not testable: add robot.base_xy_mm (robot base position in the "
                        "workplane frame, mm) to the cell file")
    else:
        rr = _normalised(f.reach_mm(d.geometry))
        out["reach"] = np.stack([rr, rr ** 2, rr ** 3], 1)
    ind = _normalised(f.ideal_reading_mm)  # the calibrated indication, not the noisy reading
    out["indication"] = np.stack([ind, ind ** 2], 1)
    return out


ROUNDOFF = 1e-10  # of a column's norm: what is left of it after a projection that spans it


def column_norm(X: np.ndarray) -> float:
    """The largest column norm of X."""
    return float(np.linalg.norm(X, axis=0).max(initial=0.0))


def f_test(ctx: Context, X: np.ndarray, given: np.ndarray | None = None) -> dict:
    """Nested-model F-test of the added columns X against the calibrated nuisance model
    (plus the columns ``given``, for a test conditional on another axis)."""
    if given is None:
        project, yt, m = ctx.project, ctx.yt, ctx.m
    else:
        project = Projector.of(np.hstack([ctx.nuisance, given]))
        yt, m = project(ctx.design.target), ctx.design.n - project.rank
    Xt = project(X)
    U, s, _ = np.linalg.svd(Xt, full_matrices=False)
    # a column the nuisance spans leaves round-off (1e-13 of its norm), not variation to test
    keep = (s > 1e-8 * max(s.max(initial=0.0), 1e-300)) & (s > ROUNDOFF * column_norm(X))
    q = int(min(keep.sum(), max(m - 3, 0)))
    yy = float(yt @ yt)
    if q == 0:
        return {"statistic": "F", "value": 0.0, "dof": [0, m], "p_value": 1.0,
                "explained_rms_mm": 0.0, "real": False,
                "note": "no variation along this axis that the tilt does not already absorb"}
    proj = U[:, keep][:, :q].T @ yt
    explained = float(proj @ proj)
    rss1 = max(yy - explained, 1e-300)
    F = (explained / q) / (rss1 / (m - q))
    p = float(special.fdtrc(q, m - q, max(F, 0.0)))  # scipy.stats.f.sf, without loading stats
    return {"statistic": "F", "value": float(F), "dof": [q, m - q], "p_value": p,
            "explained_rms_mm": float(np.sqrt(explained / ctx.design.n)), "real": bool(p < ALPHA)}


def nearest_other(xy: np.ndarray) -> np.ndarray:
    """Distance from each of the distinct points ``xy`` to the nearest other, as the dense hypot
    matrix (diagonal set to inf) gives it, without that n x n matrix
    (``identify.nearest_distance``'s k-d tree)."""
    return nearest_distance(xy[:, 0], xy[:, 1], xy[:, 0], xy[:, 1], others=True)


def smoothing_grid(d) -> tuple[np.ndarray, np.ndarray, float]:
    """The grid ``where`` smooths the residual on (46 x 38 points over the plate) and the
    bandwidth h: the median nearest-touch distance (over at most 2,000 distinct positions)."""
    xy = np.unique(np.stack([d.features.x_mm, d.features.y_mm], 1), axis=0)
    if len(xy) > 2000:
        xy = xy[np.linspace(0, len(xy) - 1, 2000).astype(int)]
    h = float(np.median(nearest_other(xy))) if len(xy) > 1 else 1.0
    (x0, x1), (y0, y1) = d.geometry.x_range_mm, d.geometry.y_range_mm
    gx, gy = np.meshgrid(np.linspace(x0, x1, 46), np.linspace(y0, y1, 38), indexing="ij")
    return gx.ravel(), gy.ravel(), h


def peaks(d, gx, gy, h: float, value: np.ndarray, weight: np.ndarray, residual: np.ndarray,
          sigma_mm: float, top: int = 3) -> list[dict]:
    """The ``top`` peaks of the smoothed residual (``value``, kernel ``weight`` per grid point),
    each with the touches within 1.5 h and their share of the residual sum of squares."""
    score = np.abs(value) * np.sqrt(weight)  # z-like: mean residual x sqrt(effective touches)
    score[weight < 0.5] = 0.0  # no touch nearby: nothing to say
    out = []
    total_ss = float(residual @ residual) or 1.0
    for _ in range(top):
        i = int(np.argmax(score))
        if score[i] <= 0:
            break
        near = np.hypot(d.features.x_mm - gx[i], d.features.y_mm - gy[i]) <= 1.5 * h
        out.append({"x_mm": round(float(gx[i]), 1), "y_mm": round(float(gy[i]), 1),
                    "residual_mm": float(value[i]),
                    "z": float(value[i] * np.sqrt(weight[i]) / sigma_mm),
                    "touches": int(near.sum()),
                    "share_of_residual_ss": float(residual[near] @ residual[near] / total_ss)})
        score[np.hypot(gx - gx[i], gy - gy[i]) < 3.0 * h] = 0.0
    return out


def where(ctx: Context, residual: np.ndarray, sigma_mm: float, top: int = 3) -> list[dict]:
    """Peaks of the kernel-smoothed residual (bandwidth: median nearest-touch distance)."""
    d = ctx.design
    gx, gy, h = smoothing_grid(d)
    # the kernel beyond KERNEL_REACH bandwidths is below the rounding of the weights that count
    # (a grid point counts from weight 0.5): only the touches within it enter each sum
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.stack([gx, gy], 1)).sparse_distance_matrix(
        cKDTree(np.stack([d.features.x_mm, d.features.y_mm], 1)), KERNEL_REACH * h,
        output_type="ndarray")
    g, t = pairs["i"], pairs["j"]
    k = np.exp(-0.5 * ((gx[g] - d.features.x_mm[t]) ** 2 + (gy[g] - d.features.y_mm[t]) ** 2)
               / h ** 2)
    weight = np.bincount(g, k, minlength=gx.size)
    value = np.bincount(g, k * residual[t], minlength=gx.size) / np.maximum(weight, 1e-300)
    return peaks(d, gx, gy, h, value, weight, residual, sigma_mm, top)


def locate(ctx: Context) -> dict:
    """The ``mismatch`` block of the report."""
    r = ctx.yt
    sigma = float(np.sqrt(r @ r / max(ctx.m, 1)))
    by = {}
    bases = axis_bases(ctx)
    for axis, X in bases.items():
        if isinstance(X, str):
            by[axis] = {"statistic": None, "p_value": None, "real": None, "note": X}
            continue
        by[axis] = f_test(ctx, X)
        if axis != "position" and ctx.m > 20:  # does the axis add anything position does not?
            by[axis]["p_value_given_position"] = f_test(ctx, X, bases["position"])["p_value"]
    if ctx.design.time_blank:
        by["time"]["note"] = ctx.design.time_blank
    return {"rms_mm": float(np.sqrt(r @ r / ctx.design.n)), "by": by,
            "where": where(ctx, r, sigma)}
