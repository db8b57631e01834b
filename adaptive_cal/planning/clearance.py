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
from dataclasses import dataclass, field

import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.scoring import STROKE_Z
from adaptive_cal.planning.survey import SurveyState

STEP_MM = 5.0  # samples along a travel at most this far apart


def plate_top_mm(plan: SurveyPlan, state: SurveyState, from_xy, to_xy) -> float:
    """The highest the plate may stand (mm, the robot's z) on the straight line from
    ``from_xy`` to ``to_xy`` (from the target alone where ``from_xy`` is not known)."""
    return top_under(plan, state.belief, from_xy, to_xy)


def top_under(plan: SurveyPlan, belief: bl.Belief, from_xy, to_xy) -> float:
    """``plate_top_mm`` under ``belief``."""
    b = np.asarray(to_xy, float)[:2]
    a = np.asarray(from_xy, float)[:2] if from_xy is not None else b
    if not np.all(np.isfinite(a)):
        a = b
    n = max(2, int(math.ceil(float(np.hypot(*(b - a))) / STEP_MM)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    (x0, x1), (y0, y1) = plan.plate_mm
    xy = a + t * (b - a)
    x, y = np.clip(xy[:, 0], x0, x1), np.clip(xy[:, 1], y0, y1)
    mean, var = bl.predict(belief, plan.model.surface.basis(x, y))
    return float(np.max(np.asarray(mean) + STROKE_Z * np.sqrt(np.asarray(var))))


def highest_mm(plan: SurveyPlan, belief: bl.Belief) -> float:
    """The highest the plate may stand anywhere on it under ``belief`` (mm): mean + z* sd over
    the plan's evaluation grid (the dry run's travel line)."""
    mean, var = bl.predict(belief, plan.model.surface.basis(*plan.eval_xy.T))
    return float(np.max(np.asarray(mean) + STROKE_Z * np.sqrt(np.asarray(var))))


@dataclass
class Guard:
    """Where else the plate may stand: a re-check's earlier belief in the frames it did not
    assume (``run.recheck.load_prior``, ``recheck_guard``: a correction assumed applied but
    not, or applied but not assumed). The belief alone puts the plate where the frame assumed
    says, trusted to micrometres; in another frame it can stand millimetres higher (an outside
    safety audit, 2026-11-29: 2 deg about an origin 525 mm away, the first touch 13 mm past the
    stroke's end).

    Until readings refute a frame, the probe cycle travels clear of it too (``top_mm``) and
    approaches from above it (``approaches``): the first approach puts that frame's plate
    mid-stroke, each next one ``STEP`` of the usable stroke lower, down to the belief's own,
    and the first that reads inside the stroke is the touch. A step reads at most ``STEP`` of
    the stroke above its bottom: none can overrun. A frame is refuted by ``REFUTE`` readings it
    would have put off the usable stroke and that lie where the frame assumed puts the plate
    (within a quarter of the usable stroke of ``assumed``: readings that agree with no frame
    refute none, an outside audit) (``seen``); then it costs nothing more.

    Beside the frames, ``safety``: the cell's own prior, told every reading inside the stroke
    -- where the plate may stand whatever was applied, as far as the cell file says (a third
    frame: a guard audit's re-check overran the stroke there). A plate outside it too (a sign
    flipped on a plate 525 mm from the origin: 18 mm off at its centre, against an offset prior
    of 0.5 mm) is not covered, as a run from scratch is not. It is what keeps a run
    from scratch inside the stroke: its touches are chosen where that prior promises the stroke
    (``scoring.stroke_ok``), a re-check's where the earlier map does. Its top (mean + z* sd)
    is cleared and approached from above like a frame's, as far as the workspace box reaches
    (``soft_top_mm``, ``approaches``: the box is where the user lets the probe work; a frame's
    plate above it is refused, the prior's is not); after a few readings spread over the plate
    it lies within micrometres of the plate and costs nothing more."""

    plan: SurveyPlan
    frames: list  # Beliefs: the earlier run's belief in each frame not assumed
    said: str = "a frame not assumed"  # for messages: which frame the guard keeps clear of
    assumed: object = None  # the Belief of the frame assumed (None: every reading counts)
    safety: object = None  # the cell's own prior, told each reading (None: frames alone)
    noise_var_mm2: float = 1e-4  # the safety belief's reading variance, (10 um)^2: ample
    refuted: list = field(default_factory=list)  # per frame: readings it would put off-stroke

    STEP = 0.75  # each step down: this share of the usable stroke
    REFUTE = 3

    def __post_init__(self):
        self.refuted = [0] * len(self.frames)

    def live(self) -> list:
        return [f for f, n in zip(self.frames, self.refuted) if n < self.REFUTE]

    def bounds(self) -> list:
        """The live frames, and the safety belief."""
        return self.live() + ([self.safety] if self.safety is not None else [])

    @property
    def z_cap_mm(self) -> float:
        """The workspace box's top (inf without a box)."""
        return self.plan.z_range_mm[1] if self.plan.z_range_mm is not None else math.inf

    def top_mm(self, from_xy, to_xy) -> float:
        """The highest the plate may stand along the travel under a live frame (-inf: none)."""
        return max((top_under(self.plan, f, from_xy, to_xy) for f in self.live()),
                   default=-math.inf)

    def soft_top_mm(self, from_xy, to_xy) -> float:
        """The same under the safety belief (-inf: none); the travel clears it as far as the
        workspace box reaches."""
        return (top_under(self.plan, self.safety, from_xy, to_xy) if self.safety is not None
                else -math.inf)

    def approaches(self, x_mm: float, y_mm: float, z_mm: float) -> list[float]:
        """Approach heights, highest first, ending at ``z_mm`` (the belief's): one where no
        live frame's plate nor the safety belief's (mean + z* sd) would read past the usable
        stroke's top from z_mm. The first puts a frame's plate mid-stroke, or the safety
        belief's top."""
        lo, hi = self.plan.usable_mm
        basis = self.plan.model.surface.basis(np.array([x_mm]), np.array([y_mm]))
        top, high = -math.inf, -math.inf
        for f in self.bounds():
            mean, var = (float(v[0]) for v in bl.predict(f, basis))
            here = mean + STROKE_Z * math.sqrt(max(var, 0.0))
            if f is self.safety:  # no higher than a step the box lets the probe make
                here = min(here, self.z_cap_mm - self.plan.zero_mm + 0.5 * (lo + hi))
            top = max(top, here)
            high = max(high, self.plan.approach_height(here if f is self.safety else mean))
        if top - z_mm + self.plan.zero_mm <= hi or high <= z_mm:
            return [z_mm]
        step = self.STEP * (hi - lo)
        n = int(math.ceil((high - z_mm) / step))
        return [high - k * step for k in range(n)] + [z_mm]

    def seen(self, x_mm: float, y_mm: float, z_mm: float, reading_mm: float) -> None:
        """A reading inside the stroke (others are ignored): each frame that would have put
        it off the usable stroke counts one more towards its refutation."""
        lo, hi = self.plan.usable_mm
        if not lo <= reading_mm <= hi:
            return
        height = reading_mm + z_mm - self.plan.zero_mm
        basis = self.plan.model.surface.basis(np.array([x_mm]), np.array([y_mm]))
        if self.safety is not None:
            self.safety = bl.fuse_step(self.safety, basis[0], height, self.noise_var_mm2)
        if self.assumed is not None and \
                abs(height - float(bl.predict(self.assumed, basis)[0][0])) > 0.25 * (hi - lo):
            return  # where no frame puts the plate: it refutes none
        for k, f in enumerate(self.frames):
            mean = float(bl.predict(f, basis)[0][0])
            if abs(height - mean) > 0.5 * (hi - lo):
                self.refuted[k] += 1
