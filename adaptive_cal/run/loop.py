"""The one ask -> touch -> judge -> record -> fuse loop, with hooks (emukit's shape: candidate
selection is ``planning.ask``, the model update ``planning.survey.fuse``, the stopping condition
a predicate, event hooks after each touch). The CLI run, the studies, the tests and the
notebooks all drive a survey through ``run_loop``.

Each touch:

1. the probe cycle touches the target (a ``TouchRejected`` touch is recorded, flagged, counted
   and never fused);
2. the gate judges the reading (pure: flags for the recording). A reading ``survey.judge``
   refuses (``InvalidReading``: NaN or infinite, off the workplane, inside a keep-out) is
   recorded flagged ``invalid;rejected`` (a non-finite value written as 0, the flag
   ``nonfinite`` saying so), counted with ``survey.skip`` and never fused; the loop goes on,
   and ends with ``INVALID_READINGS`` after ``MAX_INVALID`` such readings in a row;
3. ``record(row)`` writes it -- before anything else happens with the reading, so a crash or a
   kill during the fusion (and its refit) loses nothing that was taken;
4. the reading is fused (and the hyper-parameters refitted on schedule);
5. every hook sees the new ``Step``.

A batch is cut short after a gated reading (the retake comes first), when ``interrupt()`` says
so, or when the stop predicate fires: it is asked before each ask and after each touch, so a
batch larger than the touch budget left never makes more touches than the budget.
``loop.state`` is the latest state even when a device raises.
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

from adaptive_cal.hardware.base import ProbeCycle, ProbeLeftDown, Touch, TouchRejected
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import Target, ask
from adaptive_cal.planning.gate import Told
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.robust import InvalidReading
from adaptive_cal.planning.stopping import Status

#: the reason a loop ends when no allowed point can be promised inside the probe stroke
NO_ADMISSIBLE_POINT = "no_admissible_point"
#: the reason a loop ends after ``MAX_INVALID`` invalid readings in a row (a broken device)
INVALID_READINGS = "invalid_readings"
MAX_INVALID = 3


class Row(NamedTuple):
    """One recording row, as the loop hands it to ``record`` (mm, s)."""

    seq: int
    t_s: float
    x_mm: float
    y_mm: float
    z_mm: float
    reading_mm: float
    flags: tuple[str, ...]


class Step(NamedTuple):
    """What the hooks see after each touch: the new state and its status, the target, and
    either the touch and its judgement or the probe cycle's rejection (``invalid``: the reason
    ``survey.judge`` refused the reading, or None)."""

    state: sv.SurveyState
    status: Status
    target: Target
    touch: Touch | None
    told: Told | None
    rejected: TouchRejected | None
    invalid: InvalidReading | None = None


Hook = Callable[[Step], None]
StopPredicate = Callable[[sv.SurveyState, Status], "str | None"]


def survey_stop(plan: SurveyPlan) -> StopPredicate:
    """The survey's own stopping rule as a loop predicate."""
    return lambda state, status: plan.stop(status)


class SurveyLoop:
    """Drives one survey on a probe cycle (see module docstring). ``stop(state, status)``
    returns the reason to end or None (default: the plan's rule); ``record(row)`` writes a row
    (the recording); ``hooks`` see each step; ``interrupt()`` cuts a batch short."""

    def __init__(self, plan: SurveyPlan, state: sv.SurveyState, cycle: ProbeCycle, *,
                 stop: StopPredicate | None = None, record: Callable[[Row], None] | None = None,
                 hooks: tuple[Hook, ...] = (), interrupt: Callable[[], bool] = lambda: False):
        self.plan, self.state, self.cycle = plan, state, cycle
        self.stop = stop or survey_stop(plan)
        self.record, self.hooks, self.interrupt = record, tuple(hooks), interrupt
        self.invalid_in_a_row = 0

    def run(self) -> str:
        """Ask, touch, record and fuse until the stop predicate fires; returns its reason, or
        ``NO_ADMISSIBLE_POINT`` when the planner has no point to offer."""
        while True:
            why = self.stop(self.state, sv.status(self.plan, self.state))
            if why:
                return why
            targets = ask(self.plan, self.state, from_xy=self.cycle.motion.position()[:2])
            if not targets:
                return NO_ADMISSIBLE_POINT
            for target in targets:
                step = self.touch(target)
                if self.invalid_in_a_row >= MAX_INVALID:
                    return INVALID_READINGS
                if (step.invalid is not None or self.state.retake is not None or self.interrupt()
                        or self.stop(self.state, step.status)):
                    break  # a batch never runs past the stop rule (the touch budget included)

    def touch(self, target: Target) -> Step:
        """One touch at ``target``: taken, judged, recorded, then fused; hooks called."""
        plan = self.plan
        touch = told = rejected = invalid = None
        try:
            touch = self.cycle.touch(target.x_mm, target.y_mm, target.z_mm)
        except TouchRejected as e:
            rejected = e
            self._reject(target, e)
        except ProbeLeftDown as e:  # the tip may be down: keep what was read, then stop
            if e.touch is not None:
                try:
                    self._take(e.touch)
                except InvalidReading:
                    self._invalid(target, e.touch)
            elif isinstance(e.__cause__, TouchRejected):
                self._reject(target, e.__cause__)
            raise
        else:
            try:
                told = self._take(touch)
            except InvalidReading as e:
                invalid = e
                self._invalid(target, touch)
        self.invalid_in_a_row = self.invalid_in_a_row + 1 if invalid is not None else 0
        step = Step(self.state, sv.status(plan, self.state), target, touch, told, rejected,
                    invalid)
        for hook in self.hooks:
            hook(step)
        return step

    def _take(self, touch: Touch) -> Told:
        """Judge a reading that was taken, record it, then fuse it."""
        told = sv.judge(self.plan, self.state, touch.x_mm, touch.y_mm, touch.z_mm,
                        touch.reading_mm)
        self._record(Row(self.state.touches, touch.t_s, touch.x_mm, touch.y_mm, touch.z_mm,
                         touch.reading_mm, told.flags))
        self.state = sv.fuse(self.plan, self.state, told)
        return told

    def _invalid(self, target: Target, touch: Touch) -> None:
        """Record a reading ``survey.judge`` refused (flagged ``invalid``, never fused; a
        non-finite value is written as 0 with the flag ``nonfinite``) and count the touch at
        its target."""
        values = (touch.x_mm, touch.y_mm, touch.z_mm, touch.reading_mm)
        finite = [v if math.isfinite(v) else 0.0 for v in values]
        flags = ("invalid", "rejected") + (() if finite == list(values) else ("nonfinite",))
        t_s = touch.t_s if math.isfinite(touch.t_s) else self.cycle.clock()
        self._record(Row(self.state.touches, t_s, *finite, flags))
        self.state = sv.skip(self.plan, self.state, target.x_mm, target.y_mm)

    def _reject(self, target: Target, e: TouchRejected) -> None:
        """Record a touch the probe cycle rejected (flagged, never fused) and count it."""
        reading = e.reading_mm if math.isfinite(e.reading_mm) else 0.0
        self._record(Row(self.state.touches, self.cycle.clock(), target.x_mm, target.y_mm,
                         target.z_mm, reading, tuple(e.flags)))
        self.state = sv.skip(self.plan, self.state, target.x_mm, target.y_mm)

    def _record(self, row: Row) -> None:
        if self.record is not None:
            self.record(row)


def run_loop(plan: SurveyPlan, state: sv.SurveyState, cycle: ProbeCycle, **options
             ) -> tuple[sv.SurveyState, str]:
    """``SurveyLoop(plan, state, cycle, **options).run()``: the final state and the reason."""
    loop = SurveyLoop(plan, state, cycle, **options)
    reason = loop.run()
    return loop.state, reason


class History:
    """A hook keeping the status before the first touch and after each touch, and the touch
    counts at which the hyper-parameters were refitted (the std may jump there)."""

    def __init__(self, first: Status, fitted_at: int = 0):
        self.statuses: list[Status] = [first]
        self.refits: list[int] = []
        self._fitted_at = fitted_at

    def __call__(self, step: Step) -> None:
        self.statuses.append(step.status)
        if step.state.fitted_at != self._fitted_at:
            self._fitted_at = step.state.fitted_at
            self.refits.append(step.status.touches)
