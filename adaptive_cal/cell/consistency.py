"""Checks across the blocks of a cell file, run once it has validated block by block.

Safety first: nothing outside the workspace box is ever sent, so a cell that drives a robot must
say where that box is, and the box must hold the whole touchable plate (inside the edge margin)
and the travel height -- otherwise the planner would choose touches the probe cycle then refuses.
Each error names the keys and their values.
"""
from __future__ import annotations

import math

import numpy as np


def derived_box_mm(cell) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
    """The workspace box (x, y, z in mm) of a simulated cell that gives none, derived from the
    workplane and the probe's stroke: x, y span the workplane; z allows a surface up to one
    stroke off the nominal plane read anywhere in the stroke, so z = h + zero - reading lies in
    [zero - 2 stroke, zero + stroke], raised to the travel height when that is higher.
    A real cell must give its own box (``check_cell``)."""
    wp, p = cell.workplane, cell.probe
    z = (p.zero_mm - 2.0 * p.stroke_mm, max(p.zero_mm + p.stroke_mm, cell.robot.safe_height_mm))
    return tuple(wp.x_mm), tuple(wp.y_mm), z


KNOT_SLACK_MM = 1e-6  # round-off on knots written to the workplane's edges


def check_knots(cell) -> None:
    """ValueError naming the key unless given knot positions begin and end on the workplane's
    edges: the map, its integrated variance and the stop's RMS std are taken over the knots'
    span (an outside audit, 2026-12-01: knots 100 mm beyond a 450 x 370 mm plate gave an RMS
    std of 16.8 um where the plate's own was 5.3 um, counting area no touch reaches)."""
    for axis in ("x", "y"):
        k, (lo, hi) = getattr(cell.model, f"knots_{axis}"), getattr(cell.workplane, f"{axis}_mm")
        if isinstance(k, list) and (abs(k[0] - lo) > KNOT_SLACK_MM
                                    or abs(k[-1] - hi) > KNOT_SLACK_MM):
            raise ValueError(f"model.knots_{axis}={k} must begin and end on the edges of "
                             f"workplane.{axis}_mm={[lo, hi]} (the map and its stop are taken "
                             "over the knots' span: beyond the plate it counts area no touch "
                             "reaches; inside it the plate's edges are not mapped)")


def check_cell(cell) -> None:
    """Raise ValueError naming the keys when the blocks of ``cell`` contradict each other."""
    r, p, ws, wp = cell.robot, cell.probe, cell.workspace, cell.workplane
    check_knots(cell)  # at load, naming the key (it was found building the model)
    if r.adapter != "sim" and ws is None:
        raise ValueError(f"robot.adapter={r.adapter!r} moves a real probe: give a workspace block "
                         "(x_mm, y_mm, z_mm: the box the probe tip may be sent to; nothing outside "
                         "it is ever sent)")
    if r.adapter != "sim" and r.safe_height_mm <= p.zero_mm:
        raise ValueError(f"robot.safe_height_mm={r.safe_height_mm} must be above "
                         f"probe.zero_mm={p.zero_mm}: the free probe tip reaches zero_mm "
                         "below the commanded height and would drag over the plate")
    if ws is not None:
        if not ws.z_mm[0] <= r.safe_height_mm <= ws.z_mm[1]:
            raise ValueError(f"robot.safe_height_mm={r.safe_height_mm} lies outside "
                             f"workspace.z_mm={list(ws.z_mm)}: travel would leave the workspace")
        m = wp.edge_margin_mm
        for axis in ("x_mm", "y_mm"):
            lo, hi = getattr(wp, axis)
            box = getattr(ws, axis)
            if box[0] > lo + m or box[1] < hi - m:
                raise ValueError(
                    f"workspace.{axis}={list(box)} does not hold the touchable plate "
                    f"[{lo + m:g}, {hi - m:g}] (workplane.{axis}={[lo, hi]} inside "
                    f"edge_margin_mm={m:g}): widen the workspace, or narrow the workplane")
        if r.adapter == "modbus" and r.modbus is not None:  # every target fits the registers
            r.modbus.check_reach({"x_mm": ws.x_mm, "y_mm": ws.y_mm, "z_mm": ws.z_mm},
                                 "robot.modbus")
    if p.adapter == "modbus" and p.modbus is not None:  # every reading fits the registers:
        # a wider value wraps (int16 at 10000 counts/mm: 7.1 mm arrives as 0.5464 mm, inside
        # the usable stroke, and would be fused)
        p.modbus.check_reach({"probe.stroke_mm": (0.0, p.stroke_mm)}, "probe.modbus",
                             "a reading anywhere in")
    if (r.adapter == "sim") != (p.adapter == "sim"):
        raise ValueError(f"robot.adapter={r.adapter!r} with probe.adapter={p.adapter!r}: the "
                         "simulated robot and probe only exist together; set both to 'sim'")
    if r.adapter == "modbus" and p.adapter == "modbus":
        a, b = r.modbus, p.modbus
        same = all(getattr(a, k, None) == getattr(b, k, None)
                   for k in ("transport", "host", "port", "serial_port", "device_id"))
        if same and a != b:
            raise ValueError("robot.modbus and probe.modbus name the same PLC with different "
                             "settings; make the two blocks identical")
    sim = cell.simulation
    if sim is not None and sim.surface_file is not None:  # loads, covers, within the stroke
        from adaptive_cal.formats.mapfiles import check_map

        check_map(sim.surface_file, wp, "simulation.surface_file", p.usable_mm,
                  sim.effects.get("tilt", {}).get("c", 0.0))


def um_as_mm(value_mm: float, usable_span_mm: float) -> bool:
    """A noise or a bound this large -- a tenth of the probe's usable stroke or more, and at
    least 0.1 mm -- is um typed as mm (4 um is 0.004): the probe's noise is refused at load
    (``Probe``), a variance bound warned about (``doubts``)."""
    return value_mm >= max(0.1 * usable_span_mm, 0.1)


def doubts(cell) -> list[str]:
    """Settings that are valid but look like a unit slip, as warnings the run prints before
    anything moves: a variance bound of a tenth of the probe's usable stroke or more (and at
    least 0.1 mm) -- um typed as mm (4 um is 0.004) stops a run before it maps anything finer
    than the probe's own travel."""
    lo, hi = cell.probe.usable_mm
    span, stop, out = hi - lo, cell.plan.stop, []
    for key in ("mean_std_mm", "max_std_mm"):
        value = getattr(stop, key)
        if value is not None and um_as_mm(value, span):
            out.append(f"plan.stop.{key}: {value:g} mm is {value / span:.0%} of the probe's usable "
                       f"stroke ({span:g} mm): the run stops once the map is known to that -- "
                       f"um given as mm? ({value:g} um is {value / 1000:g})")
    unreachable = unreachable_share(cell.workplane)
    if unreachable >= UNREACHABLE_SHARE and (stop.mean_std_mm or stop.max_std_mm):
        wp = cell.workplane
        out.append(f"workplane: {unreachable:.0%} of the plate lies beyond the touches' reach (the "
                   f"edge margin of {wp.edge_margin_mm:g} mm and {len(wp.keep_outs)} keep-out(s)): "
                   "the stopping bound is over the whole plate, so over that share it rests on "
                   "extrapolation and may never be met; narrow the margin and the keep-outs to "
                   "what the probe really cannot touch")
    probe = cell.probe
    step_std = probe.resolution_mm / math.sqrt(12)  # the rounding to the readout step alone
    stated = (("noise_range_mm", probe.noise_range_mm[0]) if probe.noise_range_mm else
              ("noise_std_mm", probe.noise_std_mm))
    if stated[1] < step_std:
        out.append(f"probe.{stated[0]}: {stated[1] * 1e3:.3g} um of reading noise is below what "
                   f"the readout step alone gives (probe.resolution_mm {probe.resolution_mm * 1e3:g}"
                   f" um: {step_std * 1e3:.2g} um std): no reading is that precise, and the first "
                   "readings would fix the map as if they were (state the probe's noise as its "
                   "datasheet or a gauge study gives it)")
    seen = []
    for part in ("robot", "probe"):
        m = getattr(getattr(cell, part), "modbus", None)
        if m is not None and getattr(cell, part).adapter == "modbus" and m not in seen:
            seen.append(m)  # the probe on the robot's own PLC: said once
            out += [f"{part}.modbus.registers.{role}: {line}"
                    for role, name in m.registers.roles().items()
                    if (line := modicon_doubt(name))]
    return out


#: a share of the plate beyond the touches' reach from which a bound over the whole plate is
#: doubted (an outside audit: an edge margin of a third of the plate, 85 % unreachable, spent the
#: whole budget against a bound extrapolation could not meet)
UNREACHABLE_SHARE = 0.3


def unreachable_share(wp, n: int = 100) -> float:
    """The share of the workplane no touch may go to (edge margin, keep-outs): an n x n grid."""
    x = np.linspace(wp.x_mm[0], wp.x_mm[1], n)
    y = np.linspace(wp.y_mm[0], wp.y_mm[1], n)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    return float(1.0 - np.mean(wp.allowed(xx, yy)))


MODICON = {"coil": 0, "di": 1, "ir": 3, "hr": 4}  # a Modicon reference's leading digit
TABLE_NAMES = {"di": "discrete input", "ir": "input register", "hr": "holding register"}


def modicon_doubt(name: str) -> str | None:
    """A raw ``hr:40101`` (``ir:3..``, ``di:1..``, ``coil:0..`` can't tell) reads like a
    Modicon reference, counted from 1 with the table as its first digit; ``hr:N`` is the
    protocol address, counted from 0, and is sent as given."""
    table, _, n = str(name).strip().lower().partition(":")
    if table not in ("di", "ir", "hr") or not n.isdigit() or len(n) != 5:
        return None
    if int(n[0]) != MODICON[table] or int(n[1:]) == 0:
        return None
    return (f"{name} reads like a Modicon reference ({MODICON[table]}xxxx, counted from 1); "
            f"{table}:N is the protocol address, counted from 0, and {int(n)} is sent as "
            f"given. If your PLC's table means {TABLE_NAMES[table]} {int(n[1:])}, write "
            f"{table}:{int(n[1:]) - 1}")


def no_admissible_point(cell, plan) -> str:
    """Why a run (or its dry run) cannot make its first touch: no point the prior allows --
    the workspace's z range missing the approach height of a nominal plate, named first; a
    keep-out over the plate's centre, where the first touches must be, named."""
    lo, hi = cell.probe.usable_mm
    z0 = float(plan.approach_height(0.0))  # over the nominal plate
    box = cell.workspace
    if not plan.z_allowed(z0):
        return (f"workspace.z_mm {list(box.z_mm)} mm: the nominal plate (z 0) is read mid-stroke "
                f"from an approach height of {z0:g} mm (probe.zero_mm {cell.probe.zero_mm:g} "
                f"less the middle of probe.usable_mm {[lo, hi]}), outside that range: no touch "
                "can be made. Widen workspace.z_mm to hold it")
    cx, cy = plan.model.centre_mm
    dense = denser_grid_allows(plan) if cell.plan.candidates < DENSE else 0
    if dense:  # an audit: 16 candidates on the reference plate; the prior and keep-outs blamed
        n = len(plan.candidates.xy_mm)
        return (f"no allowed point can be promised to land inside the usable probe stroke "
                f"{[lo, hi]} mm among the {n} points of plan.candidates={cell.plan.candidates}: "
                f"none lies near enough to ({cx:g}, {cy:g}) mm, where the prior knows the plate's "
                f"height (model.pivot_mm) and the first touches must be while the tilt is "
                f"unknown ({dense} points of a 10,000-point grid would do): give more "
                "candidates (the default is 10000)")
    over = [f"workplane.keep_outs[{i}] (x_mm {list(k.x_mm)}, y_mm {list(k.y_mm)})"
            for i, k in enumerate(cell.workplane.keep_outs) if k.contains(cx, cy)]
    where = (f"{' and '.join(over)} covers the point whose height the prior knows "
             f"({cx:g}, {cy:g}) mm (model.pivot_mm), where the first touches must be while the "
             "tilt is unknown: make it smaller (the clamp's own footprint and its clearance), "
             "or level the plate first so the prior allows touches farther out" if over else
             "the prior is too wide for the stroke (level the plate first, or narrow "
             "model.offset_std_mm / tilt_std_deg), or the keep-outs and the edge margin leave "
             f"no point near ({cx:g}, {cy:g}) mm, where the prior knows the plate's height "
             "(model.pivot_mm) and the first touches must be while the tilt is unknown")
    return (f"no allowed point can be promised to land inside the usable probe stroke "
            f"{[lo, hi]} mm: {where}")


DENSE = 10_000  # candidates (the default): a grid fine enough to tell a coarse one's fault


def denser_grid_allows(plan, count: int = DENSE) -> int:
    """How many points of a ``count``-point candidate grid the prior would allow (inside the
    usable stroke with the planner's certainty, approach height inside the workspace), where
    the plan's own, coarser candidates allow none: more than 0 when they are too coarse."""
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.scoring import candidate_grid, stroke_ok

    state = sv.start(plan)
    grid = candidate_grid(plan.model.surface, plan.allows, *plan.bounds_mm, count)
    rows, b = grid.rows, state.belief
    var = np.einsum("nk,nk->n", rows @ b.cov, rows)
    ok = stroke_ok(var, state.noise_var, plan.usable_mm) & plan.z_allowed(
        plan.approach_height(rows @ b.mean))
    return int(ok.sum())
