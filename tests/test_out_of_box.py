"""Where the workspace box keeps the probe off the plate (analysis/reach.py ``out_of_box``), after
an outside audit (2026-12-01): a workspace floor 2 mm above a tilted plate's low corner was
accepted, the run spent its 120 touches and advised a larger budget, never naming the box.
Oracle: a plane whose height crosses the floor at a known x."""
import numpy as np
import pytest

from adaptive_cal.analysis.reach import out_of_box
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.gaussian.belief import Belief
from adaptive_cal.report.status import next_step

from helpers import sim_cell


def _plane_belief(plan, slope):
    """The belief of the plane h = slope * (x - x_c), certain (sim-cell's centre x_c is 0)."""
    mean = plan.model.tilt_basis @ np.array([slope, 0.0, 0.0])
    return Belief(mean, 1e-12 * np.eye(mean.size))


def test_the_points_whose_approach_lies_below_the_floor_are_found_and_named():
    cell = sim_cell(workspace={"z_mm": [-1.0, 60.0]})
    plan = survey_plan(cell)
    lo, hi = plan.usable_mm
    assert plan.approach_height(0.0) == pytest.approx(plan.zero_mm - 0.5 * (lo + hi))
    shift = plan.zero_mm - 0.5 * (lo + hi)  # approach z = height + shift
    box = out_of_box(plan, _plane_belief(plan, 0.01))  # approach 0.01 x + shift
    edge = (-1.0 - shift) / 0.01
    xs = np.unique(plan.candidates.xy_mm[:, 0])
    step = float(np.diff(xs).max())
    assert box["x_mm"][1] <= edge and box["x_mm"][1] > edge - step - 1e-9
    inside = plan.candidates.xy_mm[:, 0] < edge
    assert box["share"] == pytest.approx(inside.mean())
    assert box["approach_z_mm"][1] < -1.0 and "below the workspace floor" in box["text"]
    result = {"stopped_because": "touch_budget", "out_of_box": box}
    assert "Widen workspace.z_mm" in next_step(result, "adaptive-cal run --resume out")
    assert out_of_box(plan, _plane_belief(plan, 0.0)) is None  # a level plate: all inside
