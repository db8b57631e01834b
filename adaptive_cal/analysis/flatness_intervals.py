"""Flatness of a recording with 95 % intervals: the figures of the touched points, and their spread
over predicted repeat measurements at the same touches.

Values are the figures of the heights themselves (``analysis.flatness``: the paper's least-squares
plane, eqs. 1-6 of Cheng et al., range, ISO 1101 minimum zone), so they compare with published
numbers. The interval comes from the belief fitted to the recording,

    z* = B m* + e*,   m* ~ N(mean, C | heights),   e* ~ N(0, sigma*^2 I),

with B the spline rows of the touches and sigma*^2 = sigma^2 nu / chi2_nu, sigma the learned
reading noise on nu degrees of freedom (``flatness_answer.repeat_noise_mm``, as the run's touched
points): the figures of S such repeats give the 95 % interval, and two rounds whose intervals
separate really differ.
The prior is built here from explicit numbers (a plane with a wide tilt and offset plus a smooth
form), not from a cell file: a recording carries no cell.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from adaptive_cal.analysis import flatness as fl
from adaptive_cal.analysis.flatness_answer import MEASURED, entry, repeat_noise_mm
from adaptive_cal.formats.recording import (Recording, RecordingError, read_recording,
                                           surface_height_mm)
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import Hyper, PriorModel, fit_hyper
from adaptive_cal.gaussian.spline import Surface, default_knots

NAMES = ("least_squares", "range", "minimum_zone")  # the figures given with an interval


class TouchPrior(NamedTuple):
    """The prior of a recording's surface, in numbers (defaults: those the cell file uses, with a
    wider tilt and offset because nothing is known about the plate's level)."""

    tilt_std_deg: float = 5.0
    offset_std_mm: float = 10.0
    noise_std_mm: float = 0.01  # first guess; learned from the heights
    form_std_mm: float = 0.05  # first guess; learned
    form_tolerance_mm: float = 0.1  # knot spacing by Brunn eq. 15
    max_curvature_per_mm: float = 5e-5


def heights(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, height) of the fused touches, mm: height = reading - probe zero + z (the one
    conversion, ``surface_height_mm``), with the recording's ``probe_zero_mm`` metadata, else 0."""
    f = rec.fused
    zero_mm = float(rec.meta.get("probe_zero_mm", 0.0))
    return rec.x_mm[f], rec.y_mm[f], surface_height_mm(rec.reading_mm[f], rec.z_mm[f], zero_mm)


def _padded(v: np.ndarray) -> tuple[float, float]:
    """[min, max] of the positions widened by half the smallest step (10 mm for one position)."""
    u = np.unique(v)
    pad = 0.5 * float(np.min(np.diff(u))) if len(u) > 1 else 10.0
    return float(u[0] - pad), float(u[-1] + pad)


def touch_prior(x_mm, y_mm, prior: TouchPrior = TouchPrior()) -> PriorModel:
    """The spline prior over the touches' bounding box (plus half a grid step on each side):
    knots by Brunn eq. 15, not-a-knot ends, tilt + form covariance with ``prior``'s numbers."""
    (x0, x1), (y0, y1) = _padded(np.asarray(x_mm, float)), _padded(np.asarray(y_mm, float))
    knots = [default_knots(lo, hi, prior.form_tolerance_mm, prior.max_curvature_per_mm)
             for lo, hi in ((x0, x1), (y0, y1))]
    span = min(x1 - x0, y1 - y0)
    hyper0 = Hyper(prior.form_std_mm, 0.5 * span, prior.noise_std_mm)
    return PriorModel(Surface.create(*knots, ends="not_a_knot"),
                      float(np.tan(np.radians(prior.tilt_std_deg))), prior.offset_std_mm,
                      (0.5 * (x0 + x1), 0.5 * (y0 + y1)), hyper0)


def repeat_samples(x, y, z, rng: np.random.Generator, n: int,
                   prior: TouchPrior = TouchPrior()) -> tuple[dict, dict, dict]:
    """Figures of ``n`` predicted repeat measurements at the same touches (see module docstring),
    the learned hyper-parameters, and the figures of the same ``n`` surfaces at the touches
    without the repeats' noise (the plate's figure there, for ``compare``)."""
    model = touch_prior(x, y, prior)
    rows = model.surface.basis(x, y)
    # about their mean: every figure is blind to a constant, and the prior's offset is not
    # (an outside audit: heights 990 mm up learned 4.65 um of noise for 3.66 um)
    z = np.asarray(z, float) - float(np.mean(z))
    hyper = fit_hyper(model, rows, z)
    post = bl.condition(model.belief(hyper), rows, z, hyper.noise_std_mm**2)
    draws = bl.sample(post, rng, n) @ rows.T
    plate = fl.sampled_figures(x, y, draws)
    draws = draws + repeat_noise_mm(rows, post, hyper.noise_std_mm, rng, n, heights=z)
    return fl.sampled_figures(x, y, draws), dict(hyper._asdict()), plate


LINE_RATIO = fl.LINE_RATIO  # the one line test (``flatness.line_spread``)


def spans_area(x, y, path) -> None:
    """Raise RecordingError where the touches (x, y) lie on, or nearly on, one line (or at one
    point): across it a plane's tilt is not determined, and the minimum zone's planes may turn
    steep enough to hold the points by their spread across the line (1 um from 20 points 10 um
    out of straight). A strip 0.4 mm wide on 400 mm still spans an area."""
    spread, _ = fl.line_spread(x, y)
    if spread[1] <= LINE_RATIO * spread[0]:
        raise RecordingError(f"{path}: the {len(x)} fused touches lie on (or within "
                             f"{spread[1] * 1e3:.3g} um RMS of) one line or at one point "
                             "(columns x_mm, y_mm): a plane's tilt across that line and the "
                             "minimum zone are not determined; flatness needs touches spanning "
                             "an area")


def recording_flatness(path, rng: np.random.Generator, n: int) -> tuple[dict, dict, dict]:
    """Tilt, flatness figures with 95 % intervals and average ranges of one recording (JSON-ready),
    the figures of the predicted repeats (the intervals'), and those of the plate at the touches
    (for ``compare``). ``path``: the recording's path, or a Recording."""
    rec = (path if isinstance(path, Recording) else read_recording(path)).one_round("flatness")
    path = (rec.path or "the recording") if isinstance(path, Recording) else path
    x, y, z = heights(rec)
    if len(z) < 4:
        raise ValueError(f"{path}: {len(z)} usable touch{'es' * (len(z) != 1)}; flatness needs "
                         "at least 4")
    spans_area(x, y, path)
    values = fl.figures(x, y, z)
    sampled, hyper, plate = repeat_samples(x, y, z, rng, n)
    rx, ry = fl.average_ranges_mm(x, y, z)
    out = {"recording": str(path), "touches": int(len(z)),
           "tilt": tilt_with_std(x, y, z, hyper["noise_std_mm"]),
           # figures of the measured heights; a posterior median where one lies outside its
           # interval (value_is says which: analysis.flatness_answer.entry)
           "flatness_mm": {k: entry(values[k], sampled[k], MEASURED)
                           for k in NAMES},
           "flatness_mm_is": "the touched points as measured (no map: with the cell file, "
                             "--robot CELL.yaml, flatness_mm is the whole plate's)",
           # None where the touches are not a grid along that axis (the paper's method needs one)
           "average_range_mm": {"x": fl.finite_or_none(rx), "y": fl.finite_or_none(ry)},
           "noise_std_mm": hyper["noise_std_mm"], "hyper": hyper}
    return out, sampled, plate


def tilt_with_std(x, y, z, noise_std_mm: float) -> dict:
    """``flatness.plane_tilt`` of the touched points with its 1-sd spread over repeats at the
    same touches: cov(a, b) = s^2 (A^T A)^-1 of the least-squares plane (A = [x, y, 1], s the
    learned reading noise), carried to the angles by their Jacobian (central differences).
    A bare recording's tilt was printed without one (an outside audit); an audit measured the
    slopes within 2 of these sds in 37 of 40 (20 seeds)."""
    tilt = fl.plane_tilt(x, y, z)
    A = np.c_[x - np.mean(x), y - np.mean(y), np.ones(len(x))]
    cov = noise_std_mm**2 * np.linalg.inv(A.T @ A)[:2, :2]
    h = 1e-7  # slopes of order 1e-2: the central difference's round-off is far below the sd
    J = np.array([(np.array(fl.tilt_correction_deg(tilt["a"] + h * e[0], tilt["b"] + h * e[1]))
                   - np.array(fl.tilt_correction_deg(tilt["a"] - h * e[0], tilt["b"] - h * e[1])))
                  / (2 * h) for e in np.eye(2)]).T
    angles = J @ cov @ J.T
    return {**tilt, "a_std": float(np.sqrt(cov[0, 0])), "b_std": float(np.sqrt(cov[1, 1])),
            "rx_std_deg": float(np.sqrt(angles[0, 0])), "ry_std_deg": float(np.sqrt(angles[1, 1])),
            "std_is": "1 sd of the touched points' plane over repeats at the same touches (the "
                      "learned reading noise)", "plane_is": TOUCHED_PLANE_IS}


#: a bare recording's tilt.plane_is (result.json's tilt says the same of the map)
TOUCHED_PLANE_IS = ("least-squares plane z = a x + b y + c of the touched points as recorded, in "
                    "the recording's frame: a and b slopes along x and y (mm/mm), c the height at "
                    "x = y = 0 (mm); rx_deg, ry_deg the correction rotx(rx) roty(ry) (deg), "
                    "a_std, b_std (mm/mm) and *_std_deg (deg) their 1 sd (std_is)")


def touches_differ(first: Recording, second: Recording) -> dict | None:
    """{"first_only", "second_only"}: how many places of each recording (to 0.5 mm) the other
    does not hold, of its {"first_places", "second_places"}; None where they touch the same.
    Where they differ, each figure is of its own points, and a change between them is not the
    plate's alone (an outside audit, 2026-11-29: one unchanged plate read on two random designs
    came out "larger" at P(worse) >= 0.95 in 4 of 10 pairs)."""
    at = [{(round(x * 2), round(y * 2)) for x, y in zip(r.x_mm, r.y_mm)} for r in (first, second)]
    a, b = len(at[0] - at[1]), len(at[1] - at[0])
    return ({"first_only": a, "first_places": len(at[0]), "second_only": b,
             "second_places": len(at[1])} if a or b else None)


def compare(sampled_a: dict, sampled_b: dict) -> dict:
    """P(later > earlier) and the 95 % interval of the change, per figure of NAMES, from each
    round's posterior surfaces at its touches (``recording_flatness``'s third value): the
    change of the plate's figure there, the readings' noise removed. With the repeats' noise
    drawn into both rounds (until 2026-11-24) the interval was about 1.7 x too wide -- it held
    the true change 30 of 30 times and called a 50 % worsening "worse" (P > 0.95) in 11 of 30
    -- where the plate's figures hold it 28 and 29 of 30 (a worse and an unchanged pair of an
    outside auditor's generator) and call that worsening in 26 of 30."""
    return fl.compare_rounds({k: sampled_a[k] for k in NAMES}, {k: sampled_b[k] for k in NAMES})


def verdict(change: dict) -> str:
    """A figure's change in words: "larger" or "smaller" where its 95 % interval (``compare``'s
    ``diff_ci95``) excludes 0, else "within the noise"."""
    lo, hi = change["diff_ci95"]
    return "larger" if lo > 0 else "smaller" if hi < 0 else "within the noise"
