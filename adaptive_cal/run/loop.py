"""The one ask -> touch -> judge -> record -> fuse loop, with hooks (emukit's shape: candidate
selection is ``planning.ask``, the model update ``planning.survey.fuse``, the stopping condition
a predicate, event hooks after each touch). The CLI run, the studies, the tests and the
notebooks all drive a survey through ``run_loop``.

Each touch:

1. the probe cycle touches the target (a ``TouchRejected`` touch is recorded, flagged, counted
   and never fused; ``MAX_REJECTED`` in a row end the loop with ``TOUCHES_REJECTED``);
2. the gate judges the reading (pure: flags for the recording). A reading ``survey.judge``
   refuses (``InvalidReading``: NaN or infinite, off the workplane, inside a keep-out) is
   recorded flagged ``invalid;rejected`` (a non-finite value written as 0, the flag
   ``nonfinite`` saying so), counted with ``survey.skip`` and never fused; the loop goes on,
   and ends with ``INVALID_READINGS`` after ``MAX_INVALID`` such readings in a row;
3. ``record(row)`` writes it -- before anything else happens with the reading, so a crash or a
   kill during the fusion (and its refit) loses nothing that was taken;
4. the reading is fused (and the hyper-parameters refitted on schedule);
5. every hook sees the new ``Step``.

A batch is cut short after a gated reading (the retake first), at ``interrupt()``, when a met
bound waits for repeats (``planning.repeats``) or the stop predicate fires: asked before each ask
and after each touch, so a batch never makes more touches than the budget left. ``loop.state`` is
the latest state even when a device raises. Travels clear the plate (``planning.clearance``).

The closure touch (``plan.closure``, ``planning.closure``): at a stop on a bound the first place
is touched again (retaken if gated; confirmed if one reading alarms), flagged ``closure``, fused,
judged into ``state.closure``. A drift ends the loop with ``DRIFT``; else it stops as the
predicate says (or goes on if the repeat moved the status off the bound; a later stop closes
again ``CLOSURE_GAP`` touches on). Never past the budget: where no bound stopped the run first,
the closure comes with two touches left, the last for a retake."""
from __future__ import annotations

import math
from dataclasses import replace
from functools import partial
from typing import Callable, NamedTuple

import numpy as np

from adaptive_cal.formats.recording import surface_height_mm
from adaptive_cal.gaussian.places import positions_mm
from adaptive_cal.hardware.base import ProbeLeftDown, Touch, TouchRejected
from adaptive_cal.hardware.cycle import ProbeCycle
from adaptive_cal.planning import closure as cl
from adaptive_cal.planning import closure_noise
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import Target, ask, target as target_at
from adaptive_cal.planning.clearance import plate_top_mm  # the travel's height over the plate
from adaptive_cal.planning.disagree import READINGS_DISAGREE, Disagreements
from adaptive_cal.planning.gate import Told
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.robust import InvalidReading
from adaptive_cal.planning.shell import READOUT_FROZEN  # the stop for repeats (frozen_after)
from adaptive_cal.planning.stopping import Status, touches_left, waits_for_repeats

#: the reason a loop ends when no allowed point can be promised inside the probe stroke
NO_ADMISSIBLE_POINT = "no_admissible_point"
#: the reason a loop ends after ``MAX_INVALID`` invalid readings in a row (a broken device)
INVALID_READINGS, MAX_INVALID = "invalid_readings", 3
#: ... after ``MAX_REJECTED`` touches in a row the probe cycle rejected (stroke end, spread):
#: they teach the planner nothing, so it would ask the same touch again and again
TOUCHES_REJECTED, MAX_REJECTED = "touches_rejected", 3
#: the reason a loop ends when its closure touch found the cell drifting
DRIFT = cl.DRIFT
#: the stop reasons that close with a closure touch (a variance bound met)
CLOSING = ("mean_std_bound", "max_std_bound")
CLOSURE_GAP = 10  # touches after a closure before a later stop closes again


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
    """What the hooks see after each touch: the new state, its status, the target, and the
    touch and its judgement or the cycle's rejection (``invalid``: why it was refused, or None)."""

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
                 hooks: tuple[Hook, ...] = (), interrupt: Callable[[], bool] = lambda: False,
                 fused_t_s=None):
        self.plan, self.state, self.cycle = plan, state, cycle
        self.stop = stop or survey_stop(plan)
        self.record, self.hooks, self.interrupt = record, tuple(hooks), interrupt
        self.invalid_in_a_row = 0
        self.rejected_in_a_row = 0
        # retakes the gate rejected in a row at one place, and what they show once they stop it
        self.disagree, self.disagreement = Disagreements(), ""
        # the time (s) of each fused reading, for the closure's elapsed time (resume: from the
        # recording; NaN where unknown)
        self.fused_t_s = (list(map(float, fused_t_s)) if fused_t_s is not None
                          else [math.nan] * state.fused)
        self.closed_at: int | None = None

    def run(self) -> str:
        """Ask, touch, record and fuse until the stop predicate fires; returns its reason,
        ``DRIFT`` when the closure touch found a drift, or ``NO_ADMISSIBLE_POINT`` when the
        planner has no point to offer."""
        while True:
            why = self.stop(self.state, sv.status(self.plan, self.state))
            if (why and self._closes(why)) or (not why and self._last_touch()):
                closure = self.close()
                if closure.made and not closure.passed:
                    return DRIFT
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
                if self.rejected_in_a_row >= MAX_REJECTED:
                    return READOUT_FROZEN if "frozen" in step.rejected.flags else TOUCHES_REJECTED
                if step.told is not None and self.disagree.see(step.told):
                    self.disagreement = self.disagree.text(self.plan, self.state)
                    return READINGS_DISAGREE
                owed = waits_for_repeats(self.plan.stop, step.status)
                if (step.invalid is not None or self.state.retake is not None or self.interrupt()
                        or owed or self.stop(self.state, step.status) or self._last_touch()):
                    break  # a batch never runs past the stop rule, nor past repeats a bound owes

    def _closes(self, why: str) -> bool:
        """A closure touch is due: the plan asks for one, a variance bound stopped the loop,
        a reading was fused, the touch budget is not spent and no closure was made in the last
        ``CLOSURE_GAP`` touches."""
        touches = self.state.touches
        left = touches_left(self.plan.stop, touches)
        return (self.plan.closure and why in CLOSING and self.state.fused > 0
                and (left is None or left > 0)
                and (self.closed_at is None or touches - self.closed_at >= CLOSURE_GAP))

    def _last_touch(self) -> bool:
        """Two touches left (or one, where two could not) and no closure made: the closure now,
        the last touch for its retake or confirmation (a run its bound never stopped -- checks
        that fail, a bound out of reach -- still learns whether the cell drifted; a closure on
        the very last touch could not retake a gated repeat nor confirm an alarm)."""
        return (self.plan.closure and self.closed_at is None and self.state.fused > 0
                and self.state.retake is None
                and touches_left(self.plan.stop, self.state.touches) in (1, 2))

    def close(self) -> cl.Closure:
        """The closure touch (module docstring): the first place touched again (and its
        retake when the gate owes one), judged by ``planning.closure.judge``; the verdict is
        kept in ``state.closure`` and returned."""
        plan, state = self.plan, self.state
        self.closed_at = state.touches
        i = cl.first_place(state.fused_weights)
        if i is None:
            return self._closed(cl.Closure(False, why="every one of the first readings was "
                                           "flagged an outlier"))
        xy = positions_mm(plan.model.surface, state.rows[:cl.FIRST_OF])
        x, y = (float(v) for v in xy[i])
        first = next((k for k, p in enumerate(state.touched_xy_mm)
                      if math.hypot(p[0] - x, p[1] - y) < 1e-6), -1)
        if first >= 0:  # the place as touched: the rows give it back with round-off, and an
            # edge-margin touch's y = 10 came back 9.999999999999993, which the safety check
            # refuses (an audit's corner-origin plate: the run stopped there)
            x, y = (float(v) for v in state.touched_xy_mm[first])
        start = cl.start_cluster(state.fused_weights, xy, i)
        first_rows, first_mm = state.rows[start].copy(), state.heights_mm[start].copy()
        first_t = self.fused_t_s[i] if i < len(self.fused_t_s) else math.nan
        target = target_at(plan, state, x, y)
        if not plan.z_allowed(target.z_mm):
            return self._closed(cl.Closure(False, x_mm=x, y_mm=y, first_touch=first,
                                           why=f"its approach height {target.z_mm:.3f} mm is "
                                               "outside the workspace box; nothing was sent"))
        taken = self._repeat(target)
        keep, why = cl.repeats_to_judge([k[4] for k in taken])
        if why:
            return self._closed(cl.Closure(False, x_mm=x, y_mm=y, first_touch=first,
                                           repeat_touches=tuple(k[2] for k in taken), why=why))
        kept = [taken[k] for k in keep]
        verdict = self._judge(kept, start, first_rows, first_mm, first_t, x, y, first)
        left = touches_left(plan.stop, self.state.touches)
        if verdict.made and not verdict.passed and len(kept) == 1 and (left is None or left > 0):
            # one reading says drift: confirm it before the run ends as no result (a misreading
            # the gate let through is then averaged with a good one; a drift reads the same)
            more = self._repeat(target_at(plan, self.state, x, y))
            keep, why = cl.repeats_to_judge([k[4] for k in more])
            if more and not why:
                verdict = self._judge(kept + [more[k] for k in keep], start, first_rows,
                                      first_mm, first_t, x, y, first)
        return self._closed(verdict)

    def _repeat(self, target: Target) -> list[tuple]:
        """One touch at the closure's place and its retake when the gate owes one (and a touch
        is left): [(basis row, height, seq, t_s, Told)] of the readings taken."""
        plan, taken = self.plan, []
        for _ in range(2):
            seq = self.state.touches
            step = self.touch(target, extra=(cl.FLAG,))
            if step.touch is None or step.invalid is not None:
                break
            t = step.touch
            taken.append((plan.model.surface.basis(np.array([t.x_mm]), np.array([t.y_mm]))[0],
                          surface_height_mm(t.reading_mm, t.z_mm, plan.zero_mm), seq,
                          float(t.t_s), step.told))
            if self.state.retake is None or touches_left(plan.stop, self.state.touches) == 0:
                break
            target = ask(plan, self.state)[0]
        return taken

    def _judge(self, kept, start, first_rows, first_mm, first_t, x, y, first) -> cl.Closure:
        """``planning.closure.judge`` of the kept repeat readings against the start, on the
        noise relearned without the drift they read where it can be (``closure_noise``)."""
        rows, heights, seqs, times = ([k[i] for k in kept] for i in range(4))
        elapsed = times[-1] - first_t if math.isfinite(times[-1] - first_t) else None
        return closure_noise.judged(self.plan, self.state, self.fused_t_s, start, first_rows,
                                    first_mm, rows, heights, times, x_mm=x, y_mm=y,
                                    first_touch=first, repeat_touches=tuple(seqs),
                                    elapsed_s=elapsed)

    def _closed(self, closure: cl.Closure) -> cl.Closure:
        self.state = replace(self.state, closure=closure)
        return closure

    def touch(self, target: Target, extra: tuple[str, ...] = ()) -> Step:
        """One touch at ``target``: taken, judged, recorded (its flags and ``extra``), then
        fused; hooks called."""
        plan = self.plan
        touch = told = rejected = invalid = None
        try:
            touch = self.cycle.touch(target.x_mm, target.y_mm, target.z_mm, partial(
                plate_top_mm, plan, self.state, to_xy=(target.x_mm, target.y_mm)))
        except TouchRejected as e:
            rejected = e
            self._reject(target, e, extra)
        except ProbeLeftDown as e:  # the tip may be down: keep what was read, then stop
            if e.touch is not None:
                try:
                    self._take(e.touch, extra)
                except InvalidReading:
                    self._invalid(target, e.touch, extra)
            elif isinstance(e.__cause__, TouchRejected):
                self._reject(target, e.__cause__, extra)
            raise
        else:
            try:
                told = self._take(touch, extra)
            except InvalidReading as e:
                invalid = e
                self._invalid(target, touch, extra)
        self.invalid_in_a_row = self.invalid_in_a_row + 1 if invalid is not None else 0
        self.rejected_in_a_row = self.rejected_in_a_row + 1 if rejected is not None else 0
        step = Step(self.state, sv.status(plan, self.state), target, touch, told, rejected,
                    invalid)
        for hook in self.hooks:
            hook(step)
        return step

    def _take(self, touch: Touch, extra: tuple[str, ...] = ()) -> Told:
        """Judge a reading that was taken, record it, then fuse it. Cut short while judged (a
        second Ctrl-C), it is recorded ``cut;rejected`` -- kept, not fused -- then re-raised."""
        try:
            told = sv.judge(self.plan, self.state, touch.x_mm, touch.y_mm, touch.z_mm,
                            touch.reading_mm)
        except InvalidReading:
            raise  # the caller records it flagged invalid
        except BaseException:
            self._record(Row(self.state.touches, touch.t_s, touch.x_mm, touch.y_mm, touch.z_mm,
                             touch.reading_mm, ("cut", "rejected") + extra))
            raise
        self._record(Row(self.state.touches, touch.t_s, touch.x_mm, touch.y_mm, touch.z_mm,
                         touch.reading_mm, told.flags + extra))
        self.state = sv.fuse(self.plan, self.state, told)
        if told.fused:
            self.fused_t_s.append(float(touch.t_s))
        return told

    def _invalid(self, target: Target, touch: Touch, extra: tuple[str, ...] = ()) -> None:
        """Record a reading ``survey.judge`` refused (flagged ``invalid``, never fused; a
        non-finite value is written as 0 with the flag ``nonfinite``) and count the touch at
        its target."""
        values = (touch.x_mm, touch.y_mm, touch.z_mm, touch.reading_mm)
        finite = [v if math.isfinite(v) else 0.0 for v in values]
        flags = ("invalid", "rejected") + (() if finite == list(values) else ("nonfinite",)) \
            + extra
        t_s = touch.t_s if math.isfinite(touch.t_s) else self.cycle.clock()
        self._record(Row(self.state.touches, t_s, *finite, flags))
        self.state = sv.skip(self.plan, self.state, target.x_mm, target.y_mm)

    def _reject(self, target: Target, e: TouchRejected, extra: tuple[str, ...] = ()) -> None:
        """Record a touch the probe cycle rejected (flagged, never fused; a NaN as 0, flagged
        ``nonfinite`` as ``_invalid`` does; z: the step it was read at) and count it."""
        ok, t, z = math.isfinite(e.reading_mm), target, e.z_mm
        self._record(Row(self.state.touches, self.cycle.clock(), t.x_mm, t.y_mm,
                         t.z_mm if z is None else z, e.reading_mm if ok else 0.0,
                         tuple(dict.fromkeys((*e.flags, *(() if ok else ("nonfinite",)), *extra)))))
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
