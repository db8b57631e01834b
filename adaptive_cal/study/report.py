"""Tables and plots of a study: the headline table (markdown), touches against bound per
strategy, coverage, and one example plate per strategy with its touches."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .config import Study


def _f(v, scale=1.0, fmt="{:.1f}"):
    return "-" if v is None else fmt.format(v * scale)


def table(summary: dict) -> str:
    """The headline table (markdown): touches and robot time to the bound on the true error;
    true error and coverage at each strategy's own stop."""
    b = summary["bound"]
    lines = [f"bound: RMS posterior std {b['mean_std_mm'] * 1e3:.1f} um (own stop), true RMS "
             f"error {(b['true_rms_mm'] or b['mean_std_mm']) * 1e3:.1f} um; "
             f"{summary['plates']} plates", "",
             "| strategy | touches to true bound (mean / p90) | robot time (s) | reached | "
             "touches at own stop | true RMS (um) | true max (um) | coverage95 |",
             "|---|---|---|---|---|---|---|---|"]
    for name, s in summary["strategies"].items():
        lines.append(
            f"| {name} | {s['touches_mean']:.1f} / {s['touches_p90']:.0f} | "
            f"{_f(s['robot_time_s_mean'], fmt='{:.0f}')} | {s['true_bound_reached']:.0%} | "
            f"{_f(s['stop_touches_mean'])} | {_f(s['true_rms_mm_mean'], 1e3, '{:.2f}')} | "
            f"{_f(s['true_max_mm_mean'], 1e3, '{:.1f}')} | {_f(s['coverage95_mean'], 1, '{:.3f}')} |")
    lb = summary.get("lower_bound") or {}
    if lb.get("plates"):
        lines += ["", f"lower bound (relaxed optimal design, same hyper-parameters, first "
                  f"{lb['plates']} plates): {_f(lb['relaxed_touches'])} touches; best integer "
                  f"design: {_f(lb['best_integer_touches']) if lb['best_integer_touches'] else 'not computed (too many designs)'}; "
                  f"adaptive at its own stop / relaxed: {_f(lb['adaptive_over_relaxed'], 1, '{:.2f}')}"]
    vp = summary.get("adaptive_vs_paper")
    if vp:
        lines += ["", f"paper's procedure: {vp['paper_touches_mean']:.1f} touches, true RMS "
                  f"{vp['paper_true_rms_mm_mean'] * 1e3:.2f} um; adaptive reaches each plate's "
                  f"paper accuracy with {_f(vp['adaptive_touches_to_paper_accuracy_mean'])} "
                  f"touches ({vp['reached']:.0%} of plates), ratio of means "
                  f"{_f(vp['touch_ratio_of_means'], 1, '{:.2f}')}"]
    return "\n".join(lines)


def write_report(study: Study, summary: dict, records: list[dict], base: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table(summary) + "\n", encoding="utf-8")
    names = list(summary["strategies"])
    by = {s: [r for r in records if r["strategy"] == s] for s in names}

    # touches against bound (posterior and true), from the trajectories
    bounds = np.geomspace(study.bound.mean_std_mm, 8 * study.bound.mean_std_mm, 12)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for s in names:
        for ax, col in zip(axes, (1, 2)):
            med = []
            for b in bounds:
                t = [next((p[0] for p in r["trajectory"] if p[col] <= b), np.nan) for r in by[s]]
                med.append(np.nanmean(t) if np.isfinite(t).any() else np.nan)
            ax.plot(bounds * 1e3, med, "o-", label=s, ms=3)
    for ax, what in zip(axes, ("RMS posterior std", "true RMS error")):
        ax.set_xscale("log")
        ax.set_xlabel(f"bound on the {what} (um)")
        ax.set_ylabel("touches (mean over plates)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out / "touches_vs_bound.png", dpi=110)
    plt.close(fig)

    # coverage at the own stop, per strategy
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.boxplot([[r["coverage95"] for r in by[s]] for s in names], tick_labels=names)
    ax.axhline(0.95, color="k", ls="--", lw=1)
    ax.set_ylabel("share of the plate inside the 95 % band")
    fig.tight_layout()
    fig.savefig(out / "coverage.png", dpi=110)
    plt.close(fig)

    # one example plate per strategy
    wp = base["workplane"]
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.2), squeeze=False)
    for ax, s in zip(axes[0], names):
        rec = next((r for r in by[s] if r["plate"] == study.example_plate), None)
        if rec is None:
            continue
        xy = np.asarray(rec["xy"][: rec["touches"]]).reshape(-1, 2)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="0.7", lw=0.6)
        ax.scatter(xy[:, 0], xy[:, 1], c=np.arange(len(xy)), s=10, cmap="viridis")
        ax.set_title(f"{s}: {rec['touches']} touches\ntrue RMS {rec['true_rms_mm'] * 1e3:.1f} um",
                     fontsize=9)
        ax.set_xlim(wp["x_mm"])
        ax.set_ylim(wp["y_mm"])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(out / "example_plate.png", dpi=110)
    plt.close(fig)
