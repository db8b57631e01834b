"""Flatness and tilt of a measured workplane: least-squares plane, range, minimum zone.

Heights ``z_mm`` are surface heights (larger = higher) at plate positions ``x_mm, y_mm``.
Figures follow Cheng, Chang & Weng (2025), sec. 3.2 (least-squares plane, eqs. 1-5) and Table 8
(average ranges), plus the ISO 1101 minimum zone. Every width is reported normal to its planes,
``vertical width / sqrt(1 + a^2 + b^2)``, as in the paper's eq. 5. Each figure can also be
computed for posterior sample surfaces, giving a distribution instead of a single number.
"""
from __future__ import annotations

from typing import Mapping, NamedTuple

import numpy as np

from adaptive_cal.analysis import zone

FIGURES = ("least_squares", "range", "minimum_zone", "range_x_avg", "range_y_avg")
_GROUP_DECIMALS = 6  # positions equal to 1 nm share a row or column of the grid
_MAX_PAIRS = 4_000_000


class PlaneFit(NamedTuple):
    """z = a x + b y + c (a, b in mm/mm, c in mm) and residuals E_i = z_i - (a x_i + b y_i + c)."""

    a: float
    b: float
    c: float
    residuals_mm: np.ndarray


class MinZone(NamedTuple):
    """Two parallel planes z = a x + b y + c_low and z = a x + b y + c_high enclosing all points.

    ``value_mm`` is their distance measured normal to the planes,
    (c_high - c_low) / sqrt(1 + a^2 + b^2).
    """

    value_mm: float
    a: float
    b: float
    c_low: float
    c_high: float


def _as_arrays(*arrays) -> tuple[np.ndarray, ...]:
    """x, y, z as float arrays of one point each, checked: ValueError naming the argument for
    text, a 2-D array, fewer than 3 points (no plane) or a value that is not finite."""
    out = []
    for name, v in zip(("x_mm", "y_mm", "z_mm"), arrays):
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: {v!r:.60} is not an array of numbers (mm)") from None
        if a.ndim != 1:
            raise ValueError(f"{name}: one value per point (a 1-D array), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            bad = int(np.flatnonzero(~np.isfinite(a))[0])
            raise ValueError(f"{name}[{bad}] = {a[bad]}: every value must be a finite number (mm)")
        out.append(a)
    if any(v.shape[0] != out[0].shape[0] for v in out):
        raise ValueError(f"x, y, z must have the same number of points, got {[v.shape for v in out]}")
    if out[0].shape[0] < 3:
        raise ValueError(f"{out[0].shape[0]} point(s): a plane, and so a flatness, needs at least 3")
    return tuple(out)


def _plane_coefficients(x_mm, y_mm, z_mm):
    """[a, b, c] minimising sum (z_i - a x_i - b y_i - c)^2 (eq. 2) for z of shape (N,) or (N, S).

    Solves eq. 4 by least squares on centred coordinates (same minimiser, better conditioned).
    """
    xm, ym = x_mm.mean(), y_mm.mean()
    design = np.column_stack([x_mm - xm, y_mm - ym, np.ones_like(x_mm)])
    (a, b, c0), *_ = np.linalg.lstsq(design, z_mm, rcond=None)
    return a, b, c0 - a * xm - b * ym


def least_squares_plane(x_mm, y_mm, z_mm) -> PlaneFit:
    """z = a x + b y + c minimising S = sum_i (z_i - a x_i - b y_i - c)^2 (Cheng 2025 eqs. 1-4)."""
    x_mm, y_mm, z_mm = _as_arrays(x_mm, y_mm, z_mm)
    a, b, c = _plane_coefficients(x_mm, y_mm, z_mm)
    residuals = z_mm - (a * x_mm + b * y_mm + c)
    return PlaneFit(float(a), float(b), float(c), residuals)


def ls_flatness_mm(x_mm, y_mm, z_mm) -> float:
    """Flatness = (E_max - E_min) / sqrt(1 + a^2 + b^2) about the least-squares plane (eq. 5)."""
    fit = least_squares_plane(x_mm, y_mm, z_mm)
    return float(np.ptp(fit.residuals_mm) / np.sqrt(1.0 + fit.a**2 + fit.b**2))


def range_mm(z_mm) -> float:
    """Range = max_i z_i - min_i z_i (tilt included)."""
    return float(np.ptp(np.asarray(z_mm, dtype=np.float64)))


def _groups(key_mm: np.ndarray) -> list[np.ndarray] | None:
    """Index sets of the points sharing a key value; None when a group has fewer than 2 points."""
    _, inverse, counts = np.unique(np.round(key_mm, _GROUP_DECIMALS), return_inverse=True,
                                   return_counts=True)
    if counts.min() < 2:  # decided before the groups are built: touches off a grid are many
        return None
    order = np.argsort(inverse.ravel(), kind="stable")  # each group's indices, ascending
    return np.split(order, np.cumsum(counts)[:-1])


def _average_range(key_mm: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """mean over groups g of (max_{i in g} z_i - min_{i in g} z_i); z of shape (..., N); NaN off-grid."""
    groups = _groups(key_mm)
    if groups is None:
        return np.full(z_mm.shape[:-1], np.nan)
    return np.mean([np.ptp(z_mm[..., g], axis=-1) for g in groups], axis=0)


def average_ranges_mm(x_mm, y_mm, z_mm) -> tuple[float, float]:
    """(mean_y range_x, mean_x range_y): the paper's average-range method (Table 8).

    range_x_avg groups the points by y (grid columns S0..S3), takes max - min of z along x in each
    group and averages; range_y_avg groups by x and takes ranges along y. A figure is NaN when the
    design is not a grid in that direction (some group has a single point).
    """
    x_mm, y_mm, z_mm = _as_arrays(x_mm, y_mm, z_mm)
    return float(_average_range(y_mm, z_mm)), float(_average_range(x_mm, z_mm))


def minimum_zone_mm(x_mm, y_mm, z_mm, max_iter: int = 10, lp_only: bool = False) -> MinZone:
    """ISO 1101 minimum zone: min over unit normals n of max_i n.p_i - min_i n.p_i.

    The width along n = (-a, -b, 1)/sqrt(1 + a^2 + b^2) is V(a, b)/sqrt(1 + a^2 + b^2), with
    V(a, b) = max_i (z_i - a x_i - b y_i) - min_i (...). Exactly, without a solver, where the
    narrowest slab's slopes lie within +-0.5 of the least-squares plane (26.6 deg along x or y;
    ``zone.narrowest_normal``: every facet-vertex and edge-edge direction of a working set grown
    by the points left outside; every plate tested did): the global minimum, so value_mm <= eq. 5
    flatness and no wider than the LP's zone. Otherwise the vertical width is minimised by an LP
    in a frame whose z axis is the current normal, starting from the least-squares plane's: each
    step cannot increase the normal width, and at the fixed point (slopes < 1e-12 in the rotated
    frame) n is a local minimum of the normal width. The LP's zone can be wider than the exact
    one by its solver's tolerance (1e-7 mm on a constraint: 3e-8 of the width on 41 x 41 map
    draws). The exact route is 4 x faster on 200 such draws, 8 x on 31 touched points
    (benchmarks/bench_zone.py). ``lp_only``: the LP route alone (the exact route's oracle).
    """
    x_mm, y_mm, z_mm = _as_arrays(x_mm, y_mm, z_mm)
    centre = np.array([x_mm.mean(), y_mm.mean(), z_mm.mean()])
    xy = np.column_stack([x_mm - centre[0], y_mm - centre[1]])
    if np.linalg.matrix_rank(xy, tol=1e-6 * max(float(np.abs(xy).max(initial=0.0)), 1e-12)) < 2:
        # a vertical plane through the line holds every point: zero width, no plate zone
        raise ValueError(f"the {len(x_mm)} touched points lie on one line in x, y: a flatness "
                         "zone needs touches that span the plate")
    points = np.column_stack([x_mm, y_mm, z_mm]) - centre
    a, b, _ = _plane_coefficients(*points.T)
    normal = np.array([-a, -b, 1.0]) / np.sqrt(1.0 + a**2 + b**2)
    rotation = zone.rotation_onto_z(normal)
    narrowest = None if lp_only else zone.narrowest_normal(points @ rotation.T)
    if narrowest is not None:
        return _zone_along(rotation.T @ narrowest, points, centre)
    return _zone_along(_zone_lp_normal(points, normal, max_iter), points, centre)


def _zone_lp_normal(points, normal, max_iter: int) -> np.ndarray:
    """The minimum zone's normal by the vertical zone's LP from ``normal`` (the least-squares
    plane's): each step cannot increase the normal width, so the width stays at or below eq. 5's,
    and at the fixed point (slopes < 1e-12 in the rotated frame) n is a local minimum of it."""
    points = zone.hull_points(points) if len(points) <= zone.MANY_POINTS else points
    for _ in range(max_iter):
        rotation = zone.rotation_onto_z(normal)
        a_local, b_local = zone.vertical_zone_slopes(points @ rotation.T)
        step = np.array([-a_local, -b_local, 1.0])
        normal = rotation.T @ (step / np.linalg.norm(step))
        if max(abs(a_local), abs(b_local)) < 1e-12:
            break
    return normal


def _zone_along(normal, points, centre) -> MinZone:
    """The zone of the centred ``points`` between the planes of ``normal`` that hold them
    (``normal`` taken upward: the lower plane's c is c_low)."""
    normal = normal if normal[2] >= 0 else -normal
    distance = points @ normal
    a, b, scale = -normal[0] / normal[2], -normal[1] / normal[2], 1.0 / normal[2]
    c0 = centre[2] - a * centre[0] - b * centre[1]
    return MinZone(float(np.ptp(distance)), float(a), float(b),
                   float(c0 + distance.min() * scale), float(c0 + distance.max() * scale))


def tilt_correction_deg(a: float, b: float) -> tuple[float, float]:
    """(rx, ry) with rotx(rx) roty(ry) e_z = (sin ry, -sin rx cos ry, cos rx cos ry) || (-a, -b, 1).

    Hence rx = atan(b), ry = -atan(a / sqrt(1 + b^2)): the user-frame correction
    frame_new = frame_nominal * rotx(rx) * roty(ry) (RoboDK order) whose z axis is the plate normal.
    """
    for name, v in (("a", a), ("b", b)):
        if isinstance(v, (str, bytes)) or not np.isfinite(v):
            raise ValueError(f"{name} = {v!r}: a slope must be a finite number (mm/mm)")
    rx = np.arctan(b)
    ry = -np.arctan(a / np.sqrt(1.0 + b * b))
    return float(np.degrees(rx)), float(np.degrees(ry))


def plane_tilt(x_mm, y_mm, z_mm) -> dict[str, float]:
    """Least-squares plane z = a x + b y + c and its frame correction angles (tilt_correction_deg)."""
    fit = least_squares_plane(x_mm, y_mm, z_mm)
    rx_deg, ry_deg = tilt_correction_deg(fit.a, fit.b)
    return {"rx_deg": rx_deg, "ry_deg": ry_deg, "a": fit.a, "b": fit.b, "c": fit.c}


def figures(x_mm, y_mm, z_mm) -> dict[str, float]:
    """All flatness figures in mm: least_squares (eq. 5), range, minimum_zone, range_x/y_avg."""
    range_x_avg, range_y_avg = average_ranges_mm(x_mm, y_mm, z_mm)
    return {
        "least_squares": ls_flatness_mm(x_mm, y_mm, z_mm),
        "range": range_mm(z_mm),
        "minimum_zone": minimum_zone_mm(x_mm, y_mm, z_mm).value_mm,
        "range_x_avg": range_x_avg,
        "range_y_avg": range_y_avg,
    }


def ls_flatness_samples_mm(x_mm, y_mm, surfaces_mm) -> np.ndarray:
    """Eq. 5 of each row of ``surfaces_mm`` (S, N): one multi-right-hand-side solve of eq. 4,
    then the residual range measured normal to each row's plane. Returns (S,)."""
    surfaces_mm = np.atleast_2d(np.asarray(surfaces_mm, dtype=np.float64))
    x_mm, y_mm, _ = _as_arrays(x_mm, y_mm, surfaces_mm[0])
    a, b, c = _plane_coefficients(x_mm, y_mm, surfaces_mm.T)  # each (S,)
    residuals = surfaces_mm - (np.outer(a, x_mm) + np.outer(b, y_mm) + c[:, None])
    return np.ptp(residuals, axis=1) / np.sqrt(1.0 + a**2 + b**2)


def sampled_figures(x_mm, y_mm, surfaces_mm) -> dict[str, np.ndarray]:
    """The figures of each posterior sample surface; surfaces_mm is (S, N) heights at the N points.

    Least squares is one multi-right-hand-side solve of eq. 4; the minimum zone is one LP per
    sample on its convex hull. Returns arrays of shape (S,) keyed as in ``figures``.
    """
    surfaces_mm = np.atleast_2d(np.asarray(surfaces_mm, dtype=np.float64))
    x_mm, y_mm, _ = _as_arrays(x_mm, y_mm, surfaces_mm[0])
    return {
        "least_squares": ls_flatness_samples_mm(x_mm, y_mm, surfaces_mm),
        "range": np.ptp(surfaces_mm, axis=1),
        "minimum_zone": np.array([minimum_zone_mm(x_mm, y_mm, z).value_mm
                                  for z in _shown(surfaces_mm, "minimum-zone fits")]),
        "range_x_avg": _average_range(y_mm, surfaces_mm),
        "range_y_avg": _average_range(x_mm, surfaces_mm),
    }


def _shown(samples: np.ndarray, what: str):
    """``samples`` to iterate over, with a progress bar on a terminal where they are many
    points each (a 200,000-touch recording takes a minute or more: 0.2 s a fit)."""
    if samples.size < 2_000_000:
        return samples
    from tqdm import tqdm

    return tqdm(samples, desc=what, unit="sample", disable=None, leave=False)


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, or None where it is NaN or infinite (JSON has no NaN)."""
    return float(value) if np.isfinite(value) else None


def _ci95(samples: np.ndarray) -> list[float | None]:
    samples = np.asarray(samples, dtype=np.float64)
    if samples.size == 0 or not np.all(np.isfinite(samples)):
        return [None, None]
    return [float(q) for q in np.percentile(samples, [2.5, 97.5])]


def _require_same_names(first: Mapping, second: Mapping, what: str) -> None:
    missing = sorted(set(first) ^ set(second))
    if missing:
        raise KeyError(f"{what}: figure(s) {missing} present on one side only")


def interval_figures(value_by_name: Mapping[str, float],
                     samples_by_name: Mapping[str, np.ndarray]) -> dict[str, dict]:
    """{name: {"value": v, "ci95": [q_2.5, q_97.5]}} with q_p the p-th percentile of the samples.

    Plain floats (JSON-ready); NaN becomes None.
    """
    _require_same_names(value_by_name, samples_by_name, "interval_figures")
    return {name: {"value": finite_or_none(value), "ci95": _ci95(samples_by_name[name])}
            for name, value in value_by_name.items()}


def _thin(samples: np.ndarray, count: int) -> np.ndarray:
    if len(samples) <= count:
        return samples
    return samples[np.linspace(0, len(samples) - 1, count).round().astype(int)]


def _compare_one(a: np.ndarray, b: np.ndarray) -> dict:
    """P(B > A) = mean_{i,j} [b_j > a_i] and quantiles of b_j - a_i over all pairs (independent)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.size == 0 or b.size == 0 or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return {"p_b_greater": None, "diff_mean": None, "diff_ci95": [None, None]}
    below = np.searchsorted(np.sort(a), b, side="left")  # number of a_i < b_j, for each j
    p_b_greater = float(below.sum() / (a.size * b.size))
    if a.size * b.size > _MAX_PAIRS:
        per_side = int(np.sqrt(_MAX_PAIRS))
        a, b = _thin(np.sort(a), per_side), _thin(np.sort(b), per_side)
    diff = (b[None, :] - a[:, None]).ravel()
    return {
        "p_b_greater": p_b_greater,
        "diff_mean": float(diff.mean()),
        "diff_ci95": _ci95(diff),
    }


def compare_rounds(samples_a: Mapping[str, np.ndarray],
                   samples_b: Mapping[str, np.ndarray]) -> dict[str, dict]:
    """Per figure, P(B > A) and the 95 % interval of B - A for independent posteriors A and B.

    Both are taken over all pairs (a_i, b_j) of the samples, i.e. the exact answer for the two
    empirical distributions (thinned evenly to 2000 each when there are more than 4e6 pairs).
    """
    _require_same_names(samples_a, samples_b, "compare_rounds")
    return {name: _compare_one(samples_a[name], samples_b[name]) for name in samples_a}


LINE_RATIO = 1e-3  # touches spread across their line less than this share of along it: a line


def line_spread(x, y) -> tuple[np.ndarray, np.ndarray]:
    """(RMS spread along and across the touches' principal line, mm; its direction vectors,
    rows): the touches (x, y) lie on one line, or nearly, where spread[1] <= ``LINE_RATIO`` x
    spread[0] -- the test flatness and explain refuse such touches by (no tilt across it)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    _, spread, vt = np.linalg.svd(np.c_[x - x.mean(), y - y.mean()], full_matrices=False)
    return spread / np.sqrt(len(x)), vt

