"""The closure's test on the noise relearned without the drift it reads (``planning.closure``):
a drift the map could not hold went into the learned noise and would hide itself. Shared by the
run's loop and the replay of a recording, so a resumed run judges its closure as the run did (an
outside audit: across a resume the closure's p moved 0.685 -> 0.698 and its noise_h0 was lost).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from adaptive_cal.planning import closure as cl
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.plan import SurveyPlan


def judged(plan: SurveyPlan, state: sv.SurveyState, fused_t_s, start, first_rows, first_mm,
           rows, heights, times, **where) -> cl.Closure:
    """``closure.judge`` of the repeat readings (``rows``, ``heights`` at ``times``, s) against
    the start (``first_rows``, ``first_mm``: the fused readings ``start`` of ``state``, whose
    fused readings were taken at ``fused_t_s``), first on the state's noise, then -- where the
    noise is learned and every time known -- on the noise refitted with the drift it reads
    taken out of every fused reading, as a drift linear in time from the start to the repeat."""
    belief, r = state.belief, state.noise_var
    n = cl.residual_dof(state.rows, state.fused_weights, belief.cov, r)
    h0 = cl.judge(first_rows, first_mm, rows, heights, belief.mean, belief.cov, r, n, **where)
    t = np.asarray(fused_t_s, float)
    if not sv.learns(plan, state) or len(t) != state.fused or not np.isfinite(t).all() \
            or not len(times):
        return h0
    t0 = float(t[start].mean())
    span = float(np.mean(times)) - t0
    if span <= 0:
        return h0
    corrected = state.heights_mm - h0.difference_mm / span * (t - t0)
    refit = sv.refit(plan, replace(state, heights_mm=corrected))
    r1 = refit.noise_var
    n1 = cl.residual_dof(refit.rows, refit.fused_weights, refit.belief.cov, r1)
    return cl.judge(first_rows, first_mm, rows, heights, belief.mean, belief.cov, r1, n1,
                    noise_h0_mm=math.sqrt(r), **where)
