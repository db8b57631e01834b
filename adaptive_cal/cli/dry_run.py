"""``adaptive-cal run --dry-run``: the plan as the run would start it, nothing moved."""
from __future__ import annotations

from adaptive_cal.cli.common import UserError


def dry_run(cell) -> int:
    """Print the plan: the first touches, the expected count and robot time, the travel."""
    from adaptive_cal.cell.build import survey_plan

    plan = survey_plan(cell)
    touches, travel_mm, why, targets = _forecast(plan, cell)
    from adaptive_cal.report.sections import reason_text, signed

    if not targets and why != "no_admissible_point":  # the prior alone meets the bound
        print(f"dry run: the prior alone already meets the stopping rule ({reason_text(why)}): "
              "the plan has no first touch to show. The run still touches until its self-checks "
              "pass, but the bound asks for nothing -- is it the one meant (mm)?")
        return 0
    if not targets:  # as the run would say before its first touch
        from adaptive_cal.cell.consistency import no_admissible_point

        raise UserError(no_admissible_point(cell, plan))

    targets = targets[:20]
    print(f"dry run: the first {len(targets)} touches as planned when every reading lands where "
          "the belief expects it; nothing moves.\nThe plan adapts as readings arrive, and each "
          "approach height is set from the belief at that touch: the first from the prior, "
          "the others from the readings before them, so at run time.")
    print("  #     x_mm     y_mm  approach z_mm")
    for i, t in enumerate(targets):
        # the forecast's belief never leaves the prior's mean (each reading lands where it
        # expects), so its heights past the first are not the run's: those follow the plate
        z = f"{signed(t.z_mm, 3):>14}" if i == 0 else "   set at run time"
        print(f"{i:3d} {t.x_mm:8.2f} {t.y_mm:8.2f} {z}")
    r = cell.robot
    robot_s = touches * r.touch_time_s + travel_mm / r.speed_mm_per_s
    print(f"expected: about {touches} touches ({reason_text(why)}; at most "
          f"{cell.plan.stop.max_touches}), robot time about {robot_s / 60:.1f} min "
          f"({r.touch_time_s:g} s per touch, {travel_mm / 1000:.1f} m of travel from the plate "
          f"centre at "
          f"{r.speed_mm_per_s:g} mm/s); with the prior's hyper-parameters and no gated reading")
    print(_travel_line(plan, cell))
    if plan.closure:
        print("then one closure touch at the first place, to see whether the cell drifted during "
              "the run (plan.closure)")
    return 0


def _travel_line(plan, cell) -> str:
    """The travel height: the safe height, or higher before the readings bound the plate."""
    from adaptive_cal.hardware.base import CLEARANCE_MM
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.clearance import highest_mm

    top, safe = highest_mm(plan, sv.start(plan).belief), cell.robot.safe_height_mm
    reach = cell.probe.zero_mm - cell.probe.rest_mm
    if top + reach + CLEARANCE_MM <= safe:
        return f"travel: at robot.safe_height_mm = {safe:g} mm, clear of the plate"
    return (f"travel: at robot.safe_height_mm = {safe:g} mm; before readings bound it, the prior "
            f"lets the plate stand up to {top:.2f} mm (1 in 10^6), so the first travels may rise "
            f"to {top + reach + CLEARANCE_MM:.2f} mm (the free tip hangs {reach:g} mm below, "
            f"plus {CLEARANCE_MM:g} mm of clearance)")


def _forecast(plan, cell) -> tuple[int, float, str, list]:
    """Touches until the stopping rule fires, the travel between them (mm), why it fired and
    the touches, when every reading lands where the belief expects it: the covariance does not
    depend on the readings, so this is the plan's own count while the hyper-parameters stay at
    the prior's. The first 20 are chosen as the run chooses them (its refinement of the best
    candidates included), the rest on the candidate grid alone (faster)."""
    import math
    from dataclasses import replace

    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.ask import ask

    fixed = replace(plan, learn=False)
    quick = replace(fixed, refine=0)
    # travel counted from the plate centre, as the run's estimate counts it (result.json)
    state, travel, last, made = sv.start(quick), 0.0, tuple(plan.start_xy_mm), []
    while True:
        why = quick.stop(sv.status(quick, state))
        if why:
            return state.touches, travel, why, made
        targets = ask(fixed if state.touches < 20 else quick, state, 1)
        if not targets:
            return state.touches, travel, "no_admissible_point", made
        t = targets[0]
        made.append(t)
        travel += math.dist(last, (t.x_mm, t.y_mm))
        last = (t.x_mm, t.y_mm)
        state, _ = sv.tell(quick, state, t.x_mm, t.y_mm, t.z_mm, t.expected_reading_mm)
