"""Repeat touches: the probe's own noise read before a stop rests on a learned noise that could
be the plate.

The learned reading noise sigma_n is a nugget: the probe's noise plus whatever of the plate the
spline does not follow (``planning.adequacy``). No check can tell the two apart from readings
at different places. The learned noise is suspect (``suspected``) where the probe's span is
stated (``probe.noise_range_mm`` [lo, hi]) and sigma_n lies within its sampling error of the
span's top, sigma_n >= hi (1 - 1 / sqrt(2 n)): the top binds, the readings would have more noise
than the datasheet allows the probe. Without a span the cell's ``probe.noise_std_mm`` is a first
guess, and a learned noise above it contradicts nothing (tried, 2026-11-29: with "above the
guess by more than the claim" as suspicion, 3 of the 20 plates of tests/test_coverage.py, their
probes 4.5-12 um against a 5 um guess, failed the check and ran to their budget, and the mean
run went 59.6 -> 86.8 touches; the summary then says what the noise could hide instead).

An outside audit (2026-11-29; plates of 10-30 um RMS of 100-250 mm waves on a 50-150 um bow)
saw runs stop at 31-89 touches claiming 3.9 um with a true 9-12 um error, the noise learned
8.0-9.4 um on a 3-8 um span (5 um true); every check passed.

Readings at one place differ by the probe alone. So before a bound stops a suspect run the
planner reads places again -- the last touch, where the probe is (no travel, ``touch_time_s``
each), ``PER_PLACE`` times at most, then the next touch the criterion picks -- until ``DOF``
repeat readings are in (``gaussian.checks.repeats``). The ``repeats`` check (run where the
noise is suspect) compares the two variances: a learned noise well above the repeats' fails
it, the model is inadequate, grows and widens its bands by the excess over the probe's
measured noise; one in line with them passes -- the probe is as noisy as learned, and the
summary gives both. A bound waits for the repeats (``Status.repeats_owed``); the touch budget
does not.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.gaussian.checks import places, repeats
from adaptive_cal.planning.adequacy import positions_mm

#: repeat readings asked for (dof of their variance): with 12 and 40-60 readings, a learned
#: noise 1.3 x the probe's fails the check 26 % of the time, 1.6 x 58-60 %, 1.88 x (the
#: audit's 9.4 against 5 um) 82-84 %, 2.8 x always; 1 x 5 % (F(n, 12) at REPEAT_ALPHA)
DOF = 12
#: readings beyond the first at one place before the planner moves on
PER_PLACE = 3


def suspected(plan, state) -> bool:
    """The learned noise could hold plate structure the bands leave out: it sits at the stated
    span's top (module docstring). False without a span, or where the survey does not learn
    its noise (or has not yet)."""
    span = plan.noise_range_mm
    if span is None or not plan.learn or state.prior is not None or not state.hyper_points \
            or state.fused < 3:
        return False
    return state.hyper.noise_std_mm >= float(span[1]) * (1.0 - 1.0 / np.sqrt(2.0 * state.fused))


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
