"""A thin mutable shell over the pure survey functions, for notebooks and scripts.

    survey = Survey(survey_plan(cell))
    while not survey.stop_reason():
        target = survey.ask()[0]
        told = survey.tell(target.x_mm, target.y_mm, target.z_mm, reading_mm)

Each call replaces ``survey.state`` with the new immutable state the pure function returns and
appends the status to ``survey.history``; ``survey.state`` can be kept, compared or restored.
"""
from __future__ import annotations

import numbers
import warnings

import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.prior import Hyper
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import Target, ask
from adaptive_cal.planning.disagree import READINGS_DISAGREE, Disagreements
from adaptive_cal.planning.gate import Told
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.robust import check_touch
from adaptive_cal.planning.stopping import Status

#: frozen readouts in a row that end a survey, as the run's loop ends (``run.loop.MAX_REJECTED``)
FROZEN_STOP = 3
READOUT_FROZEN = "readout_frozen"
NO_ADMISSIBLE_POINT = "no_admissible_point"  # as ``run.loop``'s


class Survey:
    """A survey in progress: ``plan`` (read-only settings), ``state`` (the latest immutable
    state) and ``history`` (the status before the first touch and after each one)."""

    def __init__(self, plan: SurveyPlan, state: sv.SurveyState | None = None, *,
                 prior: bl.Belief | None = None, hyper: Hyper | None = None):
        if not isinstance(plan, SurveyPlan):
            raise TypeError(f"plan = {plan!r:.60}: give a SurveyPlan (cell.build.survey_plan(cell)), "
                            "or use adaptive_cal.start_survey(cell)")
        self.plan = plan
        self.state = state if state is not None else sv.start(plan, prior=prior, hyper=hyper)
        self.history: list[Status] = [self.status()]
        self._same = (float("nan"), 0)  # the last reading told and how often in a row
        self._frozen = 0  # touches in a row rejected as a frozen readout
        # retakes the gate rejected in a row at one place (``planning.disagree``)
        self._disagree, self.disagreement = Disagreements(), ""
        self._asked: tuple | None = None  # (state, n, from_xy, targets): the last ask's answer
        self._mine = self.state  # the state the counters above and ``history`` belong to

    def _adopt(self) -> None:
        """A state assigned from outside (a kept one restored, a what-if undone) starts the
        frozen-readout count afresh and the history at its own touches (an outside audit: three
        what-if tells of one reading, each undone, made the fourth tell 'frozen')."""
        if self.state is not self._mine:
            self._same, self._frozen, self._mine = (float("nan"), 0), 0, self.state
            self._disagree, self.disagreement = Disagreements(), ""
            self.history[self.state.touches:] = [self.status()]

    def ask(self, n: int | None = None, *, from_xy=None) -> list[Target]:
        """The next touch(es) (``planning.ask.ask``): ``n`` of them (None: the plan's batch)."""
        if n is not None and (isinstance(n, bool) or not isinstance(n, numbers.Integral)
                              or n < 1):
            raise ValueError(f"n = {n!r}: ask for at least 1 touch (None: the plan's batch)")
        if from_xy is not None:
            from_xy = _point(from_xy, "from_xy")
        last = self._asked  # the same question of the same state: the same answer, not redone
        if last is None or last[0] is not self.state or last[1:3] != (n, from_xy):
            last = self._asked = (self.state, n, from_xy,
                                  ask(self.plan, self.state, n, from_xy=from_xy))
        return list(last[3])

    def tell(self, x_mm: float, y_mm: float, z_mm: float, reading_mm: float) -> Told:
        """Judge and fuse one reading that was taken; returns the flags for the recording.

        A reading that is the very same value for ``plan.frozen_after`` touches in a row -- all
        but impossible for a live probe given the cell's readout step and stated noise -- is a
        frozen readout (a stale serial value, a register not updated, a value typed again): it
        is not fused, the touch is counted, the flags say ``rejected``, ``frozen`` and a
        warning says why, as the run's probe cycle does; ``FROZEN_STOP`` of them in a row make
        ``stop_reason()`` ``readout_frozen``. Else the learned noise would collapse onto the
        repeats and the bands with it."""
        self._adopt()
        try:  # a float, numpy or JAX scalar (0-d); else sv.tell says why
            number = np.ndim(reading_mm) == 0 and not isinstance(reading_mm, (str, bytes, bool))
            reading = float(reading_mm) if number else float("nan")
        except (TypeError, ValueError):
            reading = float("nan")
        same = self._same[1] + 1 if reading == self._same[0] else 1
        if self.plan.frozen_after is not None and same >= self.plan.frozen_after:
            check_touch(self.plan, x_mm, y_mm, z_mm, reading, position_only=True)
            warnings.warn(f"reading {reading:.4f} mm, the very same value for {same} touches in a "
                          "row, which the cell's readout step and stated noise make all but "
                          "impossible: is the readout frozen? The touch was not fused",
                          UserWarning, stacklevel=2)
            self.state = sv.skip(self.plan, self.state, x_mm, y_mm)
            told = Told(False, ("rejected", "frozen"), float("nan"), x_mm=float(x_mm),
                        y_mm=float(y_mm), z_mm=float(z_mm))
            self._frozen += 1
        else:
            before = self.state  # what the readings held back were judged by
            self.state, told = sv.tell(self.plan, self.state, x_mm, y_mm, z_mm, reading_mm)
            self._frozen = 0
            if self._disagree.see(told):
                self.disagreement = self._disagree.text(self.plan, before)
                warnings.warn(self.disagreement, UserWarning, stacklevel=2)
        self._same, self._mine = (reading, same), self.state
        self.history.append(self.status())
        return told

    def skip(self, x_mm: float, y_mm: float) -> None:
        """Count a touch whose reading the probe cycle rejected (not fused). The position must be
        one a touch can have (finite, on the workplane, outside the keep-outs): else
        ``InvalidReading`` naming it, and nothing is counted."""
        check_touch(self.plan, x_mm, y_mm, 0.0, 0.0, position_only=True)
        self._adopt()
        self.state = self._mine = sv.skip(self.plan, self.state, x_mm, y_mm)
        self.history.append(self.status())

    def status(self) -> Status:
        """Touches, RMS and largest posterior std (mm)."""
        return sv.status(self.plan, self.state)

    def stop_reason(self) -> str | None:
        """Why the survey's stopping rule stops now, or None; ``readout_frozen`` after
        ``FROZEN_STOP`` touches in a row rejected as a frozen readout (``tell``);
        ``readings_disagree`` after two retakes in a row at one place rejected by the gate
        (``planning.disagree``; ``disagreement`` says what the readings there show);
        ``no_admissible_point`` where the rule would go on but ``ask()`` has no touch to offer
        (as the run's loop ends; the answer is kept, so the ``ask()`` after it is not redone) --
        e.g. heights told in place of readings put the plate millimetres off the probe's stroke
        (an outside audit's loop ``survey.ask()[0]`` raised IndexError there)."""
        self._adopt()
        if self._frozen >= FROZEN_STOP:
            return READOUT_FROZEN
        if self.disagreement:
            return READINGS_DISAGREE
        why = sv.stop_reason(self.plan, self.state)
        return NO_ADMISSIBLE_POINT if why is None and not self.ask() else why

    def grid(self, n: int = 61):
        """(gx, gy, mean, std) on an n x n grid over the whole plate (mm): gx, gy the grid's x
        and y (n each), mean[i, j] and std[i, j] at (gx[i], gy[j]) -- x along the first axis
        (``indexing="ij"``; transpose for an image whose rows are y). The std includes the
        unresolved structure the self-checks found, as ``status().mean_std_mm`` does."""
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 2:
            raise ValueError(f"n = {n!r}: a grid needs a whole number of at least 2 points "
                             "per side")
        return sv.grid(self.plan, self.state.belief, int(n), state=self.state)

    @property
    def belief(self) -> bl.Belief:
        """The current belief over the spline coefficients."""
        return self.state.belief

    @property
    def hyper(self) -> Hyper:
        """The hyper-parameters the next fusion uses."""
        return self.state.hyper

    @property
    def touches(self) -> int:
        """Touches made, fused or not."""
        return self.state.touches

    @property
    def touched_xy_mm(self):
        """(x, y) of every touch, fused or not, in touch order (mm)."""
        return self.state.touched_xy_mm

    @property
    def retake_pending(self) -> bool:
        """True after a gated reading: the next ask returns the same point again."""
        return self.state.retake is not None


def _point(xy, name: str) -> tuple[float, float]:
    """``xy`` as two finite floats (mm), else a ValueError naming ``name``."""
    import math

    try:
        x, y = (float(v) for v in xy)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {xy!r}: give (x_mm, y_mm), two numbers") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"{name} = {xy!r}: not finite")
    from adaptive_cal.formats.recording import MAX_ABS_POSITION_MM as far

    if max(abs(x), abs(y)) > far:  # an audit: (1e6, 1e6) mm planned a tour from 1 km away
        raise ValueError(f"{name} = {xy!r}: beyond +-{far:g} mm of the workplane's origin, "
                         "where no robot cell's probe stands (um, or another frame?)")
    return x, y
