"""Figures of what ``explain`` found: residual maps before | after, the residual against the axis
that revealed the effect, and the fitted effect.

Object API only: each figure is a ``matplotlib.figure.Figure`` (no pyplot state), saved with
``fig.savefig``. Inputs in mm, colour scales in um.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from adaptive_cal import effects
from adaptive_cal.analysis.explain.core import Explanation

DPI = 110


def _map(ax, fig, x, y, r_um, title, lim):
    sc = ax.scatter(x, y, c=r_um, cmap="RdBu_r", vmin=-lim, vmax=lim, s=40, edgecolors="k",
                    linewidths=0.3)
    ax.set(title=title, xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    fig.colorbar(sc, ax=ax, label="residual (um)", shrink=0.8)


def nothing_removed(explanation: Explanation) -> str | None:
    """Why there is no "after" (verdict none, or unexplained with no library model): the
    after residual is the before residual, so the figures show it once and say so."""
    if explanation.winner is not None:
        return None
    verdict = explanation.findings["verdict"]
    return (f"verdict {verdict}: nothing removed, the residual is the calibrated nominal's"
            if verdict == "none" else
            f"verdict {verdict}: no library effect fitted, nothing removed")


def residual_maps(explanation: Explanation) -> Figure:
    """Calibrated nominal | with the verdict, one row per round (um, one colour scale); the
    nominal alone, one column, when nothing was removed (``nothing_removed``)."""
    d = explanation.context.design
    f = d.features
    before, after = 1e3 * explanation.residual_before, 1e3 * explanation.residual_after
    lim = float(np.abs(before).max()) or 1.0
    none = nothing_removed(explanation)
    cols = 1 if none else 2
    fig = Figure(figsize=(5.8 if none else 11, 3.8 * d.rounds + (0.4 if none else 0)))
    axes = fig.subplots(d.rounds, cols, squeeze=False)
    verdict = explanation.findings["verdict"]
    for r in range(d.rounds):
        rows = d.round_index == r
        _map(axes[r, 0], fig, f.x_mm[rows], f.y_mm[rows], before[rows],
             f"round {r}: calibrated nominal (rms {np.sqrt(np.mean(before[rows] ** 2)):.1f} um)", lim)
        if not none:
            _map(axes[r, 1], fig, f.x_mm[rows], f.y_mm[rows], after[rows],
                 f"with {verdict} (rms {np.sqrt(np.mean(after[rows] ** 2)):.1f} um)", lim)
    if none:
        fig.suptitle(none, fontsize=9)
    fig.tight_layout()
    return fig


def revealing_axis(explanation: Explanation) -> str:
    """The verdict's axis (for unexplained: the axis of the structure left, where the mismatch
    has it), or (for none) the axis with the smallest F-test p-value."""
    rep = explanation.findings
    if rep["verdict"] in effects.EFFECTS:
        return effects.get(rep["verdict"]).axis
    axis = (rep.get("unexplained") or {}).get("axis")
    if axis in rep["mismatch"]["by"] and rep["mismatch"]["by"][axis].get("p_value") is not None:
        return axis
    tested = {k: v["p_value"] for k, v in rep["mismatch"]["by"].items()
              if v.get("p_value") is not None}
    return min(tested, key=tested.get)


def _axis_values(explanation: Explanation, axis: str) -> tuple[np.ndarray, str]:
    d = explanation.context.design
    f = d.features
    values = {"position": lambda: f.y_mm, "time": lambda: f.t_s, "direction": lambda: f.direction,
              "reach": lambda: f.reach_mm(d.geometry) if d.geometry.base_xy_mm else f.x_mm,
              "indication": lambda: f.ideal_reading_mm}[axis]()
    label = {"position": "y (mm)", "time": "time (s)" if all(d.time_known) else
             "seq x touch_time_s (s)", "direction": "direction of arrival along x (-1, +1)",
             "reach": "reach from the robot base (mm)", "indication": "indication (mm)"}[axis]
    return values, label


def residual_against(explanation: Explanation, axis: str) -> Figure:
    """Residual before and after against one axis, with that axis's F-test p-value; before
    alone, labelled why, when nothing was removed (``nothing_removed``)."""
    rep = explanation.findings
    values, label = _axis_values(explanation, axis)
    before, after = 1e3 * explanation.residual_before, 1e3 * explanation.residual_after
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    jitter = 0.05 * np.sign(before) if axis == "direction" else 0.0
    none = nothing_removed(explanation)
    ax.scatter(values + jitter, before, s=18, label="before", alpha=0.7)
    if not none:
        ax.scatter(values - jitter, after, s=18, label=f"after ({rep['verdict']})", alpha=0.7)
    ax.axhline(0, color="k", lw=0.5)
    p = rep["mismatch"]["by"][axis].get("p_value")
    ax.set(xlabel=label, ylabel="residual (um)",
           title=f"residual against {axis}" + (f" (F-test p = {p:.2g})" if p is not None else "")
           + (f"\n{none}" if none else ""))
    if not none:
        ax.legend()
    fig.tight_layout()
    return fig


def fitted_effect(explanation: Explanation) -> Figure | None:
    """The winner's fitted change: a map for the plate's effects, else against its axis."""
    w = explanation.winner
    if w is None:
        return None
    d = explanation.context.design
    f = d.features
    effect = effects.get(w.effect)
    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    if effect.surface:
        (x0, x1), (y0, y1) = d.geometry.x_range_mm, d.geometry.y_range_mm
        gx, gy = np.meshgrid(np.linspace(x0, x1, 91), np.linspace(y0, y1, 75))
        zero = np.zeros(gx.size)
        gf = effects.Features(gx.ravel(), gy.ravel(), zero, zero, zero)
        X = effect.regressor(gf, d.geometry, w.fixed, w.names)
        k = X.shape[1]
        z = 1e3 * (X @ w.mean[-k:]).reshape(gx.shape)  # shared, or the last round
        cs = ax.contourf(gx, gy, z, levels=21, cmap="viridis")
        fig.colorbar(cs, ax=ax, label=f"{w.effect} (um)")
        ax.plot(f.x_mm, f.y_mm, "k.", ms=3)
        ax.set(xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    else:
        values, label = _axis_values(explanation, effect.axis)
        effect_um = 1e3 * (w.columns @ w.mean)
        order = np.argsort(values)
        ax.plot(values[order], effect_um[order], "o-", ms=3)
        ax.set(xlabel=label, ylabel=f"{w.effect} change of the reading (um)")
    ax.set_title(f"fitted {w.effect} (log BF {w.log_bf:.1f} against none)")
    fig.tight_layout()
    return fig


def figures(explanation: Explanation, out_dir: str | Path) -> list[Path]:
    """residual_map.png, residual_vs_<axis>.png and (with a verdict) fitted_effect.png."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    axis = revealing_axis(explanation)
    drawn = [("residual_map.png", residual_maps(explanation)),
             (f"residual_vs_{axis}.png", residual_against(explanation, axis)),
             ("fitted_effect.png", fitted_effect(explanation))]
    paths = []
    for name, fig in drawn:
        if fig is not None:
            paths.append(out_dir / name)
            fig.savefig(paths[-1], dpi=DPI)
    return paths
