"""Touches that do not span an area: on one line, or nearly so, the tilt across the line is not
determined (a plane fitted to them turns about the line by whatever the noise says: 87 deg from
72 touches on y = x / 2), so explain refuses them, as ``flatness`` does.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.analysis.flatness import LINE_RATIO, line_spread  # flatness's own test
from adaptive_cal.formats.recording import RecordingError


def _line(x0: float, y0: float, dx: float, dy: float) -> str:
    """The line through (x0, y0) along (dx, dy), as y = s x + c or x = s y + c (mm)."""
    dx, dy = float(dx), float(dy)
    num = lambda v: f"{v:.4g}" if abs(v) >= 1e-9 else "0"
    if abs(dy) <= abs(dx):
        s, c = dy / dx, y0 - dy / dx * x0
        lhs, var = "y", "x"
    else:
        s, c = dx / dy, x0 - dx / dy * y0
        lhs, var = "x", "y"
    if abs(s) < 1e-9:
        return f"{lhs} = {num(c)}"
    c = round(float(c), 4)
    slope = {1.0: "", -1.0: "-"}.get(round(s, 9), f"{num(s)} ")
    return f"{lhs} = {slope}{var}" + (f" {'+-'[c < 0]} {num(abs(c))}" if c else "")


def refuse_one_line(x_mm, y_mm, label: str) -> None:
    """Raise RecordingError naming the line (or the point) where the touches (x, y) lie on one
    line or nearly: their RMS distance from it at most ``LINE_RATIO`` x their RMS spread
    along it (flatness's test)."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    xm, ym = float(x.mean()), float(y.mean())
    spread, vt = line_spread(x, y)
    if spread[1] > LINE_RATIO * spread[0]:
        return
    points = np.unique(np.c_[x, y], axis=0)
    if spread[0] == 0.0:
        where, across = f"all lie at one point ({xm:g}, {ym:g})", "the tilt"
    else:
        line, across = _line(xm, ym, *vt[0]), "the tilt across that line"
        # within round-off of the line (positions written to a few decimals): on it
        on = ("on" if spread[1] <= 1e-9 * spread[0] else
              f"within {spread[1] * 1e3:.3g} um RMS of")
        where = f"lie {on} the line {line}"
        if len(points) == 2:
            (x1, y1), (x2, y2) = points
            where = f"lie at two points only, ({x1:g}, {y1:g}) and ({x2:g}, {y2:g}), on {line}"
    raise RecordingError(
        f"{label}: the {len(x)} fused touches {where} (columns x_mm, y_mm): {across} cannot be "
        "calibrated; explain needs touches spanning an area (not all on one line)")
