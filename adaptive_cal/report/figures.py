"""Figures for a measured workplane: surface and uncertainty maps, convergence, residuals.

Object API only: each function builds a ``matplotlib.figure.Figure`` (no pyplot state) and returns
it; the caller saves it (``fig.savefig(path)``). Inputs are in mm, colour scales in um.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from adaptive_cal.analysis.flatness import least_squares_plane

UM_PER_MM = 1000.0
MAX_NUMBERED_TOUCHES = 80
FINER = 3  # the maps drawn on a grid this many times finer than their nodes (``_finer``)

Range = tuple[float, float]


def plain_text(text: str) -> str:
    """``text`` shown as typed: a "$" would start matplotlib mathtext (an odd count fails)."""
    return text.replace("$", r"\$")


def incomplete_text(gap: str | None, width: int = 70) -> str:
    """The mark of an unfinished run's figure ("INCOMPLETE: interrupted after 20 touches; ...
    -- not a result", wrapped to ``width``), from ``report.status.missing(result)``, the line
    the terminal and the HTML open with; "" for a finished run (``gap`` None)."""
    if not gap:
        return ""
    import textwrap

    return "\n".join(textwrap.wrap(f"INCOMPLETE: {gap} -- not a result, the map is provisional",
                                    width))


def _plate_axes(ax, workplane_x_mm: Range, workplane_y_mm: Range) -> None:
    ax.set_xlim(*workplane_x_mm)
    ax.set_ylim(*workplane_y_mm)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def _keep_outs(ax, keep_outs: Sequence[tuple[Range, Range]]) -> None:
    for (x0, x1), (y0, y1) in keep_outs:
        ax.add_patch(Rectangle((min(x0, x1), min(y0, y1)), abs(x1 - x0), abs(y1 - y0),
                               facecolor="0.85", edgecolor="0.3", hatch="///", alpha=0.7,
                               label="keep-out", zorder=3))


def _touches(ax, touches_xy_mm: np.ndarray, numbered: bool) -> None:
    if len(touches_xy_mm) == 0:
        return
    ax.plot(touches_xy_mm[:, 0], touches_xy_mm[:, 1], "o", ms=3, mfc="white", mec="black",
            mew=0.6, label="touches", zorder=4)
    if numbered:
        for text, (x, y) in touch_labels(touches_xy_mm):  # numbers are the recording's seq
            # inside the axes: left out of the layout, which measured every label on each of
            # its passes (0.7 of the 1.7 s a map figure took with 40 touches)
            ax.annotate(text, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=8,
                        zorder=5, bbox=dict(boxstyle="square,pad=0.05", fc="white", ec="none",
                                            alpha=0.7)).set_in_layout(False)


def touch_labels(touches_xy_mm: np.ndarray, near_frac: float = 0.03) -> list[tuple[str, tuple]]:
    """One label per place: touches closer than ``near_frac`` of the plate's span to an earlier
    labelled one (a retake, a neighbour) join its label ("3,4") instead of overprinting it."""
    xy = np.asarray(touches_xy_mm, float).reshape(-1, 2)
    span = float(np.ptp(xy, axis=0).max()) if len(xy) > 1 else 1.0
    near = near_frac * max(span, 1e-9)
    places: list[list] = []  # [x, y, [seq, ...]]
    for seq, (x, y) in enumerate(xy):
        for p in places:
            if abs(p[0] - x) < near and abs(p[1] - y) < near:
                p[2].append(seq)
                break
        else:
            places.append([x, y, [seq]])
    return [(",".join(map(str, p[2])), (p[0], p[1])) for p in places]


def _next_point(ax, next_xy_mm) -> None:
    if next_xy_mm is not None:
        ax.plot([next_xy_mm[0]], [next_xy_mm[1]], marker="*", ms=14, color="magenta",
                mec="black", linestyle="none", label="next touch", zorder=6)


def _detrend_grid(x_grid_mm, y_grid_mm, mean_mm) -> np.ndarray:
    """mean - (a x + b y + c) with the least-squares plane of the map on its grid nodes."""
    x, y = np.meshgrid(x_grid_mm, y_grid_mm, indexing="ij")
    fit = least_squares_plane(x.ravel(), y.ravel(), mean_mm.ravel())
    return fit.residuals_mm.reshape(mean_mm.shape)


def _finer(x_grid, y_grid, values, factor: int = FINER):
    """The grid's values interpolated bilinearly onto a grid ``factor`` x finer, for a mesh drawn
    cell by cell: it looks as Gouraud shading does, at a third of the drawing time (Agg draws a
    Gouraud mesh triangle by triangle). Returns x, y and the values transposed for pcolormesh."""
    fx = np.linspace(x_grid[0], x_grid[-1], factor * (len(x_grid) - 1) + 1)
    fy = np.linspace(y_grid[0], y_grid[-1], factor * (len(y_grid) - 1) + 1)
    along_x = np.array([np.interp(fx, x_grid, column) for column in values.T])  # (ny, fx)
    return fx, fy, np.array([np.interp(fy, y_grid, row) for row in along_x.T]).T


def surface_figure(x_grid_mm, y_grid_mm, mean_mm, std_mm, touches_xy_mm,
                   workplane_x_mm: Range, workplane_y_mm: Range,
                   keep_outs: Sequence[tuple[Range, Range]] = (), next_xy_mm=None,
                   title: str = "", remove_tilt: bool = True, incomplete: str | None = None
                   ) -> Figure:
    """Posterior mean height (left) and posterior std (right) over the plate, in um.

    ``mean_mm`` and ``std_mm`` are (nx, ny) on the grid ``x_grid_mm`` (nx,) x ``y_grid_mm`` (ny,).
    With ``remove_tilt`` the least-squares plane of the mean map is subtracted (the title says
    so). Touches are drawn on both panels and numbered by seq on the mean panel when there are at
    most 80; keep-outs are hatched; ``next_xy_mm`` is a star. ``incomplete``: what an unfinished
    run misses (``report.status.missing``), said in red under the title (``incomplete_text``):
    the PNG is copied into other documents without the terminal's or the page's warning.
    """
    x_grid_mm = np.asarray(x_grid_mm, dtype=np.float64)
    y_grid_mm = np.asarray(y_grid_mm, dtype=np.float64)
    mean_mm = np.asarray(mean_mm, dtype=np.float64)
    std_mm = np.asarray(std_mm, dtype=np.float64)
    expected = (x_grid_mm.size, y_grid_mm.size)
    if mean_mm.shape != expected or std_mm.shape != expected:
        raise ValueError(f"mean_mm and std_mm must be (nx, ny) = {expected}, "
                         f"got {mean_mm.shape} and {std_mm.shape}")
    touches_xy_mm = np.asarray(touches_xy_mm, dtype=np.float64).reshape(-1, 2)
    height_mm = _detrend_grid(x_grid_mm, y_grid_mm, mean_mm) if remove_tilt else mean_mm

    width_mm = workplane_x_mm[1] - workplane_x_mm[0]
    height_ratio = (workplane_y_mm[1] - workplane_y_mm[0]) / width_mm
    fig = Figure(figsize=(12.0, max(3.0, 5.6 * height_ratio) + 1.2), layout="constrained")
    ax_mean, ax_std = fig.subplots(1, 2)
    panels = [
        (ax_mean, height_mm, "viridis",
         "height minus LS plane (um)" if remove_tilt else "height (um)",
         "posterior mean, tilt removed" if remove_tilt else "posterior mean"),
        (ax_std, std_mm, "magma", "posterior std (um)", "posterior std"),
    ]
    for ax, values_mm, cmap, bar_label, panel_title in panels:
        mesh = ax.pcolormesh(*_finer(x_grid_mm, y_grid_mm, values_mm * UM_PER_MM), cmap=cmap,
                             shading="nearest", zorder=1)
        fig.colorbar(mesh, ax=ax, shrink=0.9).set_label(bar_label)
        _plate_axes(ax, workplane_x_mm, workplane_y_mm)
        _keep_outs(ax, keep_outs)
        _touches(ax, touches_xy_mm, numbered=ax is ax_mean and len(touches_xy_mm) <= MAX_NUMBERED_TOUCHES)
        _next_point(ax, next_xy_mm)
        ax.set_title(panel_title, fontsize=10)
    ax_mean.set_label("mean")
    ax_std.set_label("std")
    handles, labels = ax_std.get_legend_handles_labels()
    if handles:
        unique = dict(zip(labels, handles))
        ax_std.legend(unique.values(), unique.keys(), loc="upper right", fontsize=7, framealpha=0.8)
    suffix = " (tilt removed)" if remove_tilt else ""
    head = f"{plain_text(title)}{suffix}" if title else f"workplane{suffix}"
    mark = incomplete_text(incomplete, width=110)
    if mark:
        fig.suptitle(f"{head}\n{plain_text(mark)}", color="#b00000", fontweight="bold")
    else:
        fig.suptitle(head)
    return fig


def convergence_figure(touches, mean_std_mm, max_std_mm, bound_mean_mm=None,
                       bound_max_mm=None, true_rms_mm=None, refits=(), floor_touches=0,
                       incomplete: str | None = None, jump: str | None = None) -> Figure:
    """Posterior std against touches: RMS/mean std and max std over the plate (um, log y).

    Bounds (stopping thresholds) are dashed horizontal lines in the colour of their curve;
    ``true_rms_mm`` (n,), the RMS of (posterior mean - true surface) when a simulated cell knows
    the truth, is drawn as a dotted curve. ``refits``: touch counts at which the
    hyper-parameters were refitted (thin grey lines: the std may jump there, when the learned
    form amplitude or noise changes); ``floor_touches``: no bound stops the run before this many
    touches (a shaded band); ``incomplete``: what an unfinished run misses, said in red in the
    title (as ``surface_figure``); ``jump``: what made the last point's step at the same touch
    count (a closure touch's drift widening every band), written beside it.
    """
    touches = np.asarray(touches, dtype=np.float64)
    fig = Figure(figsize=(7.0, 4.5), layout="constrained")
    ax = fig.subplots()
    mean_line, = ax.plot(touches, np.asarray(mean_std_mm) * UM_PER_MM, "-o", ms=3,
                         label="posterior std, RMS over plate")
    max_line, = ax.plot(touches, np.asarray(max_std_mm) * UM_PER_MM, "-s", ms=3,
                        label="posterior std, max over plate")
    for bound, line, name in ((bound_mean_mm, mean_line, "RMS"), (bound_max_mm, max_line, "max")):
        if bound is not None:
            ax.axhline(bound * UM_PER_MM, linestyle="--", color=line.get_color(),
                       label=f"{name} bound {bound * UM_PER_MM:.3g} um")
    if true_rms_mm is not None:
        ax.plot(touches, np.asarray(true_rms_mm) * UM_PER_MM, ":", color="black",
                label="true RMS error (simulated)")
    for i, t in enumerate(refits):
        ax.axvline(t, color="0.6", linewidth=0.7,
                   label="hyper-parameters refitted (std may jump)" if i == 0 else None)
    if floor_touches:
        ax.axvspan(0, floor_touches, color="0.92", zorder=0,
                   label=f"touch floor: no bound stops before {floor_touches} touches")
    if jump and touches.size >= 2:
        ax.annotate(jump, (touches[-1], float(np.asarray(mean_std_mm)[-1]) * UM_PER_MM),
                    xytext=(-8, 0), textcoords="offset points", ha="right", va="center",
                    fontsize=8, color="#b00000")
    ax.set_yscale("log")
    ax.set_xlabel("touches")
    ax.set_ylabel("posterior std (um)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    mark = incomplete_text(incomplete)
    if mark:
        ax.set_title(f"convergence\n{plain_text(mark)}", color="#b00000", fontweight="bold",
                     fontsize=10)
    else:
        ax.set_title("convergence")
    return fig


def residual_figure(x_mm, y_mm, residual_mm, title: str = "") -> Figure:
    """Residuals on the plate in um, diverging colours centred on zero (limits +-max|r|)."""
    residual_um = np.asarray(residual_mm, dtype=np.float64) * UM_PER_MM
    half_range = float(np.max(np.abs(residual_um))) if residual_um.size else 0.0
    half_range = half_range if half_range > 0 else 1.0
    fig = Figure(figsize=(7.5, 5.0), layout="constrained")
    ax = fig.subplots()
    points = ax.scatter(x_mm, y_mm, c=residual_um, cmap="RdBu_r", s=45, edgecolors="0.2",
                        linewidths=0.4, norm=Normalize(-half_range, half_range))
    fig.colorbar(points, ax=ax).set_label("residual (um)")
    ax.set_aspect("equal")
    ax.margins(0.05)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title or "residuals")
    return fig
