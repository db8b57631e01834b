"""One self-contained HTML page per run, for whoever adjusts the robot.

    html = render(run_dir)        # reads DIR/result.json, recording.csv, cell.yaml, belief.npz
    write(run_dir)                # DIR/report.html
    render_recording(result, cell, rec, belief, recording, cell_file)   # a replayed recording

The page holds the cell, the touches on the plate, the surface and its uncertainty, the tilt
correction as a controller takes it (rx, ry in deg; frame_new = frame_nominal * rotx(rx) *
roty(ry)), the flatness of the touched points and of the whole plate with 95 % intervals
(``analysis.flatness_answer``'s words), and what ``explain`` found when
DIR/explain.json exists (the pieces: ``sections.py``). Figures are embedded as base64 PNG: the
file can be mailed on its own. Reads files, writes one; no numerical work beyond evaluating the
saved belief on a grid.
"""
from __future__ import annotations

import base64
import datetime as _dt
import io
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from adaptive_cal import __version__
from adaptive_cal.cell.run_cell import load_run_cell
from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.formats.jsonfile import read_result
from adaptive_cal.formats.npz import read_npz, unresolved_at
from adaptive_cal.gaussian.belief import Belief, predict
from adaptive_cal.gaussian.spline import Surface
from adaptive_cal.report import figures as plots
from adaptive_cal.report.status import missing, quoted, unfinished
from adaptive_cal.report.explain_page import explain_section
from adaptive_cal.report.sections import (cards, cell_section, escape,
                                          flatness_section, image, incomplete_banner, run_section,
                                          tilt_section)


# -- figures ---------------------------------------------------------------------------------
def _png(fig: Figure, tight: bool = True) -> str:
    buf = io.BytesIO()
    # "tight": the canvas grows to hold what lies outside the axes (the touches figure's
    # legend on the right; constrained layout with an equal aspect cut it and the y label).
    # It draws the figure twice: the maps, whose legend lies inside, are drawn once.
    fig.savefig(buf, format="png", dpi=100,
                **({"bbox_inches": "tight", "pad_inches": 0.1} if tight else {}))
    return base64.b64encode(buf.getvalue()).decode("ascii")


def touches_figure(cell: Cell, rec) -> Figure:
    """The plate to scale: outline, edge margin, keep-outs hatched, touches numbered in order and
    joined by the travel path; touches not fused (gated, rejected) drawn as red crosses."""
    wp = cell.workplane
    (x0, x1), (y0, y1) = wp.x_mm, wp.y_mm
    ratio = (y1 - y0) / (x1 - x0)
    fig = Figure(figsize=(9.0, max(3.0, 7.0 * ratio) + 0.8), layout="constrained")
    ax = fig.subplots()
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, facecolor="#f4f4f0", edgecolor="black",
                           lw=1.2, label="workplane", zorder=0))
    m = wp.edge_margin_mm
    if m > 0:
        ax.add_patch(Rectangle((x0 + m, y0 + m), x1 - x0 - 2 * m, y1 - y0 - 2 * m, fill=False,
                               ls="--", lw=0.8, edgecolor="0.5", label=f"edge margin {m:g} mm"))
    for k in wp.keep_outs:
        (a0, a1), (b0, b1) = k.x_mm, k.y_mm
        ax.add_patch(Rectangle((a0, b0), a1 - a0, b1 - b0, facecolor="0.8", edgecolor="0.3",
                               hatch="///", label="keep-out", zorder=1))
    fused = rec.fused
    ax.plot(rec.x_mm, rec.y_mm, "-", color="0.6", lw=0.7, label="travel order", zorder=2)
    ax.plot(rec.x_mm[fused], rec.y_mm[fused], "o", ms=5, mfc="white", mec="black", mew=0.8,
            label="touch (fused)", zorder=3)
    if (~fused).any():
        ax.plot(rec.x_mm[~fused], rec.y_mm[~fused], "x", ms=8, color="red", mew=1.5,
                label="touch not fused (gated / rejected)", zorder=4)
    if len(rec) <= 150:
        seqs = [str(int(s)) for s in rec.seq]
        for text, xy in plots.touch_labels(np.c_[rec.x_mm, rec.y_mm], near_frac=0.02):
            label = ",".join(seqs[int(i)] for i in text.split(","))
            ax.annotate(label, xy, xytext=(3, 3), textcoords="offset points", fontsize=8, zorder=5)
    ax.set_xlim(x0 - 0.04 * (x1 - x0), x1 + 0.04 * (x1 - x0))
    ax.set_ylim(y0 - 0.04 * (y1 - y0), y1 + 0.04 * (y1 - y0))
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm, workplane frame)")
    ax.set_ylabel("y (mm, workplane frame)")
    base = cell.robot.base_xy_mm
    where = f"; robot base at ({base[0]:g}, {base[1]:g}) mm" if base else ""
    ax.set_title(f"{len(rec)} touches, numbered in the order taken (seq){where}", fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    ax.legend(unique.values(), unique.keys(), loc="upper left", bbox_to_anchor=(1.01, 1.0),
              fontsize=8)
    return fig


def surface_png(run_dir: Path, cell: Cell, rec, result: dict) -> str | None:
    """The posterior mean (tilt removed) and std maps from DIR/belief.npz; DIR/surface.png when
    the belief was not saved; None when neither exists."""
    path = run_dir / "belief.npz"
    if not path.exists():
        png = run_dir / "surface.png"
        return base64.b64encode(png.read_bytes()).decode("ascii") if png.exists() else None
    return belief_png(read_npz(path), cell, rec, result)


def belief_png(data, cell: Cell, rec, result: dict) -> str:
    """The maps of a belief given as belief.npz holds it (mean, cov, knots_x, knots_y)."""
    ends = result.get("knots_mm", {}).get("ends", cell.model.ends)
    surface = Surface.create(data["knots_x"], data["knots_y"], ends=ends)
    wp = cell.workplane
    gx, gy = np.linspace(*wp.x_mm, 81), np.linspace(*wp.y_mm, 81)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    mean, var = predict(Belief(data["mean"], data["cov"]), surface.basis(xx.ravel(), yy.ravel()))
    var = var + unresolved_at(data, xx.ravel(), yy.ravel())  # the run's bands: surface.png's
    # every touch, so the numbers are the recording's seq (a retake lands where its gated touch did)
    fig = plots.surface_figure(gx, gy, mean.reshape(xx.shape), np.sqrt(np.maximum(var, 0)).reshape(xx.shape),
                               np.c_[rec.x_mm, rec.y_mm], wp.x_mm, wp.y_mm,
                               keep_outs=[(k.x_mm, k.y_mm) for k in wp.keep_outs], title=cell.name,
                               incomplete=missing(result))
    return _png(fig, tight=False)


CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Arial,sans-serif;max-width:1100px;
margin:24px auto;padding:0 20px;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:0.2em}h2{font-size:1.25em;border-bottom:2px solid #ddd;
padding-bottom:4px;margin-top:1.8em}
table{border-collapse:collapse;margin:8px 0 12px}td,th{border:1px solid #ccc;padding:5px 10px;
text-align:left;vertical-align:top}th{background:#f0f0f0}table.kv td:first-child{color:#555;
white-space:nowrap}
.cards{display:flex;flex-wrap:wrap;gap:12px;margin:16px 0}.card{border:1px solid #ccc;
border-radius:6px;padding:10px 14px;min-width:200px;background:#fafafa}.card .v{font-size:1.3em;
font-weight:bold}.card .l{color:#555;font-size:0.85em}
figure{margin:12px 0}img{max-width:100%;border:1px solid #eee}figcaption{color:#555;
font-size:0.85em}.note{color:#555;font-size:0.9em}pre.code{background:#f6f6f6;padding:8px 12px;
border:1px solid #ddd;overflow-x:auto}.verdict{font-size:1.15em}
.incomplete{border:2px solid #c0392b;background:#fdecea;padding:10px 14px;border-radius:6px;
font-size:1.1em}footer{margin-top:2em;color:#777;
font-size:0.8em;border-top:1px solid #ddd;padding-top:6px}
"""


def render(run_dir: str | Path) -> str:
    """The report page of a run folder, as one HTML string."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such folder")
    for name in ("result.json", "recording.csv", "cell.yaml"):
        if not (run_dir / name).exists():
            raise FileNotFoundError(f"{run_dir / name}: missing; " + unfinished(run_dir, name))
    result = read_result(run_dir / "result.json")
    cell = load_run_cell(run_dir / "cell.yaml")
    rec = read_recording(run_dir / "recording.csv")
    conv = run_dir / "convergence.png"
    return page(result, cell, rec, surface_png(run_dir, cell, rec, result),
                base64.b64encode(conv.read_bytes()).decode("ascii") if conv.exists() else None,
                run_dir=run_dir)


def render_recording(result: dict, cell: Cell, rec, belief_data, recording: Path,
                     cell_file: Path) -> str:
    """The page of a bare recording replayed with its cell file (``run.results.result_of``):
    the same sections, said to be built from a recording; no convergence history, no explain."""
    return page(result, cell, rec, belief_png(belief_data, cell, rec, result), None,
                source=(Path(recording), Path(cell_file)))


def _made(meta: dict) -> str:
    """The sentence "Recorded with adaptive-cal V, started YYYY-MM-DD HH:MM:SS UTC." from a
    recording's metadata (``run`` writes both); empty where it has neither (another tool's)."""
    software, started = meta.get("software"), meta.get("started_utc")
    if not software and not started:
        return ""
    said = ", ".join(s for s in (f"with {escape(software)}" if software else "",
                                 f"started {escape(started.replace('T', ' ').rstrip('Z'))} UTC"
                                 if started else "") if s)
    return f" Recorded {said}."


def page(result: dict, cell: Cell, rec, surface_b64: str | None, convergence_b64: str | None,
         run_dir: Path | None = None, source: tuple[Path, Path] | None = None) -> str:
    """The page from its pieces: a run folder's (``run_dir``) or a replayed recording's
    (``source`` = (recording, cell file))."""
    title = f"Workplane map: {cell.name}"
    if source is None:
        origin = (f"Run folder <code>{escape(run_dir.resolve())}</code>.")
        # only what is there; surface.png where there is no belief to draw the maps from
        read = [n for n in ("result.json", "recording.csv", "cell.yaml", "belief.npz",
                            "surface.png") if (run_dir / n).is_file()
                and not (n == "surface.png" and (run_dir / "belief.npz").is_file())]
        footer = f"{escape(run_dir.name)}/" + ", ".join(read)
        resume = f"adaptive-cal run --resume {quoted(run_dir)}"
    else:
        rec_path, cell_path = source
        origin = (f"<b>Built from a recording, not a run:</b> <code>{escape(rec_path.resolve())}"
                  f"</code> replayed with the cell file <code>{escape(cell_path.resolve())}</code> "
                  "(every fused touch, one refit of the hyper-parameters at the end; a run's own "
                  "figures may differ in the last digit).")
        footer = f"{escape(rec_path.name)} replayed with {escape(cell_path.name)}"
        resume = None
    conv_note = ("no convergence history in a recording: the page of the run folder has it"
                 if source else "Posterior std against touches (um, log scale); dashed: the bound.")
    origin += _made(rec.meta)
    body = [
        f"<h1>{escape(title)}</h1>",
        f"<p class='note'>{origin} Lengths in mm (um where marked), angles in deg, heights in the "
        "workplane frame.</p>",
        incomplete_banner(result, resume),
        cards(result, run_dir),
        tilt_section(result["tilt"], provisional=missing(result) is not None,
                     prior_from=result.get("prior_from"),
                     spread=result["flatness_mm"].get("range")),
        flatness_section(result),
        "<h2>Touches on the plate</h2>",
        image(_png(touches_figure(cell, rec)), "touches", "The plate drawn to scale; numbers are the "
             "recording's seq."),
        "<h2>Surface and its uncertainty</h2>",
        image(surface_b64, "surface", "Left: posterior mean height with "
             "the least-squares plane removed (um). Right: posterior standard deviation (um)."),
        "<h2>Convergence</h2>",
        image(convergence_b64, "convergence", conv_note) if convergence_b64 or not source
        else f"<p class='note'>{escape(conv_note)}.</p>",
        run_section(result),
        cell_section(cell, result),
        explain_section(run_dir, result) if run_dir is not None else "",
        f"<footer>adaptive-cal {__version__}, report written "
        f"{_dt.datetime.now().strftime('%Y-%m-%d %H:%M')} from {footer}.</footer>",
    ]
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{escape(title)}</title><style>{CSS}</style></head><body>"
            + "\n".join(body) + "</body></html>\n")


def write(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Write the page to ``out`` (default DIR/report.html) and return its path."""
    out = Path(out) if out else Path(run_dir) / "report.html"
    page = render(run_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out
