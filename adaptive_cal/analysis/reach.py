"""Where the touches reach: the grid the flatness within reach of the touches is taken on, and
the largest gap between the touches. The grid: as many points as the whole
plate's evaluation grid, its ends on the edges of the reachable box (the workplane less its edge
margin). The whole plate's grid nodes that fall inside the box stop short of its edges (on the
sim cell's 41 x 41 grid: y to +-166.5 of +-175 mm), and a plate bowed across y read 8 % flatter
there than over the box the figure names, its interval missing the truth (an outside audit,
2026-11-29)."""
from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator


def reach_grid(eval_xy, box) -> np.ndarray:
    """(n*n, 2) points spanning ``box`` ((x0, x1), (y0, y1)), n the whole plate's grid size
    (``eval_xy`` a square n x n grid), ordered as ``eval_xy`` (x major)."""
    n = int(round(np.sqrt(len(eval_xy))))
    (x0, x1), (y0, y1) = box
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n), indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], 1)


def on_grid(eval_xy, values, xy) -> np.ndarray:
    """``values`` given at the regular grid ``eval_xy`` (x major), interpolated bilinearly at
    the points ``xy`` inside it."""
    eval_xy = np.asarray(eval_xy, dtype=np.float64)
    ux, uy = np.unique(eval_xy[:, 0]), np.unique(eval_xy[:, 1])
    grid = np.asarray(values, dtype=np.float64).reshape(len(ux), len(uy))
    return RegularGridInterpolator((ux, uy), grid)(np.asarray(xy, dtype=np.float64))


GAP_MEANS = ("the largest disc inside the reachable, allowed part of the plate with no fused "
             "touch (centre x_mm, y_mm; radius_mm): a dent or bump narrower than it can lie "
             "there unseen, and no interval here includes one")


def largest_gap(plan, touched_xy) -> dict | None:
    """{"radius_mm", "x_mm", "y_mm", "means"}: the point a touch may go to (the plan's
    candidates: inside the edge margin, outside keep-outs) farthest from every touch in
    ``touched_xy`` (N, 2), and that distance (the fill distance of the touches); None without
    touches. A feature narrower than this can sit between the touches: the checks see only
    what lands on a touch, so neither the bands nor the flatness intervals carry it."""
    from adaptive_cal.planning.gap import largest_gap as gap

    cand = np.asarray(plan.candidates.xy_mm, dtype=np.float64)
    radius, i = gap(cand, touched_xy)
    if i < 0:
        return None
    return {"radius_mm": radius, "x_mm": float(cand[i, 0]), "y_mm": float(cand[i, 1]),
            "means": GAP_MEANS}


def gap_line(gap: dict) -> str:
    return (f"largest gap between touches: {gap['radius_mm']:.0f} mm radius around "
            f"({gap['x_mm']:.0f}, {gap['y_mm']:.0f}) mm; a dent or bump of smaller radius can "
            "lie there unseen, and the flatness intervals do not include one")


def out_of_box(plan, belief) -> dict | None:
    """Where the workspace box keeps the probe off the plate: the share of the points a touch may
    go to whose approach height under ``belief`` (the expected reading mid-stroke) lies outside
    ``workspace.z_mm``, the box around them and their approach heights (mm); None where every
    point is inside. Such points are never planned, so no budget maps them (an outside audit,
    2026-12-01: a floor 2 mm above a tilted plate's low corner ran its 120 touches and advised
    a larger budget)."""
    if plan.z_range_mm is None:
        return None
    from adaptive_cal.gaussian import belief as bl

    cand = np.asarray(plan.candidates.xy_mm, dtype=np.float64)
    z = plan.approach_height(np.asarray(bl.predict(belief, plan.candidates.rows)[0]))
    off = ~plan.z_allowed(z)
    if not off.any():
        return None
    lo, hi = plan.z_range_mm
    xy, zz = cand[off], z[off]
    side = "below the workspace floor" if zz.min() < lo else "above the workspace ceiling"
    out = {"share": float(off.mean()), "x_mm": [float(xy[:, 0].min()), float(xy[:, 0].max())],
           "y_mm": [float(xy[:, 1].min()), float(xy[:, 1].max())],
           "approach_z_mm": [float(zz.min()), float(zz.max())], "workspace_z_mm": [lo, hi]}
    out["text"] = (f"{100 * out['share']:.0f} % of the plate (x {out['x_mm'][0]:.0f}.."
                   f"{out['x_mm'][1]:.0f} mm, y {out['y_mm'][0]:.0f}..{out['y_mm'][1]:.0f} mm) is "
                   f"out of the workspace box: its approach heights, {zz.min():.2f} to "
                   f"{zz.max():.2f} mm, lie {side} (workspace.z_mm [{lo:g}, {hi:g}] mm); no touch "
                   "goes there, so the map rests on touches elsewhere. Widen workspace.z_mm if "
                   "the robot can reach there safely; more touches will not")
    return out
