"""The pieces of a run's HTML page: the cell, the run, the tilt correction for the controller,
flatness with 95 % intervals, what ``explain`` found, and the headline cards. Each takes the run's
saved data (result.json, explain.json) and returns an HTML string; numbers are formatted here,
never computed."""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from adaptive_cal.analysis.local_features import feature_line, weighted_out_line
from adaptive_cal.analysis.flatness_answer import (FIGURES, MEDIAN, MEDIAN_NOTE, OUTSIDE,
                                                   OUTSIDE_NOTE, PLATE, PLATE_CALIBRATION,
                                                   SPREAD, gap_line,
                                                   touched_what, value_text, within_what)
from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.jsonfile import read_json
from adaptive_cal.formats.numbers import count, fixed
from adaptive_cal.gaussian.kernels import KERNEL_NAMES
from adaptive_cal.report.explain_text import stale
from adaptive_cal.report.status import missing, next_step

UM = 1000.0
def rotation(rx_deg: float, ry_deg: float) -> np.ndarray:
    """rotx(rx) @ roty(ry): the rotation the nominal user frame is multiplied by on the right."""
    a, b = np.radians(rx_deg), np.radians(ry_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return rx @ ry


def escape(v) -> str:
    return html.escape(str(v))


def image(b64: str | None, alt: str, caption: str) -> str:
    if b64 is None:
        return f"<p class='note'>{escape(alt)}: no figure in the run folder.</p>"
    return (f"<figure><img alt='{escape(alt)}' src='data:image/png;base64,{b64}'>"
            f"<figcaption>{escape(caption)}</figcaption></figure>")


def _table(rows, head=None, cls="") -> str:
    out = [f"<table class='{cls}'>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>")
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>")
    return "".join(out) + "</table>"


def _um(mm, digits: int = 1) -> str:
    return "-" if mm is None else f"{fixed(mm * UM, digits)} um"


def signed(value: float, digits: int) -> str:
    """``value`` with its sign and ``digits`` decimals, never "-0.0..." (a value that rounds to
    zero prints "+0.0...")."""
    return fixed(value, digits, "+")


def tilt_angles(tilt: dict) -> str:
    """"rx +0.1088 +- 0.0004 deg, ry -0.8021 +- 0.0004 deg (1 sd)" -- the sds where the tilt has
    them (a run's map), the angles alone where not (a bare recording's touched points)."""
    sd = [tilt.get(f"{k}_std_deg") for k in ("rx", "ry")]
    if None in sd:
        return f"rx {signed(tilt['rx_deg'], 4)} deg, ry {signed(tilt['ry_deg'], 4)} deg"
    return (f"rx {signed(tilt['rx_deg'], 4)} +- {sd[0]:.4f} deg, ry {signed(tilt['ry_deg'], 4)} "
            f"+- {sd[1]:.4f} deg (1 sd)")


def percent(share: float) -> str:
    """A share as the outputs write percentages: "98 %" (a space, as in "95 % band")."""
    return f"{share * 100:.0f} %"


#: stop reasons in words where they differ from the name with spaces (the names are result.json's
#: stable interface; "mean_std_bound" is the bound on the RMS std over the plate)
REASON_WORDS = {"mean_std_bound": "RMS std bound", "max_std_bound": "max std bound",
                "gap_bound": "largest-gap bound", "at_least": "touch floor"}
#: what happened, for the summary's "stopped:" line (a bound is met, a budget spent)
REASON_DONE = {"mean_std_bound": "met", "max_std_bound": "met", "gap_bound": "met",
               "touch_budget": "spent", "at_least": "reached"}


def _kernels(hyper: dict) -> str:
    """The form kernel of result.json's ``hyper``, with each kernel's evidence share."""
    name = KERNEL_NAMES.get(hyper["kernel"], hyper["kernel"])
    shares = hyper.get("kernel_weights") or {}
    if len(shares) < 2:
        return name
    ranked = sorted(shares.items(), key=lambda kw: -kw[1])
    return f"{name} (weights " + ", ".join(f"{KERNEL_NAMES.get(k, k)} {w:.2f}"
                                           for k, w in ranked) + ")"


def reason_text(why: str) -> str:
    """A stop reason in words: "RMS std bound", "touch budget", ..."""
    return REASON_WORDS.get(why, why.replace("_", " "))


def stopped_text(why: str) -> str:
    """The run summary's reason: the words, what happened, then result.json's name where it
    differs from the words -- "RMS std bound met (mean_std_bound)", "touch budget spent"."""
    words = " ".join(filter(None, (reason_text(why), REASON_DONE.get(why))))
    return words if why.replace("_", " ") == reason_text(why) else f"{words} ({why})"


def cell_section(cell: Cell, result: dict) -> str:
    wp, pr, st = cell.workplane, cell.probe, cell.plan.stop
    k = result.get("knots_mm", {})
    rows = [
        ("name", escape(cell.name)),
        ("robot adapter / probe adapter", f"{escape(cell.robot.adapter)} / {escape(pr.adapter)}"),
        ("workplane", f"x {wp.x_mm[0]:g} .. {wp.x_mm[1]:g} mm, y {wp.y_mm[0]:g} .. {wp.y_mm[1]:g} mm "
                      f"({wp.x_mm[1] - wp.x_mm[0]:g} x {wp.y_mm[1] - wp.y_mm[0]:g} mm), edge margin "
                      f"{wp.edge_margin_mm:g} mm, {len(wp.keep_outs)} keep-out(s)"),
        ("probe", f"stroke {pr.stroke_mm:g} mm, usable {pr.usable_mm[0]:g} .. {pr.usable_mm[1]:g} mm, "
                  f"zero {pr.zero_mm:g} mm, resolution {pr.resolution_mm * UM:g} um"),
        ("stopping bound", ", ".join(filter(None, [
            f"RMS posterior std {_um(st.mean_std_mm)}" if st.mean_std_mm else "",
            f"max posterior std {_um(st.max_std_mm)}" if st.max_std_mm else "",
            f"no gap wider than {st.max_gap_mm:g} mm" if st.max_gap_mm else "",
            f"at most {st.max_touches} touches"]))),
        ("spline knots", f"{len(k.get('x', []))} x {len(k.get('y', []))}, {escape(k.get('ends', '-'))} ends"
                         if k else "-"),
    ]
    return "<h2>The cell</h2>" + _table(rows, cls="kv")


def _robot_time(result: dict) -> str:
    """Touches and robot time side by side (result.json before robot time was written: '-')."""
    if result.get("robot_time_s") is None:
        return "-"
    how, clock = result.get("robot_time_is"), result.get("clock_s")
    return (f"about {result['robot_time_s'] / 60:.1f} min for {result['touches']} touches "
            f"({result['travel_mm'] / 1000:.1f} m of travel)"
            + (f"; the cell's own clock read {clock / 60:.1f} min at the last reading"
               if clock is not None else "") + (f"; {escape(how)}" if how else ""))


def run_section(result: dict) -> str:
    p, h = result["posterior"], result.get("hyper", {})
    pf = result.get("prior_from")
    how = "(carried from the earlier run)" if pf else "(learned)"
    rows = [("touches", f"{result['touches']} ({result['fused']} fused)"),
            ("robot time (estimate)", _robot_time(result)),
            ("stopped because", escape(reason_text(result["stopped_because"]))),
            ("posterior std over the plate", f"RMS {_um(p['mean_std_mm'], 2)}, max "
                                             f"{_um(p['max_std_mm'], 2)}"),  # the terminal's digits
            (f"reading noise {how}", _um(h.get("noise_std_mm"))),
            (f"form prior {how}", f"amplitude {_um(h.get('form_std_mm'))}, length scale "
                                  f"{h.get('length_scale_mm', float('nan')):.0f} mm"
                                  + (f", {_kernels(h)}" if h.get("kernel") else ""))]
    if pf:
        c = pf.get("correction_deg") or {}
        rows.insert(0, ("a re-check of", f"{escape(str(pf.get('run', '-')))}, its belief the "
                        f"prior, the correction assumed applied: {escape(str(pf.get('assumed')))}"
                        + (f" (rx {signed(c['rx'], 4)}, ry {signed(c['ry'], 4)} deg)"
                           if 'rx' in c and 'ry' in c else "")))
    if "truth" in result:
        t = result["truth"]
        rows.append(("simulated cell: true error", f"RMS {_um(t['rms_error_mm'], 2)}, max "
                     f"{_um(t['max_error_mm'], 2)}; the 95 % band covers {percent(t['coverage95'])} of the "
                     "plate"))
    return "<h2>The run</h2>" + _table(rows, cls="kv") + model_section(result)


def model_section(result: dict) -> str:
    """Whether the spline's self-checks passed, and where the map should not be trusted."""
    m = result.get("model")
    if not m:
        return ""
    rows = [("verdict", escape(m.get("summary", "")))]
    rows += [(escape(k), f"{'passed' if c['passed'] else 'FAILED'}: "
              + (f"{c['value'] * 1e3:.3g} um (bound {c['bound'] * 1e3:.3g} um; "  # heights in um
                 if "(mm)" in c.get("is", "") else f"{c['value']:.3g} (bound {c['bound']:.3g}; ")
              + f"{escape(c.get('is', '').replace('(mm) ', ''))})")
             for k, c in m.get("checks", {}).items()]
    rows += [(f"x {w['x_mm'][0]:.0f}..{w['x_mm'][1]:.0f} mm, y {w['y_mm'][0]:.0f}.."
              f"{w['y_mm'][1]:.0f} mm", f"about {_um(w['unresolved_rms_mm'])} RMS unresolved "
              f"({count(w['readings'], 'reading')}): do not trust the map here to better than this")
             for w in m.get("where", [])]
    rows += [("keep-out", escape(k["text"])) for k in result.get("keep_outs") or ()
             if k.get("text")]  # never touched: what the map under it rests on
    c = result.get("closure")
    if c:  # the closure touch: did the cell drift during the run?
        rows.append(("closure touch (drift)", escape(c.get("text", ""))))
    return "<h3>Is the model adequate?</h3>" + _table(rows, cls="kv")


def incomplete_banner(result: dict, resume: str | None) -> str:
    """The page's opening line for an unfinished run (interrupted, budget spent, bound not met);
    nothing for a finished one. ``resume``: the command that continues it (None for a recording)."""
    gap = missing(result)
    if gap is None:
        return ""
    then = f"{escape(next_step(result, resume))}, then write this report again."
    said = (f"<br><b>What stopped the run:</b> {escape(result['error'])}"
            if result.get("error") else "")  # a device's failure, as the terminal said it
    return (f"<p class='incomplete'><b>INCOMPLETE: {escape(gap)}.</b> This map is not a result: "
            "the tilt correction and the flatness below are provisional; do not correct the frame "
            f"from them. {then}{said}</p>")


def _dof_note(tilt: dict) -> str:
    """How the tilt's std counts the learned noise (``analysis.flatness_answer.t_std_factor``)."""
    nu = tilt.get("noise_dof")
    if nu is None:
        return ""
    return (f", widened for the learned reading noise's own uncertainty: a Student-t on {nu:.1f} "
            "degrees of freedom, given as the sd with the same 2-sd interval")


def tilt_section(tilt: dict, provisional: bool = False, spread: dict | None = None,
                 prior_from: dict | None = None) -> str:
    """The correction for the controller; ``spread``: the raw height spread of the plate (max -
    min, the tilt included), shown here, never under Flatness; ``prior_from``: a re-check's
    earlier run, whose corrected frame is the one this correction goes on top of."""
    rx, ry = tilt["rx_deg"], tilt["ry_deg"]
    R = rotation(rx, ry)
    sx, sy = tilt.get("rx_std_deg"), tilt.get("ry_std_deg")
    pm = lambda s: "" if s is None else f" &plusmn; {s:.4f} deg"
    rows = [("rx (about the user frame's x axis)",
             f"<b>{signed(rx, 4)} deg</b>{pm(sx)} ({signed(np.radians(rx), 6)} rad)"),
            ("ry (about the rotated y axis)",
             f"<b>{signed(ry, 4)} deg</b>{pm(sy)} ({signed(np.radians(ry), 6)} rad)"),
            ("fitted plane z = a x + b y + c", f"a {signed(tilt['a'], 6)} mm/mm, b "
                                              f"{signed(tilt['b'], 6)} mm/mm, "
                                              f"c {signed(tilt['c'], 4)} mm"),
            ("height change over 100 mm", f"along x {signed(tilt['a'] * 100 * UM, 1)} um, along y "
                                          f"{signed(tilt['b'] * 100 * UM, 1)} um")]
    if spread:
        rows.append((SPREAD.replace(" (not flatness)", ", whole plate"), escape(value_text(spread))))
    matrix = "<br>".join("[" + "  ".join(signed(v, 6) for v in row) + "]" for row in R)
    head = ("<h2>Tilt correction for the controller (provisional)</h2><p><b>Provisional:</b> "
            "the map is not a result (the top of the page says why and what to do); do not "
            "correct the frame from it.</p>" if provisional
            else "<h2>Tilt correction for the controller</h2>")
    if prior_from:
        c = prior_from.get("correction_deg") or {}
        done = (f"rotx({signed(c['rx'], 4)} deg) * roty({signed(c['ry'], 4)} deg)"
                if {"rx", "ry"} <= c.keys() else "its correction")
        head += (f"<p><b>A re-check:</b> frame_nominal below is the frame already corrected "
                 f"after {escape(prior_from.get('run', 'the earlier run'))} ({done} assumed "
                 "applied, the original frame times that): apply this on top of that frame, not "
                 "on the original one.</p>")
    return (head + "<p>Rotate the user frame so its z axis is the plate normal:</p>"
            f"<pre class='code'>frame_new = frame_nominal * rotx({signed(rx, 4)} deg) * "
            f"roty({signed(ry, 4)} deg)\n"
            f"# RoboDK (radians): frame_new = frame_nominal * rotx({signed(np.radians(rx), 6)}) * "
            f"roty({signed(np.radians(ry), 6)})</pre>"
            + _table(rows, cls="kv")
            + f"<p>rotx(rx) roty(ry), the rotation to multiply on the right (no translation):</p>"
              f"<pre class='code'>{matrix}</pre>"
              f"<p class='note'>± is one posterior standard deviation (surfaces sampled from the "
              f"belief{_dof_note(tilt)}). c is the plate height at the frame origin, measured "
              "from where the probe reads its zero: moving the frame origin by +c along z puts "
              "it on the plate.</p>")


def flatness_section(result: dict) -> str:
    """Both answers (``analysis.flatness_answer``), in the words and digits of the terminal."""
    rows, used = [], []
    touched, plate = result.get("touched_flatness_mm"), result["flatness_mm"]
    within = result.get("flatness_within_reach_mm")
    for what, figs in ((touched_what(touched["points"]) if touched else None, touched),
                       (PLATE, plate), (within_what(within) if within else None, within)):
        if not figs:
            continue
        used.append(figs)
        for key, name in FIGURES:
            if key in figs:
                rows.append((escape(what), escape(name), f"<b>{escape(value_text(figs[key]))}</b>",
                             escape(figs[key].get("value_is", "-"))))
    said = {f.get("value_is") for u in used for f in u.values() if isinstance(f, dict)}
    notes = [note for kind, note in ((MEDIAN, MEDIAN_NOTE), (OUTSIDE, OUTSIDE_NOTE))
             if kind in said]
    if plate:
        notes.append(PLATE_CALIBRATION)  # what the whole plate's intervals held elsewhere
    notes += [feature_line(f) for f in result.get("local_features") or ()]
    weighed = weighted_out_line(result.get("weighted_out") or [])
    if weighed:
        notes.append(weighed)
    if result.get("largest_gap"):
        notes.append(gap_line(result["largest_gap"]))
    head = ("<h2>Flatness (provisional)</h2><p><b>Provisional:</b> the map is not a result "
            "(the top of the page says why); these figures are of that map.</p>"
            if missing(result) else "<h2>Flatness</h2>")
    return (head
            + _table(rows, head=("flatness", "figure", "value (95 % interval)", "value is"))
            + "".join(f"<p class='note'>{escape(n)}</p>" for n in notes)
            + "<p class='note'>Both figures remove the tilt: least squares is the spread of the "
              "heights about their least-squares plane (eq. 5), minimum zone the distance of the "
              "two closest parallel planes enclosing them; both measured normal to the planes. "
              "Touched points: the figure of the measured heights, the interval over predicted "
              "repeat measurements at the same touches. Whole plate: the figure of the mean map, "
              "the interval over surfaces sampled from the belief, with the structure finer "
              "than the knots the run found; within reach, the same on the part of the plate "
              "touches could reach (beyond it, in the edge margin, the map is an "
              "extrapolation). The same numbers are printed by "
              "<code>adaptive-cal run</code> and <code>adaptive-cal flatness</code>.</p>")


def cards(result: dict, run_dir: Path | None) -> str:
    t, ls, p = result["tilt"], result["flatness_mm"]["least_squares"], result["posterior"]
    tilt_label = "tilt correction" + (" (provisional)" if missing(result) else "")
    text = value_text(ls).split(" (", 1)
    cards = [(f"rx {signed(t['rx_deg'], 4)} deg<br>ry {signed(t['ry_deg'], 4)} deg", tilt_label),
             (escape(text[0]), f"flatness {PLATE}, least squares"
              + (f" ({escape(text[1])}" if len(text) > 1 else "")
              + (" (provisional)" if missing(result) else "")),
             (f"{_um(p['mean_std_mm'], 2)}", f"RMS posterior std after {result['touches']} touches")]
    ex = run_dir / "explain.json" if run_dir is not None else None
    if ex is not None and ex.exists():
        findings = read_json(ex)
        old = " -- out of date, of an earlier recording" if stale(findings, result) else ""
        cards.append((escape(findings.get("verdict", "-")),
                      f"explain verdict (left-out physics){old}"))
    return "<div class='cards'>" + "".join(
        f"<div class='card'><div class='v'>{v}</div><div class='l'>{l}</div></div>" for v, l in cards) + "</div>"
