"""One self-contained HTML page per run, for whoever adjusts the robot.

    html = render(run_dir)        # reads DIR/result.json, recording.csv, cell.yaml, belief.npz
    write(run_dir)                # DIR/report.html

The page holds the cell, the touches on the plate, the surface and its uncertainty, the tilt
correction as a controller takes it (rx, ry in deg; frame_new = frame_nominal * rotx(rx) *
roty(ry)), the flatness figures with 95 % intervals, and what ``explain`` found when
DIR/explain.json exists. Figures are embedded as base64 PNG: the file can be mailed on its own.
Reads files, writes one; no numerical work beyond evaluating the saved belief on a grid.
"""
from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from adaptive_cal import __version__
from adaptive_cal.cell.schema import Cell, load_cell
from adaptive_cal.formats.recording import read_recording

UM = 1000.0
FLATNESS = (("least_squares", "least squares (Cheng eq. 5)"), ("minimum_zone", "minimum zone (ISO 1101)"),
            ("range", "range, max - min (tilt included)"))
EXPLAIN_FIGURES = ("residual_map.png", "residual_vs_position.png", "residual_vs_time.png",
                   "residual_vs_direction.png", "residual_vs_reach.png",
                   "residual_vs_indication.png", "fitted_effect.png")


def rotation(rx_deg: float, ry_deg: float) -> np.ndarray:
    """rotx(rx) @ roty(ry): the rotation the nominal user frame is multiplied by on the right."""
    a, b = np.radians(rx_deg), np.radians(ry_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return rx @ ry


# -- figures ---------------------------------------------------------------------------------
def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
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
        for s, x, y in zip(rec.seq, rec.x_mm, rec.y_mm):
            ax.annotate(str(int(s)), (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7,
                        zorder=5)
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
    from adaptive_cal.report import figures as plots
    from adaptive_cal.gaussian.belief import Belief, predict
    from adaptive_cal.gaussian.spline import Surface

    path = run_dir / "belief.npz"
    if not path.exists():
        png = run_dir / "surface.png"
        return base64.b64encode(png.read_bytes()).decode("ascii") if png.exists() else None
    data = np.load(path)
    ends = result.get("knots_mm", {}).get("ends", cell.model.ends)
    surface = Surface.create(data["knots_x"], data["knots_y"], ends=ends)
    wp = cell.workplane
    gx, gy = np.linspace(*wp.x_mm, 81), np.linspace(*wp.y_mm, 81)
    xx, yy = np.meshgrid(gx, gy, indexing="ij")
    mean, var = predict(Belief(data["mean"], data["cov"]), surface.basis(xx.ravel(), yy.ravel()))
    # every touch, so the numbers are the recording's seq (a retake lands where its gated touch did)
    fig = plots.surface_figure(gx, gy, mean.reshape(xx.shape), np.sqrt(np.maximum(var, 0)).reshape(xx.shape),
                               np.c_[rec.x_mm, rec.y_mm], wp.x_mm, wp.y_mm,
                               keep_outs=[(k.x_mm, k.y_mm) for k in wp.keep_outs], title=cell.name)
    return _png(fig)


# -- html pieces ---------------------------------------------------------------------------------
def _e(v) -> str:
    return html.escape(str(v))


def _img(b64: str | None, alt: str, caption: str) -> str:
    if b64 is None:
        return f"<p class='note'>{_e(alt)}: no figure in the run folder.</p>"
    return (f"<figure><img alt='{_e(alt)}' src='data:image/png;base64,{b64}'>"
            f"<figcaption>{_e(caption)}</figcaption></figure>")


def _table(rows, head=None, cls="") -> str:
    out = [f"<table class='{cls}'>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>")
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>")
    return "".join(out) + "</table>"


def _um(mm) -> str:
    return "-" if mm is None else f"{mm * UM:.1f} um"


def _interval(f: dict) -> str:
    lo, hi = f.get("ci95", [None, None])
    if lo is None:
        return "-"
    return f"{lo:.4f} .. {hi:.4f} mm"


def _cell_section(cell: Cell, result: dict) -> str:
    wp, pr, st = cell.workplane, cell.probe, cell.plan.stop
    k = result.get("knots_mm", {})
    rows = [
        ("name", _e(cell.name)),
        ("robot adapter / probe adapter", f"{_e(cell.robot.adapter)} / {_e(pr.adapter)}"),
        ("workplane", f"x {wp.x_mm[0]:g} .. {wp.x_mm[1]:g} mm, y {wp.y_mm[0]:g} .. {wp.y_mm[1]:g} mm "
                      f"({wp.x_mm[1] - wp.x_mm[0]:g} x {wp.y_mm[1] - wp.y_mm[0]:g} mm), edge margin "
                      f"{wp.edge_margin_mm:g} mm, {len(wp.keep_outs)} keep-out(s)"),
        ("probe", f"stroke {pr.stroke_mm:g} mm, usable {pr.usable_mm[0]:g} .. {pr.usable_mm[1]:g} mm, "
                  f"zero {pr.zero_mm:g} mm, resolution {pr.resolution_mm * UM:g} um"),
        ("stopping bound", ", ".join(filter(None, [
            f"RMS posterior std {_um(st.mean_std_mm)}" if st.mean_std_mm else "",
            f"max posterior std {_um(st.max_std_mm)}" if st.max_std_mm else "",
            f"at most {st.max_touches} touches"]))),
        ("spline knots", f"{len(k.get('x', []))} x {len(k.get('y', []))}, {_e(k.get('ends', '-'))} ends"
                         if k else "-"),
    ]
    return "<h2>The cell</h2>" + _table(rows, cls="kv")


def _run_section(result: dict) -> str:
    p, h = result["posterior"], result.get("hyper", {})
    rows = [("touches", f"{result['touches']} ({result['fused']} fused)"),
            ("stopped because", _e(result["stopped_because"].replace("_", " "))),
            ("posterior std over the plate", f"RMS {_um(p['mean_std_mm'])}, max {_um(p['max_std_mm'])}"),
            ("reading noise (learned)", _um(h.get("noise_std_mm"))),
            ("form prior (learned)", f"amplitude {_um(h.get('form_std_mm'))}, length scale "
                                     f"{h.get('length_scale_mm', float('nan')):.0f} mm")]
    if "truth" in result:
        t = result["truth"]
        rows.append(("simulated cell: true error", f"RMS {_um(t['rms_error_mm'])}, max "
                     f"{_um(t['max_error_mm'])}; the 95 % band covers {t['coverage95']:.0%} of the plate"))
    return "<h2>The run</h2>" + _table(rows, cls="kv")


def _tilt_section(tilt: dict) -> str:
    rx, ry = tilt["rx_deg"], tilt["ry_deg"]
    R = rotation(rx, ry)
    sx, sy = tilt.get("rx_std_deg"), tilt.get("ry_std_deg")
    pm = lambda s: "" if s is None else f" &plusmn; {s:.4f}"
    rows = [("rx (about the user frame's x axis)", f"<b>{rx:+.4f} deg</b>{pm(sx)} ({np.radians(rx):+.6f} rad)"),
            ("ry (about the rotated y axis)", f"<b>{ry:+.4f} deg</b>{pm(sy)} ({np.radians(ry):+.6f} rad)"),
            ("fitted plane z = a x + b y + c", f"a {tilt['a']:+.6f} mm/mm, b {tilt['b']:+.6f} mm/mm, "
                                              f"c {tilt['c']:+.4f} mm"),
            ("height change over 100 mm", f"along x {tilt['a'] * 100 * UM:+.1f} um, along y "
                                          f"{tilt['b'] * 100 * UM:+.1f} um")]
    matrix = "<br>".join("[" + "  ".join(f"{v:+.6f}" for v in row) + "]" for row in R)
    return ("<h2>Tilt correction for the controller</h2>"
            "<p>Rotate the user frame so its z axis is the plate normal:</p>"
            f"<pre class='code'>frame_new = frame_nominal * rotx({rx:+.4f} deg) * roty({ry:+.4f} deg)\n"
            f"# RoboDK (radians): frame_new = frame_nominal * rotx({np.radians(rx):+.6f}) * "
            f"roty({np.radians(ry):+.6f})</pre>"
            + _table(rows, cls="kv")
            + f"<p>rotx(rx) roty(ry), the rotation to multiply on the right (no translation):</p>"
              f"<pre class='code'>{matrix}</pre>"
              "<p class='note'>± is one posterior standard deviation (surfaces sampled from the "
              "belief). c is the plate height at the frame origin, measured from where the probe "
              "reads its zero: moving the frame origin by +c along z puts it on the plate.</p>")


def _flatness_section(result: dict) -> str:
    fl = result["flatness_mm"]
    rows = []
    for key, name in FLATNESS:
        if key in fl:
            f = fl[key]
            rows.append((name, f"<b>{f['value']:.4f} mm</b>", _interval(f), _um(f["value"])))
    return ("<h2>Flatness</h2>"
            + _table(rows, head=("figure", "value", "95 % interval", "in um"))
            + "<p class='note'>Value: the figure of the posterior mean surface over the whole plate. "
              "Interval: the same figure over surfaces sampled from the belief. Least squares and "
              "minimum zone are measured normal to the planes; range includes the tilt.</p>")


def _explain_section(run_dir: Path) -> str:
    path = run_dir / "explain.json"
    if not path.exists():
        return ("<h2>Explain</h2><p class='note'>No explain findings in this folder. To compare the "
                "recording with the cell's simulation: <code>adaptive-cal explain "
                f"{_e(run_dir / 'recording.csv')} --robot CELL.yaml --json {_e(path)} --out "
                f"{_e(run_dir)}</code>, then run the report again.</p>")
    rep = json.loads(path.read_text(encoding="utf-8"))
    fit = rep.get("fit", {})
    parts = ["<h2>Explain: what the simulation left out</h2>",
             f"<p class='verdict'>verdict: <b>{_e(rep.get('verdict', '-'))}</b>"
             + (" (no left-out effect is supported by the data)" if rep.get("verdict") == "none" else "")
             + "</p>"]
    rows = [(_e(e["effect"]), _e(e["summary"])) for e in rep.get("left_out", [])]
    if rows:
        parts.append(_table(rows, head=("effect", "fitted (log Bayes factor against none)")))
    if fit:
        parts.append(_table([
            ("RMS residual", f"{_um(fit.get('rms_before_mm'))} &rarr; {_um(fit.get('rms_after_mm'))}"),
            ("leave-one-out RMS", f"{_um(fit.get('cv_rms_before_mm'))} &rarr; "
                                  f"{_um(fit.get('cv_rms_after_mm'))}")],
            head=("fit", "nominal → with the effect"), cls="kv"))
    by = rep.get("mismatch", {}).get("by", {})
    if by:
        parts.append(_table([(_e(k), f"{v['p_value']:.3g}" + (" <b>real</b>" if v.get("real") else "")
                              if v.get("p_value") is not None else _e(v.get("note", "-")))
                             for k, v in by.items()],
                            head=("residual against", "F-test p (small = a real trend)"), cls="kv"))
    r = rep.get("rounds")
    if r and "p_value" in r:
        lo, hi = r["null_change_95_mm"]
        real = "larger than" if r.get("exceeds_noise") else "within"
        parts.append(f"<p>Rounds: flatness {r['flatness_mm'][0]:.4f} &rarr; {r['flatness_mm'][1]:.4f} "
                     f"mm, change {r['change_mm']:+.4f} mm; noise alone gives 95 % within "
                     f"[{lo:+.4f}, {hi:+.4f}] mm (repeatability {_um(r['repeatability_mm'])}), "
                     f"p = {r['p_value']:.3f}: the change is <b>{real}</b> what noise gives.</p>")
    ni = rep.get("not_identifiable", [])
    if ni:
        parts.append("<p>Not identifiable from this recording:</p><ul>" + "".join(
            f"<li><b>{_e(e['effect'])}</b>: {_e(e['why'])}</li>" for e in ni) + "</ul>")
    for name in EXPLAIN_FIGURES:
        p = run_dir / name
        if p.exists():
            parts.append(_img(base64.b64encode(p.read_bytes()).decode("ascii"), name, name))
    return "".join(parts)


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
border:1px solid #ddd;overflow-x:auto}.verdict{font-size:1.15em}footer{margin-top:2em;color:#777;
font-size:0.8em;border-top:1px solid #ddd;padding-top:6px}
"""


def _cards(result: dict, run_dir: Path) -> str:
    t, ls, p = result["tilt"], result["flatness_mm"]["least_squares"], result["posterior"]
    cards = [(f"rx {t['rx_deg']:+.4f} deg<br>ry {t['ry_deg']:+.4f} deg", "tilt correction"),
             (f"{ls['value']:.4f} mm", f"flatness, least squares (95 % {_interval(ls)})"),
             (f"{_um(p['mean_std_mm'])}", f"RMS posterior std after {result['touches']} touches")]
    ex = run_dir / "explain.json"
    if ex.exists():
        cards.append((_e(json.loads(ex.read_text(encoding="utf-8")).get("verdict", "-")),
                      "explain verdict (left-out physics)"))
    return "<div class='cards'>" + "".join(
        f"<div class='card'><div class='v'>{v}</div><div class='l'>{l}</div></div>" for v, l in cards) + "</div>"


def render(run_dir: str | Path) -> str:
    """The report page of a run folder, as one HTML string."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such folder")
    for name in ("result.json", "recording.csv", "cell.yaml"):
        if not (run_dir / name).exists():
            raise FileNotFoundError(f"{run_dir / name}: missing; is {run_dir} a folder written by "
                                    "'adaptive-cal run --out DIR'?")
    result = json.loads((run_dir / "result.json").read_text(encoding="utf-8"))
    cell = load_cell(run_dir / "cell.yaml")
    rec = read_recording(run_dir / "recording.csv")
    conv = run_dir / "convergence.png"
    title = f"Workplane map: {cell.name}"
    body = [
        f"<h1>{_e(title)}</h1>",
        f"<p class='note'>Run folder <code>{_e(run_dir.resolve())}</code>. Lengths in mm (um where "
        "marked), angles in deg, heights in the workplane frame.</p>",
        _cards(result, run_dir),
        _tilt_section(result["tilt"]),
        _flatness_section(result),
        "<h2>Touches on the plate</h2>",
        _img(_png(touches_figure(cell, rec)), "touches", "The plate drawn to scale; numbers are the "
             "recording's seq."),
        "<h2>Surface and its uncertainty</h2>",
        _img(surface_png(run_dir, cell, rec, result), "surface", "Left: posterior mean height with "
             "the least-squares plane removed (um). Right: posterior standard deviation (um)."),
        "<h2>Convergence</h2>",
        _img(base64.b64encode(conv.read_bytes()).decode("ascii") if conv.exists() else None,
             "convergence", "Posterior std against touches (um, log scale); dashed: the bound."),
        _run_section(result),
        _cell_section(cell, result),
        _explain_section(run_dir),
        f"<footer>adaptive-cal {__version__}, report written "
        f"{_dt.datetime.now().strftime('%Y-%m-%d %H:%M')} from {_e(run_dir.name)}/result.json, "
        "recording.csv, cell.yaml, belief.npz.</footer>",
    ]
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{_e(title)}</title><style>{CSS}</style></head><body>"
            + "\n".join(body) + "</body></html>\n")


def write(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Write the page to ``out`` (default DIR/report.html) and return its path."""
    out = Path(out) if out else Path(run_dir) / "report.html"
    page = render(run_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out
