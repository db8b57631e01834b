"""Repeat touches: the probe's own noise read before a stop rests on a learned noise that could
be the plate.

The learned reading noise sigma_n is a nugget: the probe's noise plus whatever of the plate the
spline does not follow (``planning.adequacy``). No check can tell the two apart from readings
at different places. The learned noise is suspect (``suspected``)

* where the probe's span is stated (``probe.noise_range_mm`` [lo, hi]) and sigma_n lies within
  its sampling error of the span's top, sigma_n >= hi (1 - 1 / sqrt(2 n)): the top binds, the
  readings would have more noise than the datasheet allows the probe;
* where no span is stated and sigma_n is ``GUESS_FACTOR`` x the cell's first guess
  (``probe.noise_std_mm``) or more: the guess is wrong, or plate structure hides in the noise.

An outside audit (2026-11-29; plates of 10-30 um RMS of 100-250 mm waves on a 50-150 um bow)
saw runs stop at 31-104 touches claiming 3.9 um with a true 9-15 um error (coverage 0.38-0.55),
the noise learned 8-9.4 um on a 3-8 um span (5 um true), or 9.4-14.7 um against a first guess
of 5 um with no span; every check passed.

Readings at one place differ by the probe alone. So before a bound stops a suspect run the
planner reads places again -- the last touch, where the probe is (no travel, ``touch_time_s``
each), ``PER_PLACE`` times at most, then the next touch the criterion picks -- until ``DOF``
repeat readings are in (``gaussian.checks.repeats``). The ``repeats`` check compares the two
variances (F test, ``judged``): a learned noise well above the repeats' fails it, the model is
inadequate, grows and widens its bands by the excess over the probe's measured noise; one in
line with them passes -- the probe is as noisy as learned, and the summary gives both. A bound
waits for the repeats (``Status.repeats_owed``); the touch budget does not.

The learned noise is fitted to places (``prior.learned_belief``, ``gaussian.places``): readings
at one place enter as their mean, and their scatter -- the probe's alone -- is a floor under the
nugget, not a pull toward it; fitted with the rest, repeats had pulled the nugget toward the
probe's noise and narrowed the bands by the structure it held.

Both tests are judged once all ``DOF`` repeats are in (``SPAN_TEST``, ``NO_SPAN_TEST``); without
a span the test is stricter (1 % against 5 %), as suspicion is common there -- a first guess is
often off by 1.5 x -- and a false alarm sends a run to its budget. Measured (2026-11-29): on the
20 plates of tests/test_coverage.py (no span, probes of 4.5-12 um against a 5 um guess) 10 runs
took repeats, the mean run went 59.6 -> 69.4 touches and coverage 0.963 -> 0.964, one false
alarm (plate 14: 12 repeats read 4.9 um of an 8.9 um probe, a 1.5 % draw) ran to 200 touches. Of
8 of the audit's no-span plates that had stopped with coverage 0.38-0.53, 6 went on to 99-200
touches, coverage 0.84-0.97; two (an 8 um probe guessed at 5 um) read 8.8 and 9.7 um in their
repeats against 11.7 and 14.7 um learned, ratios the 1 % test passes, and stopped as before
(coverage 0.53, 0.40): 12 repeats see a learned noise 3.5 x the probe's variance.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.gaussian.checks import repeats
from adaptive_cal.gaussian.places import places, positions_mm

#: repeat readings asked for (dof of their variance): with 12 and 40-60 readings, a learned
#: noise 1.3 x the probe's fails the check 26 % of the time, 1.6 x 58-60 %, 1.88 x (the
#: audit's 9.4 against 5 um) 82-84 %, 2.8 x always; 1 x 5 % (F(n, 12) at SPAN_TEST's level)
DOF = 12
#: readings beyond the first at one place before the planner moves on
PER_PLACE = 3
#: without a span: the learned noise this many times the cell's first guess is suspect
GUESS_FACTOR = 1.5
#: the repeats check with a span: its level (run only where the noise exceeds the cell's: a miss
#: costs more there) and the repeat readings it waits for -- all ``DOF`` of them, as a bound
#: does: judged at 6, a 5 % false alarm made the model inadequate, the bound stopped asking for
#: repeats and the run went to its budget (a study plate, 2026-12-01: 6 repeats read a 19 um
#: probe at 10 um, F = 3.9; judged at 12 the same run stops on its bound)
SPAN_TEST = (0.05, DOF)
#: without a span: the repeats check's level and the repeat readings it waits for
NO_SPAN_TEST = (0.01, DOF)


def suspected(plan, state) -> bool:
    """The learned noise could hold plate structure the bands leave out: it sits at the stated
    span's top, or without a span it is ``GUESS_FACTOR`` x the first guess (module docstring).
    False where the survey does not learn its noise (or has not yet)."""
    span, sigma = plan.noise_range_mm, state.hyper.noise_std_mm
    if not plan.learn or state.prior is not None or not state.hyper_points or state.fused < 3:
        return False
    if span is None:
        return sigma >= GUESS_FACTOR * float(plan.model.hyper0.noise_std_mm)
    return sigma >= float(span[1]) * (1.0 - 1.0 / np.sqrt(2.0 * state.fused))


def judged(plan, state) -> tuple[float, int] | None:
    """How the ``repeats`` check judges a suspect run (``adequacy.assess(repeats=...)``): its
    level and the repeat readings it needs -- ``SPAN_TEST`` with a span, ``NO_SPAN_TEST``
    without; None where not suspect."""
    if not suspected(plan, state):
        return None
    return SPAN_TEST if plan.noise_range_mm is not None else NO_SPAN_TEST


def owed(plan, state) -> int:
    """Repeat readings a bound waits for: ``DOF`` less those already fused where the learned
    noise is ``suspected``, else 0."""
    if not suspected(plan, state):
        return 0
    xy = positions_mm(plan.model.surface, state.rows)
    return max(0, DOF - repeats(xy, state.heights_mm, state.fused_weights)[0])


def place(plan, state) -> tuple[float, float] | None:
    """Where the next repeat goes: the last fused reading's place while it holds at most
    ``PER_PLACE`` repeats, else None (a touch the criterion picks first)."""
    if not state.fused:
        return None
    xy = positions_mm(plan.model.surface, state.rows)
    label, counts = places(xy)
    here = np.round(xy[-1], 9)
    return (float(here[0]), float(here[1])) if counts[label[-1]] <= PER_PLACE else None
