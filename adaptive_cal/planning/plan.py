"""The survey plan: everything the engine reads from a cell file, as plain values, read once.

``adaptive_cal.cell.build.survey_plan(cell)`` makes it at the edge; the planning functions only
read its fields. Following one config key (``probe.usable_mm``, ``plan.stop.mean_std_mm``) from
the command line to the planner: cli -> cell.schema (validated) -> cell.build (into this value)
-> planning (reads the field).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from adaptive_cal.gaussian.prior import PriorModel
from adaptive_cal.planning.scoring import Candidates
from adaptive_cal.planning.stopping import StopRule

Interval = tuple[float, float]
LOOKAHEAD = 64


@dataclass(frozen=True, eq=False)
class SurveyPlan:
    """The settings of one survey (units in the names; mm unless said otherwise).

    ``model``: spline and prior; ``candidates``: points a touch may go to and their rows;
    ``gram``: Q of J(C) = trace(Q C); ``eval_xy``/``eval_rows``: the evaluation grid over the
    whole plate (status, results); ``usable_mm``/``zero_mm``: the probe's usable stroke and the
    indication at the commanded height; ``z_range_mm``: the workspace box's z range, or None;
    ``allows(x, y)``: inside the edge margin and outside every keep-out; ``bounds_mm``: the
    refinement box ((x0, x1), (y0, y1)) inside the edge margin; ``plate_mm``: the workplane's
    extent ((x0, x1), (y0, y1)); ``gate_sigma``: the Mahalanobis gate; ``learn``: refit the
    hyper-parameters (``hyper_after`` readings first, then every ``hyper_every``);
    ``criterion``: ``integrated`` or ``max`` (resolved); ``refine``: best candidates refined
    by gradient steps (0: none); ``batch``: touches planned per ask; ``stop``: the composed
    stopping rule; ``speed_mm_per_s``/``touch_time_s``: the robot's travel speed and the time
    of one touch, which price a touch at t = touch_time_s + distance / speed_mm_per_s from
    where the probe is (``start_xy_mm`` before the first touch); ``time_aware``: choose by
    the drop of J per second of robot time (False: by the drop of J alone); ``lookahead``: with
    ``time_aware``, one touch asked for is the first of a batch of this many planned ahead and
    ordered for travel (receding horizon; 1: the best touch per second alone), or the rest of
    the touch budget where the bound is out of reach and that is at most twice the touches
    made (``planning.ask``);
    ``min_spacing_mm``: once the self-checks found structure finer than the knots, no touch is
    planned closer than this to an earlier one while points further away are allowed (0: off;
    ``planning.ask.kept_apart``); ``closure``: when a variance bound stops the run, touch the
    first place again to see a drift (``planning.closure``, ``run.loop``); ``max_gap_mm``: a
    bound stops the run only once no allowed point is farther than this from a touch, and the
    planner touches the largest gap while only that holds the stop back (``planning.gap``);
    ``frozen_after``: touches in a row with the very same reading that mark the readout frozen
    (``hardware.base.frozen_after`` of the probe's readout step and stated noise; None: no
    check), for the library's ``Survey.tell`` -- the run's probe cycle makes its own check."""

    model: PriorModel
    candidates: Candidates
    gram: np.ndarray
    eval_xy: np.ndarray
    eval_rows: np.ndarray
    usable_mm: Interval
    zero_mm: float
    z_range_mm: Interval | None
    allows: Callable[[float, float], bool]
    bounds_mm: tuple[Interval, Interval]
    plate_mm: tuple[Interval, Interval]
    gate_sigma: float
    learn: bool
    hyper_after: int
    hyper_every: int
    criterion: str
    refine: int
    batch: int
    stop: StopRule
    # self-checks (planning.adequacy): the probe's stated noise span [lo, hi] (mm) or None, and
    # the grid of regions the plate is split into to say where the model is inadequate
    noise_range_mm: Interval | None = None
    adequacy_regions: tuple[int, int] = (3, 3)
    # a model that grows: the unit covariance (K x K) of structure finer than the coarse knots
    # on the refined knots of ``model`` (whose form lives on ``model.coarse``), or None
    growth: np.ndarray | None = None
    speed_mm_per_s: float = 100.0
    touch_time_s: float = 3.0
    start_xy_mm: tuple[float, float] = (0.0, 0.0)
    time_aware: bool = True
    lookahead: int = LOOKAHEAD
    min_spacing_mm: float = 0.0
    max_gap_mm: float | None = None  # a bound stops only once no gap is wider (``planning.gap``)
    closure: bool = False
    frozen_after: int | None = None
    # (x, y) inside a keep-out, the edge margin aside; None: judged by ``allows`` alone
    kept_out: Callable[[float, float], bool] | None = None

    @property
    def coefficients(self) -> int:
        """K, the number of spline coefficients."""
        return self.model.surface.size

    def here_xy_mm(self, touched_xy_mm) -> np.ndarray:
        """Where the probe is: the last touched point, or the start before the first touch."""
        return np.asarray(touched_xy_mm[-1] if len(touched_xy_mm) else self.start_xy_mm, float)

    def approach_height(self, mean_mm):
        """Reference height z putting the expected reading mid-way in the usable stroke:
        z = mean - (lo + hi) / 2 + zero (mm)."""
        lo, hi = self.usable_mm
        return mean_mm + self.zero_mm - 0.5 * (lo + hi)

    def z_allowed(self, z_mm) -> np.ndarray:
        """Whether approach heights ``z_mm`` lie inside the workspace box's z range (every one
        does without a box): the one check of the candidates, a refined pick and the closure."""
        z = np.asarray(z_mm, float)
        if self.z_range_mm is None:
            return np.ones(z.shape, bool)
        return (z >= self.z_range_mm[0]) & (z <= self.z_range_mm[1])
