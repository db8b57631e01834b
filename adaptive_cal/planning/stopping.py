"""Stopping rules: each returns the reason to stop or None; compose with | (any) and & (all).

A variance bound never stops a survey whose model is known to be inadequate
(``Status.adequate`` False, see ``planning.adequacy``): only the touch budget stops it then.
Nor one that owes repeat touches (``Status.repeats_owed``, see ``planning.repeats``)."""
from __future__ import annotations

import abc
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Status:
    """What the stopping rules look at."""

    touches: int
    mean_std_mm: float  # RMS posterior std over the plate: sqrt(trace(Q C) / area)
    max_std_mm: float  # largest posterior std on the evaluation grid
    adequate: bool = True  # the model's self-checks pass (or have nothing to check)
    unresolved_rms_mm: float = 0.0  # structure finer than the spline, included in the stds
    gap_mm: float = 0.0  # the largest gap between touches (``planning.gap``; 0: not asked for)
    repeats_owed: int = 0  # repeat touches a bound waits for (``planning.repeats``)


#: a learning survey refits before its schedule once its stds come within this factor of a
#: bound (``near``): the last refit's hyper-parameters, learned from fewer readings, tend to
#: hold the stds up (a dent plate read 4.51 um RMS std against its 4 um bound where a refit
#: of the same readings read 3.80: two touches more, benchmarks/plates)
NEAR = 1.25


def near(rule: "StopRule", status: Status, factor: float = NEAR) -> str | None:
    """``rule`` on ``status`` with its stds divided by ``factor``: the reason it would stop were
    the stds ``factor`` x smaller (None: not near). Every status ``rule`` stops is near."""
    return rule(replace(status, mean_std_mm=status.mean_std_mm / factor,
                        max_std_mm=status.max_std_mm / factor))


class StopRule(abc.ABC):
    """A rule returns the reason to stop, or None. Compose with | (any) and & (all). A rule of
    one's own subclasses this and defines ``__call__`` (without it: a TypeError on creation)."""

    name = "rule"

    @abc.abstractmethod
    def __call__(self, status: Status) -> str | None:
        """The reason to stop (the rule's ``name``), or None to go on."""

    def __or__(self, other: "StopRule") -> "StopRule":
        return _Any(self, other)

    def __and__(self, other: "StopRule") -> "StopRule":
        return _All(self, other)


@dataclass(frozen=True)
class MeanStdBelow(StopRule):
    bound_mm: float
    name = "mean_std_bound"

    def __call__(self, status):
        return self.name if (status.adequate and not status.repeats_owed
                             and status.mean_std_mm <= self.bound_mm) else None


@dataclass(frozen=True)
class MaxStdBelow(StopRule):
    bound_mm: float
    name = "max_std_bound"

    def __call__(self, status):
        return self.name if (status.adequate and not status.repeats_owed
                             and status.max_std_mm <= self.bound_mm) else None


@dataclass(frozen=True)
class GapBelow(StopRule):
    """Holds once no allowed point is farther than ``radius_mm`` from a touch: ``bound &
    GapBelow(r)`` lets the bound stop the run only then (``plan.stop.max_gap_mm``)."""

    radius_mm: float
    name = "gap_bound"

    def __call__(self, status):
        return self.name if status.gap_mm <= self.radius_mm else None


@dataclass(frozen=True)
class AtLeast(StopRule):
    """Holds once ``touches`` touches were made: ``bound & AtLeast(n)`` stops no earlier."""

    touches: int
    name = "at_least"

    def __call__(self, status):
        return self.name if status.touches >= self.touches else None


@dataclass(frozen=True)
class TouchBudget(AtLeast):
    """Stops once ``touches`` touches were made (the same test as AtLeast, named for a stop)."""

    name = "touch_budget"


def touches_left(rule: StopRule, touches: int) -> int | None:
    """Touches left before ``rule`` stops the survey on its touch budget alone, whatever the
    bounds do: a ``TouchBudget``, or the smallest of those joined by | ; None when none is."""
    if isinstance(rule, TouchBudget):
        return max(0, rule.touches - touches)
    if isinstance(rule, _Any):
        a, b = touches_left(rule.a, touches), touches_left(rule.b, touches)
        return a if b is None else b if a is None else min(a, b)
    return None  # no budget, or one joined by & (it stops only with the other)


@dataclass(frozen=True)
class _Any(StopRule):
    a: StopRule
    b: StopRule

    def __call__(self, status):
        return self.a(status) or self.b(status)


@dataclass(frozen=True)
class _All(StopRule):
    a: StopRule
    b: StopRule

    def __call__(self, status):
        ra, rb = self.a(status), self.b(status)
        return ra if ra and rb else None


def waits_for_repeats(rule: StopRule, status: Status) -> bool:
    """The rule would stop now but for the repeat readings ``status`` owes (``planning.repeats``):
    ask gives them next, and a batch planned ahead breaks there."""
    return bool(status.repeats_owed) and bool(rule(replace(status, repeats_owed=0)))
