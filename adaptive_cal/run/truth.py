"""How wrong a map really is, where the truth is known (a simulated cell): kept out of the engine,
used as a loop hook by the run, the studies, the tests and the notebooks."""
from __future__ import annotations

from typing import Callable

import numpy as np

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.survey import SurveyState

Truth = Callable[[np.ndarray, np.ndarray], np.ndarray]  # true surface height (mm) at x, y (mm)


def truth_error(plan: SurveyPlan, belief: bl.Belief, truth: Truth, *,
                unresolved_var_mm2=None) -> dict:
    """RMS and max error (mm) of the posterior mean against a known surface, and the share of
    the plate inside the 95 % band mean +- Z95 std (evaluation grid, whole plate); the band's
    variance is the spline's plus ``unresolved_var_mm2`` (at plan.eval_xy, the structure the
    self-checks found the spline cannot represent: ``state_truth_error``)."""
    mean, var = bl.predict(belief, plan.eval_rows)
    if unresolved_var_mm2 is not None:
        var = var + unresolved_var_mm2
    err = mean - truth(plan.eval_xy[:, 0], plan.eval_xy[:, 1])
    return {"rms_error_mm": float(np.sqrt(np.mean(err**2))),
            "max_error_mm": float(np.abs(err).max()),
            "coverage95": float(np.mean(np.abs(err) <= bl.Z95 * np.sqrt(var)))}


def state_truth_error(plan: SurveyPlan, state: SurveyState, truth: Truth) -> dict:
    """``truth_error`` of a survey state: bands of the plate, unresolved structure included."""
    return truth_error(plan, state.belief, truth,
                       unresolved_var_mm2=sv.unresolved_var_mm2(plan, state, plan.eval_xy))


class TrueError:
    """A loop hook: the true RMS error (mm) before the first touch and after each touch."""

    def __init__(self, plan: SurveyPlan, state: SurveyState, truth: Truth):
        self.plan, self.truth = plan, truth
        self.rms_mm: list[float] = [self.rms(state)]

    def rms(self, state: SurveyState) -> float:
        """The true RMS error of ``state``'s map (mm)."""
        return truth_error(self.plan, state.belief, self.truth)["rms_error_mm"]

    def __call__(self, step) -> None:
        self.rms_mm.append(self.rms(step.state))
