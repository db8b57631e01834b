"""explain's findings as terminal text for a process engineer: heights in um, one line per
finding, the standardized residual as "sd" (z is a height in this tool), the suggested extra
touches printed, and the statistical terms named in full (docs/explain.md explains them).
Standard library only; ``units`` maps an effect's parameter names to their units (from the
effect library) and is passed in by the command."""
from __future__ import annotations

import re
import textwrap

from adaptive_cal.formats.numbers import fixed

LATERAL = {"x_mm", "y_mm", "radius_mm"}  # positions and sizes on the plate stay in mm
LABELS = {"pv_mm": "peak-to-valley over the workplane", "bow_x": "bow in x",
          "bow_y": "bow in y", "sag_mm_at_1m": "sag at 1 m reach"}


def _pm(value: float, std: float | None, sign: str = "", alone: int = 3) -> str:
    """"value +- std" with the sd to 2 significant digits and the value to the same decimal
    place (e.g. "10 +- 82", "0.051 +- 0.012"); without an sd the value to ``alone``
    significant digits."""
    import math

    if std is None or not math.isfinite(std) or std <= 0:
        return f"{value:{sign}.{alone}g}" if value != 0 else f"{0.0:{sign}g}"
    decimals = max(0, 1 - math.floor(math.log10(std)))
    return f"{fixed(value, decimals, sign)} +- {std:.{decimals}f}"


def effect_units() -> dict[str, dict[str, str]]:
    """Each library effect's parameters and their units, for ``lines`` / ``left_out_line``."""
    from adaptive_cal.effects import EFFECTS

    return {name: {p.name: p.unit for p in e.params} for name, e in EFFECTS.items()}


def _label(name: str) -> str:
    """A parameter's name as the text prints it (LABELS, else its key without the unit)."""
    return LABELS.get(name, re.sub(r"_(mm|s|deg|mm_per_s)$", "", name).replace("_", " "))


def quantity(name: str, value: float, std: float | None, unit: str) -> str:
    """One fitted parameter in the unit an engineer reads: heights in um, positions in mm."""
    label = _label(name)
    if isinstance(value, (list, tuple)):  # fitted per round: each round's value in turn
        stds = std if isinstance(std, (list, tuple)) else [std] * len(value)
        return f"{label} per round " + ", ".join(
            f"{i}: " + quantity(name, v, s, unit).removeprefix(f"{label} ")
            for i, (v, s) in enumerate(zip(value, stds)))
    pm = lambda scale, fmt: "" if std is None else f" +- {std * scale:{fmt}}"  # noqa: E731
    if unit == "mm" and name not in LATERAL:
        sign = "" if name == "pv_mm" else "+"
        return f"{label} {fixed(value * 1e3, 1, sign)}{pm(1e3, '.1f')} um"
    if unit == "mm":
        return f"{label} {fixed(value, 0)}{pm(1, '.0f')} mm"
    if unit == "mm/s" or name.endswith("_mm_per_s"):
        return f"{label} {_pm(value * 1e3, None if std is None else std * 1e3, '+')} um/s"
    if unit in ("s", "deg"):
        return f"{label} {_pm(value, std)} {unit}"
    return f"{label} {_pm(value, std, '+', 4)}" + (f" {unit}" if unit and unit != "-" else "")


def _held(name: str, value: float, unit: str) -> str:
    """A parameter held at a value, not fitted: "rate held at 0 um/s" (no sign, no sd)."""
    label = _label(name)
    said = quantity(name, value, None, unit).removeprefix(label).strip().removeprefix("+")
    return f"{label} held at {said}"


def _notes(summary: str) -> list[str]:
    """The notes of an effect's summary line (between its parameters and its evidence)."""
    parts = [p.strip() for p in summary.split(";")][1:]
    parts = [p for p in parts if not p.startswith("log BF vs none")]
    parts = [re.sub(r"^shared \(log BF shared vs per round ([-+0-9.e]+)\)",
                    lambda m: f"the same in every round (log Bayes factor {fixed(float(m[1]), 1)} over "
                              "one per round)", p) for p in parts]
    return [p.replace("log BF", "log Bayes factor") for p in parts]


def left_out_line(e: dict, units: dict, verdict: str | None = None) -> str:
    """One ``left_out`` entry. Beside a verdict (``given_verdict``): "as well" with the fit
    beside it where it is still there with the verdict in the model, else "instead of" -- it
    explains the verdict's residual, not something more."""
    given = e.get("given_verdict")
    if given and given["left_out"]:
        params, stds = given["params"], given["params_std"]
    else:
        params, stds = e.get("params", {}), e.get("params_std", {})
    held = set(e.get("held") or ())  # fixed, not fitted: "rate held at 0 um/s", not "+0 um/s"
    values = ", ".join(_held(k, v, units.get(k, "")) if k in held
                       else quantity(k, v, stds.get(k), units.get(k, ""))
                       for k, v in params.items())
    notes = "; ".join(_notes(e.get("summary", "")) if not (given and given["left_out"]) else
                      [n for n in _notes(e.get("summary", "")) if n.startswith("t_s ")])
    alone = e.get("log_bayes_factor")
    against = ("log Bayes factor " + ("-" if alone is None else fixed(alone, 1)) + " against none")
    if not given:
        return (f"  left out: {e['effect']}: {values}" + (f"; {notes}" if notes else "")
                + f"; evidence: {against}")
    beside = f"{fixed(given['log_bayes_factor'], 1)} with {verdict} in the model"
    if given["left_out"]:
        why = (f"clearer with {verdict} in the model" if alone is None
               or alone < given["log_bayes_factor"]
               else f"where it takes up part of what {verdict} explains")
        return (f"  left out as well, beside {verdict}: {e['effect']}: {values}"
                + (f"; {notes}" if notes else "") + f"; evidence: log Bayes factor {beside} "
                f"({against} alone, {why})")
    return (f"  instead of {verdict}, not beside it: {e['effect']}: {values}"
            + (f"; {notes}" if notes else "") + f"; evidence: {against}, {beside}")


def touches_lines(touches: list[dict]) -> list[str]:
    # a no-break space inside each point, so no point is split across lines
    text = " ".join(f"({t['x_mm']:g},\u00a0{t['y_mm']:g},\u00a0{t['z_mm']:g})" for t in touches)
    wrapped = textwrap.wrap(f"{len(touches)} touch(es) at x, y, z (mm): {text}", width=96,
                            initial_indent="      ", subsequent_indent="        ",
                            break_on_hyphens=False)
    return [w.replace("\u00a0", " ") for w in wrapped]


def readings_lines(report: dict, shown: int = 5) -> list[str]:
    """The readings not used (outside the probe's usable stroke) and the suspect readings set
    aside (the first ``shown`` of each), a heavy-tailed noise judgement and
    the scaling of the evidence for readings correlated from one touch to the next."""
    sus, readings = report.get("suspect_readings") or [], report.get("readings") or {}
    out = []
    aside = readings.get("not_used") or []
    if aside:
        by_file: dict = {}
        for r in aside[:shown]:
            by_file.setdefault(r.get("recording"), []).append(str(r["seq"]))
        seqs = "; ".join(("" if k is None else f"{k}: ") + "seq " + ", ".join(v)
                         for k, v in by_file.items())
        more = f" and {len(aside) - shown} more (readings.not_used in --json)" \
            if len(aside) > shown else ""
        out.append(f"readings not used: {len(aside)} ({seqs}{more}): {aside[0]['why']}")
    if sus:
        out.append(f"suspect readings, set aside (not physics): {len(sus)} of "
                   f"{readings.get('total', '?')}")
        out.extend(f"  seq {s['seq']} at x {s['x_mm']:g}, y {s['y_mm']:g} mm: residual "
                   f"{1e3 * s['residual_mm']:+.1f} um, P(gross error) {s['probability']:.2f}"
                   for s in sus[:shown])
        if len(sus) > shown:
            out.append(f"  ... and {len(sus) - shown} more (suspect_readings in --json)")
    noise = readings.get("noise") or {}
    if noise.get("distribution") == "student_t":
        out.append(f"reading noise: heavy-tailed (Student-t, {noise['dof']:g} dof; log likelihood "
                   f"ratio {fixed(noise['log_lr_vs_gaussian'], 1)} against Gaussian): every effect "
                   "is judged against heavy-tailed noise")
    serial = noise.get("serial")
    if serial:
        out.append(f"reading noise: consecutive readings correlated (lag-1 {serial['lag1_correlation']:+.2f}"
                   f"): every log Bayes factor scaled by {serial['evidence_factor']:.2f}, the "
                   "readings' effective share")
    return out


NONE = "no left-out effect is supported by the data"  # the report's words for verdict none


# what verdict none's probability is: none's own posterior, from a prior of 1/2
NONE_MEANS = (" that no library effect is present; none's prior is 1/2, so 0.5 means the data "
              "could not tell, not that an effect is likely")
# what to do after an ``unexplained`` verdict, by the structure test that found it (its ``test``,
# else its ``axis``): what to check on the cell, and which touches would test it
NEXT_STEP = {
    "time": "check for warm-up or drift: touch one point again at the start, middle and end of "
            "a run (a reading that changes with time at one place is the cell, not the plate)",
    "serial correlation": "look for a disturbance that lasts over several touches (vibration, "
                          "air draught, a gauge that settles): a longer probe.settle_s, "
                          "probe.samples above 1, and a few touches in a row at one point",
    "direction": "check the robot's backlash: touch a few points twice, arriving once moving +x "
                 "and once moving -x (a difference at one place is the robot, not the plate)",
    "direction along y": "check the robot's backlash along y: touch a few points twice, arriving "
                         "once moving +y and once moving -y",
    "position": "the plate has shape finer than the library's form (a ripple, a step, a row or "
                "column offset): add touches between those near the places listed, or look at "
                "the plate there",
    "reach": "check the arm (its sag, a joint's zero): the residual follows the reach from "
             "robot.base_xy_mm; touch the plate's near and far edges again in one run",
    "indication": "check the gauge (its scale, a sticking plunger): touch a few points again "
                  "from a second approach height (z_mm + 2 mm), so one surface is read at two "
                  "indications",
    "noise": "the readings scatter beyond the probe's stated noise: touch one point ten times "
             "to measure the repeatability, then correct probe.noise_std_mm / noise_range_mm "
             "or check the probe's mounting",
}


def none_line(report: dict) -> str:
    """Why the verdict is none: the best candidate's log Bayes factor against none and the one a
    verdict needs, and where the rest of the probability is (none's prior is 1/2)."""
    cands = [c for c in report.get("candidates") or [] if c.get("log_bayes_factor") is not None]
    if not cands:
        return f"  {NONE}: no candidate effect was tested"
    low = report.get("readout_limited")
    if low:
        return (f"  {NONE}: the mismatch after the tilt, RMS {low['rms_mm'] * 1e3:.4f} um, is "
                f"below the probe's readout step ({low['readout_mm'] * 1e3:g} um): rounding, "
                "not physics -- no effect can be shown")
    # an effect the tilt absorbs whole scores exactly 0, the likelihood of none: not a candidate
    # to name as the best (an audit: "probe_gain, +0.00" beside "the tilt absorbs 100 %")
    absorbed = {n["effect"] for n in report.get("not_identifiable") or ()}
    tested = [c for c in cands if not (c["effect"] in absorbed
                                        and abs(c["log_bayes_factor"]) < 1e-9)] or cands
    best = max(tested, key=lambda c: c["log_bayes_factor"])
    need = (report.get("threshold") or {}).get("log_bayes_factor")
    line = (f"  {NONE}: the best candidate, {best['effect']}, has log Bayes factor "
            f"{fixed(best['log_bayes_factor'], 2, '+')} against none"
            + (f" (a verdict needs above {need:.1f})" if need is not None else ""))
    p = report.get("verdict_probability")
    if p is not None:
        line += (f"; the other {fixed(1 - p, 2)} of the probability is spread over the "
                 f"{len(cands)} candidate{'s' * (len(cands) != 1)} (none starts at 1/2)")
    return line


def verdict_lines(report: dict) -> list[str]:
    """The verdict with its probability and what it cannot be told from, then for
    ``unexplained`` the structure left, its axis and where (the terminal's and the report's)."""
    amb = report.get("ambiguous_with") or []
    kind = ("probability, bounded from the structure test's p-value" if report["verdict"] ==
            "unexplained" else "probability")
    p = report.get("verdict_probability")
    said = [f"{kind} {p:.2f}" + (NONE_MEANS if report["verdict"] == "none" else "")] \
        if p is not None else []
    said += [f"cannot be told apart from {', '.join(amb)} on this design"] if amb else []
    out = [f"verdict: {report['verdict']}" + (f" ({'; '.join(said)})" if said else "")]
    if report["verdict"] == "none":
        out.append(none_line(report))
    u = report.get("unexplained")
    if u:
        near = (f"; the nearest library effect, {u['nearest_library_effect']}, explains "
                f"{100 * u['library_share']:.0f} % of it" if u.get("nearest_library_effect") else "")
        out.append(f"  unexplained structure along {u['axis']}: {u['detail']}{near}")
        out.extend(f"    near x {w['x_mm']:g}, y {w['y_mm']:g} mm: residual "
                   f"{1e3 * w['residual_mm']:+.1f} um" for w in u["where"])
        step = NEXT_STEP.get(u.get("test")) or NEXT_STEP.get(u["axis"])
        if step:
            out.append(f"  next: {step}")
    return out


def rounds_lines(r: dict) -> list[str]:
    """The flatness of two rounds (um) and the test of "plate unchanged": the band noise alone
    puts the change in, its p-value and the repeatability behind it; and where the interval of
    the change itself is (``flatness --compare``, a different statistic with its own noise)."""
    if "flatness_mm" not in r:
        return []
    a, b = (1e3 * v for v in r["flatness_mm"])
    # the change of the figures as printed, as flatness --compare prints it (541.7 -> 596.0
    # had read "+54.4 um" here and "+54.3" there)
    out = [f"rounds: flatness (least squares) {a:.1f} -> {b:.1f} um, change "
           f"{fixed(round(b, 1) - round(a, 1), 1, '+')} um"]
    if "p_value" not in r:
        return out + ([f"  {r['note']}"] if r.get("note") else [])
    lo, hi = r["null_change_95_mm"]
    n = r.get("matched_points")
    at = f"the same {n} points" if n else "the same points"
    out[0] += (f"; test of \"plate unchanged\" (only its tilt moved): p = {r['p_value']:.3f}, "
               + ("larger than the noise" if r.get("exceeds_noise") else "within the noise"))
    out += [f"  if unchanged, noise alone puts the change within {fixed(1e3 * lo, 1, '+')} .. "
            f"{fixed(1e3 * hi, 1, '+')} um (95 %); repeatability {1e3 * r['repeatability_mm']:.1f} "
            f"um, from the two rounds' difference at {at} (form both share cancels in it)",
            "  not an interval of the change: adaptive-cal flatness FIRST.csv --compare LATER.csv "
            "gives that, from each round's own fit (its reading noise, the scatter about that "
            "fit, is larger)"]
    return out


def stale(findings: dict, result: dict | None) -> str | None:
    """Why explain.json is not of the run's recording as it is now (its readings against the
    run's fused ones: a run resumed after explain), or None."""
    total = (findings.get("readings") or {}).get("total")
    fused = (result or {}).get("fused")
    if total is None or fused is None or total == fused:
        return None
    return (f"explain.json was made from {total} readings; the run has {fused} fused now (it "
            "went on after explain): its findings are of the earlier recording -- run explain "
            "again for these")


def lines(report: dict, units: dict[str, dict[str, str]]) -> list[str]:
    fit = report["fit"]
    out = verdict_lines(report)
    for e in report["left_out"]:
        out.append(left_out_line(e, units.get(e["effect"], {}), report.get("verdict")))
    out.extend(readings_lines(report))
    for e in report["not_identifiable"]:
        if e.get("not_testable"):
            out.append(f"  not testable: {e['effect']}: {e['why'].removeprefix('not testable: ')}")
            design = e.get("suggested_design") or {}
            if design.get("description"):
                out.append(f"    suggested: {design['description']}")
            continue
        alias = (f" (inside the span of {', '.join(e['inside_span_of'])})" if e.get("inside_span_of")
                 else f" (cannot be told from {', '.join(e['aliased_with'])})" if e["aliased_with"]
                 else "")
        out.append(f"  not identifiable: {e['effect']}{alias}: {e['why']}")
        design = e.get("suggested_design") or {}
        if design.get("description"):
            out.append(f"    suggested: {design['description']}")
        if design.get("touches"):
            out.extend(touches_lines(design["touches"]))
    m = report["mismatch"]
    out.append(f"mismatch (recording minus simulation): RMS {1e3 * m['rms_mm']:.1f} um; trends "
               "(p: chance that noise alone shows one this strong):")
    for axis, v in m["by"].items():
        p = v.get("p_value")
        out.append(f"  {axis:>10}: " + (f"p = {p:.3g}{', real' if v['real'] else ''}"
                                       if p is not None else v.get("note", "")))
    for w in m["where"]:
        out.append(f"  residual {1e3 * w['residual_mm']:+.1f} um near x {w['x_mm']:g}, "
                   f"y {w['y_mm']:g} mm ({abs(w['z']):.1f} sd of the expected scatter)")
    out.append(f"fit: RMS residual {1e3 * fit['rms_before_mm']:.1f} -> {1e3 * fit['rms_after_mm']:.1f}"
               f" um, leave-one-out {1e3 * fit['cv_rms_before_mm']:.1f} -> "
               f"{1e3 * fit['cv_rms_after_mm']:.1f} um")
    out.extend(rounds_lines(report.get("rounds") or {}))
    if report.get("model"):
        out.append(f"model: {report['model']}")
    out.append("terms (log Bayes factor, canonical correlation, regressor, sd): docs/explain.md")
    return out
