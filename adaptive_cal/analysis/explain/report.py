"""Writing what explain found: the updated cell file and the figures (the world's edge)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from adaptive_cal.effects import library as physics
from adaptive_cal.analysis.explain.core import Explanation

AXIS_OF = {"form": "position", "local_defect": "position", "thermal_drift": "time",
           "reversal": "direction", "arm_sag": "reach", "probe_gain": "indication"}


def write_cell(explanation: Explanation, cell_data: dict, cell_path: str | Path,
               out_dir: str | Path) -> Path | None:
    """The cell file with the winning effect added to simulation.effects (std in comments)."""
    rep = explanation.report
    if rep["verdict"] == "none":
        return None
    entry = next(e for e in rep["left_out"] if e["effect"] == rep["verdict"])
    params = {k: (v[-1] if isinstance(v, list) else v) for k, v in entry["params"].items()}
    data = dict(cell_data)
    sim = dict(data.get("simulation") or {})
    effects = dict(sim.get("effects") or {})
    effects[entry["effect"]] = {k: float(v) for k, v in params.items()
                                if k in physics.PARAMS[entry["effect"]]}
    sim["effects"] = effects
    data["simulation"] = sim
    out = Path(out_dir) / f"{Path(cell_path).stem}-explained.yaml"
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {Path(cell_path).name} with the effect adaptive-cal explain found added:",
             f"# {entry['summary']}",
             "# standard deviations: " + ", ".join(
                 f"{k} {np.atleast_1d(v)[-1]:.3g}" for k, v in entry["params_std"].items())]
    if entry.get("sharing") == "per_round":
        lines.append("# fitted per round; the last round's values are written")
    out.write_text("\n".join(lines) + "\n" + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return out


def _map(ax, fig, x, y, r_um, title, lim):
    sc = ax.scatter(x, y, c=r_um, cmap="RdBu_r", vmin=-lim, vmax=lim, s=40, edgecolors="k",
                    linewidths=0.3)
    ax.set(title=title, xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
    fig.colorbar(sc, ax=ax, label="residual (um)", shrink=0.8)


def figures(explanation: Explanation, out_dir: str | Path) -> list[Path]:
    """residual_map.png (before | after, per round), residual_vs_<axis>.png, fitted_effect.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    d = explanation.context.design
    f = d.features
    rep = explanation.report
    before, after = 1e3 * explanation.residual_before, 1e3 * explanation.residual_after
    lim = float(np.abs(before).max()) or 1.0
    paths = []
    fig, axes = plt.subplots(d.rounds, 2, figsize=(11, 3.8 * d.rounds), squeeze=False)
    for r in range(d.rounds):
        rows = d.round_index == r
        _map(axes[r, 0], fig, f.x_mm[rows], f.y_mm[rows], before[rows],
             f"round {r}: calibrated nominal (rms {np.sqrt(np.mean(before[rows] ** 2)):.1f} um)", lim)
        _map(axes[r, 1], fig, f.x_mm[rows], f.y_mm[rows], after[rows],
             f"with {rep['verdict']} (rms {np.sqrt(np.mean(after[rows] ** 2)):.1f} um)", lim)
    fig.tight_layout()
    paths.append(out_dir / "residual_map.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    by = rep["mismatch"]["by"]
    tested = {k: v["p_value"] for k, v in by.items() if v.get("p_value") is not None}
    axis = AXIS_OF.get(rep["verdict"]) or min(tested, key=tested.get)
    values = {"position": f.y_mm, "time": f.t_s, "direction": f.direction,
              "reach": f.reach_mm(d.geometry) if d.geometry.base_xy_mm else f.x_mm,
              "indication": f.displacement_mm}[axis]
    label = {"position": "y (mm)", "time": "time (s)" if all(d.time_known) else
             "seq x touch_time_s (s)", "direction": "direction of arrival along x (-1, +1)",
             "reach": "reach from the robot base (mm)", "indication": "indication (mm)"}[axis]
    fig, ax = plt.subplots(figsize=(7, 4))
    jitter = 0.05 * np.sign(before) if axis == "direction" else 0.0
    ax.scatter(values + jitter, before, s=18, label="before", alpha=0.7)
    ax.scatter(values - jitter, after, s=18, label=f"after ({rep['verdict']})", alpha=0.7)
    ax.axhline(0, color="k", lw=0.5)
    p = by[axis].get("p_value")
    ax.set(xlabel=label, ylabel="residual (um)",
           title=f"residual against {axis}" + (f" (F-test p = {p:.2g})" if p is not None else ""))
    ax.legend()
    fig.tight_layout()
    paths.append(out_dir / f"residual_vs_{axis}.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    w = explanation.winner
    if w is not None:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        effect_um = 1e3 * (w.columns @ w.mean)
        if w.effect in physics.SURFACE_EFFECTS:
            (x0, x1), (y0, y1) = d.geometry.x_range_mm, d.geometry.y_range_mm
            gx, gy = np.meshgrid(np.linspace(x0, x1, 91), np.linspace(y0, y1, 75))
            gf = physics.Features(gx.ravel(), gy.ravel(), np.zeros(gx.size), np.zeros(gx.size),
                                  np.zeros(gx.size))
            X = physics.effect_regressor(w.effect, gf, d.geometry, w.fixed)
            k = X.shape[1]
            z = 1e3 * (X @ w.mean[-k:]).reshape(gx.shape)  # shared, or the last round
            cs = ax.contourf(gx, gy, z, levels=21, cmap="viridis")
            fig.colorbar(cs, ax=ax, label=f"{w.effect} (um)")
            ax.plot(f.x_mm, f.y_mm, "k.", ms=3)
            ax.set(xlabel="x (mm)", ylabel="y (mm)", aspect="equal")
        else:
            order = np.argsort(values)
            ax.plot(values[order], effect_um[order], "o-", ms=3)
            ax.set(xlabel=label, ylabel=f"{w.effect} change of the reading (um)")
        ax.set_title(f"fitted {w.effect} (log BF {w.log_bf:.1f} against none)")
        fig.tight_layout()
        paths.append(out_dir / "fitted_effect.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths
