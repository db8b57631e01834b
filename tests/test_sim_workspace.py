"""A simulated cell without a workspace block gets one derived from its workplane and stroke
(issue 16, deliver 4), and the planner and the safety check use it as they use a given one."""
from dataclasses import replace

from adaptive_cal.cell.build import survey_plan, workspace
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.ask import ask
from adaptive_cal.run.devices import safety_check

from helpers import sim_cell


def _no_box(**sections):
    cell = sim_cell(**sections)
    return cell.model_copy(update={"workspace": None})


def test_the_box_spans_the_workplane_and_the_stroke_around_the_nominal_plane():
    cell = _no_box()  # zero 5 mm, stroke 10 mm, safe height 15 mm
    box = workspace(cell)
    assert box.x_mm == (-225, 225) and box.y_mm == (-185, 185)
    assert box.z_mm == (5.0 - 20.0, 15.0)
    high = _no_box(robot={"safe_height_mm": 40})
    assert workspace(high).z_mm == (-15.0, 40.0)  # travel height is always inside


def test_a_given_workspace_is_kept():
    cell = sim_cell()
    assert workspace(cell) == cell.workspace
    assert survey_plan(cell).z_range_mm == tuple(cell.workspace.z_mm)


def test_the_planner_and_the_safety_check_use_the_derived_box():
    cell = _no_box(plan={"candidates": 400})
    plan = survey_plan(cell)
    assert plan.z_range_mm == (-15.0, 15.0)
    targets = ask(plan, sv.start(plan), 8)
    assert targets and all(-15.0 <= t.z_mm <= 15.0 for t in targets)
    allowed = safety_check(cell)
    assert allowed(0.0, -150.0, 0.0)
    assert not allowed(0.0, -150.0, -15.1) and not allowed(0.0, -150.0, 1e6)


def test_a_prior_far_off_the_stroke_leaves_no_admissible_target():
    """The z range restricts the plan: with the plate believed 30 mm above the nominal plane
    no approach height fits the derived box, so nothing is asked (a real workspace does the
    same), where without a box the planner would send z = 30 mm."""
    cell = _no_box(plan={"candidates": 400}, model={"offset_std_mm": 50.0})
    plan = survey_plan(cell)
    state = sv.start(plan)
    free = replace(plan, z_range_mm=None)  # what the planner did before: z = 30 mm sent
    for x, y in ((-200, -160), (200, -160), (-200, 160), (200, 160), (0, 0)):
        # height = 5 - 5 + 30 = 30 mm, read at a z the box refuses (tell would: no touch of
        # this cell is made there), so told to the plan without the box
        state, _ = sv.tell(free, state, x, y, 30.0, 5.0)
    assert ask(plan, state, 1) == []
    assert ask(free, state, 1)[0].z_mm > 25.0
