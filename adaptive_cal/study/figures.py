"""The figures of a study, object API only (``matplotlib.figure.Figure``, ``fig.savefig``; no
pyplot state): touches against bound per strategy, coverage at the own stop, and one example
plate per strategy with its touches. ``write_summary`` writes them with the table to a folder."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from adaptive_cal.study.config import Study
from adaptive_cal.study.summary import table

DPI = 110


def _by_strategy(summary: dict, records: list[dict]) -> dict[str, list[dict]]:
    return {s: [r for r in records if r["strategy"] == s] for s in summary["strategies"]}


def touches_vs_bound_figure(study: Study, summary: dict, records: list[dict]) -> Figure:
    """Mean touches over plates to reach each bound on the RMS posterior std (left) and on the
    true RMS error (right), read off each record's trajectory."""
    by = _by_strategy(summary, records)
    bounds = np.geomspace(study.bound.mean_std_mm, 8 * study.bound.mean_std_mm, 12)
    fig = Figure(figsize=(11, 4))
    axes = fig.subplots(1, 2)
    for s, recs in by.items():
        for ax, col in zip(axes, (1, 2)):
            med = []
            for b in bounds:
                t = [next((p[0] for p in r["trajectory"] if p[col] <= b), np.nan) for r in recs]
                med.append(np.nanmean(t) if np.isfinite(t).any() else np.nan)
            ax.plot(bounds * 1e3, med, "o-", label=s, ms=3)
    for ax, what in zip(axes, ("RMS posterior std", "true RMS error")):
        ax.set_xscale("log")
        ax.set_xlabel(f"bound on the {what} (um)")
        ax.set_ylabel("touches (mean over plates)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    return fig


def coverage_figure(summary: dict, records: list[dict]) -> Figure:
    """Share of the plate inside the posterior 95 % band at each strategy's own stop."""
    by = _by_strategy(summary, records)
    fig = Figure(figsize=(6, 3.5))
    ax = fig.subplots()
    ax.boxplot([[r["coverage95"] for r in recs] for recs in by.values()],
               tick_labels=list(by))
    ax.axhline(0.95, color="k", ls="--", lw=1)
    ax.set_ylabel("share of the plate inside the 95 % band")
    fig.tight_layout()
    return fig


def example_plate_figure(study: Study, summary: dict, records: list[dict], base: dict) -> Figure:
    """The study's example plate under every strategy: its touches up to the own stop, in order."""
    by = _by_strategy(summary, records)
    wp = base["workplane"]
    fig = Figure(figsize=(3.4 * len(by), 3.2))
    axes = fig.subplots(1, len(by), squeeze=False)
    for ax, (s, recs) in zip(axes[0], by.items()):
        rec = next((r for r in recs if r["plate"] == study.example_plate), None)
        if rec is None:
            continue
        xy = np.asarray(rec["xy"][: rec["touches"] - bool(rec.get("closure"))]).reshape(-1, 2)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="0.7", lw=0.6)
        ax.scatter(xy[:, 0], xy[:, 1], c=np.arange(len(xy)), s=10, cmap="viridis")
        ax.set_title(f"{s}: {rec['touches']} touches\ntrue RMS {rec['true_rms_mm'] * 1e3:.1f} um",
                     fontsize=9)
        ax.set_xlim(wp["x_mm"])
        ax.set_ylim(wp["y_mm"])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig


def write_summary(study: Study, summary: dict, records: list[dict], base: dict,
                  out: Path) -> None:
    """OUT/table.md, touches_vs_bound.png, coverage.png and example_plate.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table(summary) + "\n", encoding="utf-8")
    for name, fig in (("touches_vs_bound.png", touches_vs_bound_figure(study, summary, records)),
                      ("coverage.png", coverage_figure(summary, records)),
                      ("example_plate.png", example_plate_figure(study, summary, records, base))):
        fig.savefig(out / name, dpi=DPI)
