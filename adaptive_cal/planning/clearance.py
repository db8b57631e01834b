"""How high the plate may stand under a travel: the probe's free tip reaches ``zero_mm - rest_mm``
below the commanded height, so a travel at ``robot.safe_height_mm`` drags it over any part of the
plate higher than that. On a tilted or large plate the plate itself can stand there (an outside
audit, 2026-11-29: a 1 m plate at 1.2 deg read up to 0.33 mm of indication during travel at the
safe height, a 5.7 deg one had its approaches above the safe height and travelled with the probe
pushed 5 mm into its stroke, and every run ended on its bound without a word).

``plate_top_mm`` is the highest the plate may stand along a straight travel, ends included,
under the belief: the largest mean + z* sd over samples ``STEP_MM`` apart, z* the stroke
constraint's (a surface above it has probability below 1e-6, ``scoring.STROKE_Z``); the probe
cycle lifts the travel to at least that + the tip's reach + ``hardware.base.CLEARANCE_MM``.
Samples beyond the workplane are taken at its edge (the belief says nothing of what stands
beyond it). The variance of structure finer than the knots is left out: micrometres against a
clearance of a millimetre.
"""
from __future__ import annotations

import math

import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.scoring import STROKE_Z
from adaptive_cal.planning.survey import SurveyState

STEP_MM = 5.0  # samples along a travel at most this far apart


def plate_top_mm(plan: SurveyPlan, state: SurveyState, from_xy, to_xy) -> float:
    """The highest the plate may stand (mm, the robot's z) on the straight line from
    ``from_xy`` to ``to_xy`` (from the target alone where ``from_xy`` is not known)."""
    b = np.asarray(to_xy, float)[:2]
    a = np.asarray(from_xy, float)[:2] if from_xy is not None else b
    if not np.all(np.isfinite(a)):
        a = b
    n = max(2, int(math.ceil(float(np.hypot(*(b - a))) / STEP_MM)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    (x0, x1), (y0, y1) = plan.plate_mm
    xy = a + t * (b - a)
    x, y = np.clip(xy[:, 0], x0, x1), np.clip(xy[:, 1], y0, y1)
    mean, var = bl.predict(state.belief, plan.model.surface.basis(x, y))
    return float(np.max(np.asarray(mean) + STROKE_Z * np.sqrt(np.asarray(var))))
