"""The largest gap the touches leave: the point a touch may go to farthest from every touch, and
that distance -- the fill distance of the touches over the allowed plate (Wendland 2005, ch. 1:
the radius of the largest disc around an allowed point that holds no touch).

A feature narrower than it -- a dent, a burr, a chip -- can lie there unseen: the spline's bands
and the self-checks see only what lands on a touch. ``plan.stop.max_gap_mm`` holds a variance
bound back until the gap is at most that radius; the planner then touches the gap's centre
(``planning.ask``), a farthest-point (Gonzalez 1985) fill.
"""
from __future__ import annotations

import numpy as np


def largest_gap(candidates_xy, touched_xy) -> tuple[float, int]:
    """(radius in mm, index of the candidate at the gap's centre) over ``candidates_xy`` (N, 2),
    the points a touch may go to; (inf, -1) without touches, (0, -1) without candidates."""
    from scipy.spatial import cKDTree

    cand = np.asarray(candidates_xy, dtype=np.float64).reshape(-1, 2)
    xy = np.asarray(touched_xy, dtype=np.float64).reshape(-1, 2)
    if len(cand) == 0:
        return 0.0, -1
    if len(xy) == 0:
        return float("inf"), -1
    d, _ = cKDTree(xy).query(cand)
    i = int(np.argmax(d))
    return float(d[i]), i
