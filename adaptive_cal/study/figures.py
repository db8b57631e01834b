"""The figures of a study, object API only (``matplotlib.figure.Figure``, ``fig.savefig``; no
pyplot state): touches against bound per strategy, coverage at the own stop, and one example
plate per strategy with its touches. ``write_summary`` writes them with the table to a folder."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, ScalarFormatter

from adaptive_cal.study.config import Study
from adaptive_cal.study.summary import count, table

DPI = 110


def _by_strategy(summary: dict, records: list[dict]) -> dict[str, list[dict]]:
    return {s: [r for r in records if r["strategy"] == s] for s in summary["strategies"]}


def touches_vs_bound_figure(study: Study, summary: dict, records: list[dict]) -> Figure:
    """Mean touches over plates to reach each bound on the RMS posterior std (left) and on the
    true RMS error (right), read off each record's trajectory. A plate that never reached a bound
    counts at the touch budget, as in the table (an outside audit: averaged over the plates that
    reached it, a strategy that reached it on fewer -- the easy -- plates looked cheaper); such a
    point is drawn hollow."""
    by = _by_strategy(summary, records)
    bounds = np.geomspace(study.bound.mean_std_mm, 8 * study.bound.mean_std_mm, 12)
    budget = study.bound.max_touches
    fig = Figure(figsize=(11, 4.3))
    axes = fig.subplots(1, 2)
    for s, recs in by.items():
        for ax, col in zip(axes, (1, 2)):
            mean, every = [], []
            for b in bounds:
                t = [next((p[0] for p in r["trajectory"] if p[col] <= b), None) for r in recs]
                mean.append(np.mean([budget if x is None else x for x in t]))
                every.append(all(x is not None for x in t))
            line, = ax.plot(bounds * 1e3, mean, "-", label=s)
            for hollow in (False, True):
                keep = [e != hollow for e in every]
                ax.plot(bounds[keep] * 1e3, np.asarray(mean)[keep], "o", ms=4,
                        color=line.get_color(), mfc="white" if hollow else line.get_color())
    for ax, what in zip(axes, ("RMS posterior std", "true RMS error")):
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())  # 20, 30 rather than 2x10^1
        ax.xaxis.set_minor_formatter(FuncFormatter(_plain))
        ax.set_xlabel(f"bound on the {what} (um)")
        ax.set_ylabel(f"touches (mean over plates; hollow: some never\nreached it, counted at "
                      f"the budget of {budget})", fontsize=9)
        ax.set_title(f"touches to reach a bound on the {what}", fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"study {study.name}: touches against the bound, "
                 f"{count(len(_plate_ids(records)))}", fontsize=11)
    fig.tight_layout()
    return fig


def _plain(v, _pos=None) -> str:
    """A log axis' minor tick as a plain number, only where there is room (2, 3, 5 x 10^k)."""
    lead = v / 10 ** np.floor(np.log10(v))
    return f"{v:g}" if round(lead) in (2, 3, 5) and abs(lead - round(lead)) < 1e-6 else ""


def _plate_ids(records: list[dict]) -> set:
    return {r["plate"] for r in records}


def coverage_figure(summary: dict, records: list[dict]) -> Figure:
    """Share of the plate inside the posterior 95 % band at each strategy's own stop."""
    by = _by_strategy(summary, records)
    fig = Figure(figsize=(6.5, 4))
    ax = fig.subplots()
    ax.boxplot([[r["coverage95"] for r in recs] for recs in by.values()],
               tick_labels=list(by))
    ax.axhline(0.95, color="k", ls="--", lw=1, label="nominal 95 %")
    ax.set_xlabel("strategy (each at its own stop)")
    ax.set_ylabel("share of the plate inside the 95 % band")
    ax.set_title(f"study {summary['study']}: coverage of the posterior 95 % band, "
                 f"{count(len(_plate_ids(records)))}", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return fig


def example_plate_figure(study: Study, summary: dict, records: list[dict], base: dict) -> Figure:
    """The study's example plate under every strategy: its touches up to the own stop, in order
    (colour: first to last; the closure touch, a return to the first touch, is not drawn)."""
    by = _by_strategy(summary, records)
    wp = base["workplane"]
    fig = Figure(figsize=(3.4 * len(by) + 0.8, 3.6), layout="constrained")
    axes = fig.subplots(1, len(by), squeeze=False)
    seed, dots = None, None
    for k, (ax, (s, recs)) in enumerate(zip(axes[0], by.items())):
        rec = next((r for r in recs if r["plate"] == study.example_plate), None)
        ax.set_xlabel("x (mm)", fontsize=8)
        if k == 0:
            ax.set_ylabel("y (mm)", fontsize=8)
        ax.set_xlim(wp["x_mm"])
        ax.set_ylim(wp["y_mm"])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        if rec is None:
            ax.set_title(f"{s}: not run on this plate", fontsize=9)
            continue
        seed = rec.get("seed", seed)
        xy = np.asarray(rec["xy"][: rec["touches"] - bool(rec.get("closure"))]).reshape(-1, 2)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="0.7", lw=0.6)
        order = np.arange(len(xy)) / max(len(xy) - 1, 1)
        dots = ax.scatter(xy[:, 0], xy[:, 1], c=order, s=10, cmap="viridis", vmin=0, vmax=1)
        closure = " (+1 closure)" if rec.get("closure") else ""
        ax.set_title(f"{s}: {rec['touches'] - bool(rec.get('closure'))} touches{closure}\n"
                     f"true RMS {rec['true_rms_mm'] * 1e3:.1f} um", fontsize=9)
    seed_text = "" if seed is None else f" (seed {seed})"
    fig.suptitle(f"study {study.name}: plate {study.example_plate}{seed_text}, each strategy's "
                 "touches up to its own stop", fontsize=10)
    if dots is not None:
        bar = fig.colorbar(dots, ax=list(axes[0]), fraction=0.015, pad=0.01, ticks=[0, 1])
        bar.ax.set_yticklabels(["first", "last"], fontsize=7)
        bar.set_label("touch order", fontsize=8)
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
