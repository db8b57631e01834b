"""The explain part of a run's HTML page: what ``adaptive-cal explain --json DIR/explain.json
--out DIR`` found, in the terminal's words and units (``report.explain_text``), its figures --
those that explain wrote, not every figure of an earlier explain left in the folder -- and a
warning where the findings are of another recording than the run's now (a resume since)."""
from __future__ import annotations

import base64
from pathlib import Path

from adaptive_cal.formats.jsonfile import read_json
from adaptive_cal.report.explain_text import (effect_units, left_out_line, readings_lines,
                                              rounds_lines, stale, verdict_lines)
from adaptive_cal.report.sections import _table, _um, escape, image
from adaptive_cal.report.status import quoted

#: the figures explain writes, in the page's order
EXPLAIN_FIGURES = ("residual_map.png", "residual_vs_position.png", "residual_vs_time.png",
                   "residual_vs_direction.png", "residual_vs_reach.png",
                   "residual_vs_indication.png", "fitted_effect.png")


def explain_section(run_dir: Path, result: dict | None = None) -> str:
    path = run_dir / "explain.json"
    if not path.exists():
        return ("<h2>Explain</h2><p class='note'>No explain findings in this folder. To compare the "
                "recording with the cell's simulation: <code>adaptive-cal explain "
                f"{escape(quoted(run_dir / 'recording.csv'))} --robot CELL.yaml --json "
                f"{escape(quoted(path))} --out {escape(quoted(run_dir))}</code>, then run the "
                "report again.</p>")
    units = effect_units()
    findings = read_json(path)
    fit = findings.get("fit", {})
    verdict = findings.get("verdict", "-")
    head, *more = verdict_lines({**findings, "verdict": verdict})
    said = escape(head.removeprefix(f"verdict: {verdict}"))
    parts = ["<h2>Explain: what the simulation left out</h2>"]
    old = stale(findings, result)
    if old:
        parts.append(f"<p class='incomplete'><b>Out of date:</b> {escape(old)}.</p>")
    parts.append(f"<p class='verdict'>verdict: <b>{escape(verdict)}</b>{said}</p>")
    # (with verdict none, verdict_lines' next line says why: no left-out effect is supported)
    more += readings_lines(findings)  # the structure left, suspect readings, the noise judged
    more += [left_out_line(e, units.get(e["effect"], {}), verdict)
             for e in findings.get("left_out", [])]  # the terminal's words, values in um
    if more:
        parts.append("<ul>" + "".join(f"<li>{escape(line.strip())}</li>" for line in more)
                     + "</ul>")
    if fit:
        parts.append(_table([
            ("RMS residual", f"{_um(fit.get('rms_before_mm'))} &rarr; {_um(fit.get('rms_after_mm'))}"),
            ("leave-one-out RMS", f"{_um(fit.get('cv_rms_before_mm'))} &rarr; "
                                  f"{_um(fit.get('cv_rms_after_mm'))}")],
            head=("fit", "nominal → with the effect"), cls="kv"))
    by = findings.get("mismatch", {}).get("by", {})
    if by:
        parts.append(_table([(escape(k), f"{v['p_value']:.3g}" + (" <b>real</b>" if v.get("real") else "")
                              if v.get("p_value") is not None else escape(v.get("note", "-")))
                             for k, v in by.items()],
                            head=("residual against", "F-test p (small = a real trend)"), cls="kv"))
    r = findings.get("rounds")
    if r and "p_value" in r:  # the terminal's words (explain_text.rounds_lines), in um
        first, *rest = rounds_lines(r)
        parts.append(f"<p>{escape(first[0].upper() + first[1:])}</p>"
                     + (f"<p class='note'>{'<br>'.join(escape(x.strip()) for x in rest)}</p>"
                        if rest else ""))
    ni = findings.get("not_identifiable", [])
    if ni:
        parts.append("<p>Not identifiable from this recording:</p><ul>" + "".join(
            f"<li><b>{escape(e['effect'])}</b>: {escape(e['why'])}</li>" for e in ni) + "</ul>")
    written = findings.get("figures")  # those this explain wrote (older files: any found)
    names = {Path(f).name for f in written} if written is not None else set(EXPLAIN_FIGURES)
    for name in EXPLAIN_FIGURES:
        p = run_dir / name
        if name in names and p.exists():
            parts.append(image(base64.b64encode(p.read_bytes()).decode("ascii"), name, name))
    return "".join(parts)
