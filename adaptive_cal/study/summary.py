"""The summary of a study (OUT.json) and its headline table (markdown): per strategy the touches
and robot time to the bound on the TRUE error, and at each strategy's own stop the posterior bound,
true errors and 95 % coverage; the lower bound on touches; adaptive against the paper."""
from __future__ import annotations

import numpy as np

from adaptive_cal.formats.numbers import count
from adaptive_cal.study.config import Study


#: bootstrap draws of the 95 % intervals over plates (a fixed seed: a summary is reproducible)
DRAWS = 2000


def _mean(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def ci95(*columns, stat=None, draws: int = DRAWS, seed: int = 0) -> list[float] | None:
    """A 95 % percentile-bootstrap interval of ``stat`` (default: the first column's mean) over
    the plates resampled with replacement, every column by the same indices (paired: the
    strategies ran on the same plates); None for fewer than 2 plates or, paired, a missing
    value. It says how far another study of as many plates drawn the same way could move the
    figure. A lone column's missing values are left out, as ``_mean`` leaves them out."""
    cols = [np.asarray(c, float) for c in columns]
    if stat is None and len(cols) == 1:
        cols = [cols[0][np.isfinite(cols[0])]]
    n = len(cols[0])
    if n < 2 or any(len(c) != n or not np.all(np.isfinite(c)) for c in cols):
        return None
    idx = np.random.default_rng(seed).integers(0, n, (draws, n))
    vals = (cols[0][idx].mean(axis=1) if stat is None
            else np.array([stat(*(c[i] for c in cols)) for i in idx], float))
    return [float(v) for v in np.percentile(vals, [2.5, 97.5])]


def _ratio(a, b):
    return a.mean() / b.mean()


def summarise(study: Study, records: list[dict]) -> dict:
    """OUT.json: per strategy the touches and robot time to reach the bound on the TRUE error
    (the budget counted where it was never reached), and at the strategy's own stop the posterior
    bound, true RMS and max error and 95 % coverage; the lower bound; adaptive against paper."""
    budget = study.bound.max_touches
    bound = study.bound.model_dump()
    # the target in force, not the file's null: the table and the runs use bound.true_mm
    bound["true_rms_mm"] = study.bound.true_mm
    bound["true_rms_from"] = ("bound.true_rms_mm" if study.bound.true_rms_mm is not None
                              else "bound.mean_std_mm (default)")
    out = {"study": study.name, "plates": study.plates, "bound": bound,
           "strategies": {}, "lower_bound": {}}
    by = {s: [r for r in records if r["strategy"] == s] for s in study.strategies}
    for s, recs in by.items():
        if not recs:
            continue
        touches = [r["touches_true"] if r["touches_true"] is not None else budget for r in recs]
        out["strategies"][s] = {
            "plates": len(recs),
            "touches_mean": float(np.mean(touches)),
            "touches_p90": float(np.percentile(touches, 90)),
            "robot_time_s_mean": _mean(r["robot_time_true_s"] for r in recs),
            "true_bound_reached": float(np.mean([r["touches_true"] is not None for r in recs])),
            "true_rms_mm_mean": _mean(r["true_rms_mm"] for r in recs),
            "true_max_mm_mean": _mean(r["true_max_mm"] for r in recs),
            "coverage95_mean": _mean(r["coverage95"] for r in recs),
            "stop_touches_mean": _mean(r["touches"] for r in recs),
            "stop_touches_p90": float(np.percentile([r["touches"] for r in recs], 90)),
            "stop_robot_time_s_mean": _mean(r["robot_time_s"] for r in recs),
            "stop_travel_mm_mean": _mean(r.get("travel_mm") for r in recs),
            "stop_mean_std_mm_mean": _mean(r["mean_std_mm"] for r in recs),
            "touches_mean_ci95": ci95(touches),
            "stop_touches_mean_ci95": ci95([r["touches"] for r in recs]),
            "coverage95_mean_ci95": ci95([r["coverage95"] for r in recs]),
        }
    adaptive = by.get("adaptive", [])
    grids = {r["plate"]: r for r in by.get("grid", [])}
    same = [(a, grids[a["plate"]]) for a in adaptive if a["plate"] in grids]
    if same:  # each at its own stop, the same plates: touches and robot time side by side
        out["adaptive_vs_grid"] = {
            "plates": len(same),
            "touch_ratio": float(np.mean([a["touches"] for a, _ in same])
                                 / np.mean([g["touches"] for _, g in same])),
            "robot_time_ratio": float(np.mean([a["robot_time_s"] for a, _ in same])
                                      / np.mean([g["robot_time_s"] for _, g in same])),
            "touch_ratio_ci95": ci95([a["touches"] for a, _ in same],
                                     [g["touches"] for _, g in same], stat=_ratio),
            "robot_time_ratio_ci95": ci95([a["robot_time_s"] for a, _ in same],
                                          [g["robot_time_s"] for _, g in same], stat=_ratio)}
    lb = [r for r in adaptive if r.get("relaxed_touches") is not None]
    # a plate where no design meets the bound within the budget has no bound (inf): counted,
    # and left out of every mean and ratio alike (one such plate made the mean inf, the ratio not)
    beyond = sum(not np.isfinite(r["relaxed_touches"]) for r in lb)
    lb = [r for r in lb if np.isfinite(r["relaxed_touches"])]
    relaxed = _mean(r["relaxed_touches"] for r in lb)
    best = [r.get("best_integer_touches") for r in lb]
    out["lower_bound"] = {
        "plates": len(lb),
        "plates_beyond_budget": beyond,
        "relaxed_touches": relaxed,
        "best_integer_touches": _mean(best) if best and all(b is not None for b in best) else None,
        "adaptive_stop_touches_same_plates": _mean(to_bound(r) for r in lb),
        "adaptive_over_relaxed": _mean(to_bound(r) / r["relaxed_touches"] for r in lb
                                       if r["relaxed_touches"]),  # lb: finite ones only
    }
    if not lb and not beyond:  # none computed: say why (an outside audit read a bare 0)
        out["lower_bound"]["why_none"] = (
            "lower_bound.plates is 0" if not study.lower_bound.plates else
            "computed beside the adaptive strategy, which this study does not run"
            if "adaptive" not in study.strategies else "no adaptive record holds one")
    whole = [r for r in lb if r.get("relaxed_whole_touches") is not None]
    if whole:  # the relaxation rounded up to whole touches: the tightest bound computed
        out["lower_bound"].update(
            relaxed_whole_touches=_mean(r["relaxed_whole_touches"] for r in whole),
            adaptive_over_relaxed_whole=_mean(
                to_bound(r) / r["relaxed_whole_touches"] for r in whole
                if r["relaxed_whole_touches"] and np.isfinite(r["relaxed_whole_touches"])))
    at_stop = [r for r in lb if r.get("relaxed_whole_touches_at_stop")]
    if at_stop:
        out["lower_bound"].update(adaptive_over_relaxed_whole_at_stop=_mean(
            to_bound(r) / r["relaxed_whole_touches_at_stop"] for r in at_stop
            if np.isfinite(r["relaxed_whole_touches_at_stop"])))
    marginal = [r for r in lb if r.get("marginal_whole_touches_at_stop")]
    if marginal:  # the bound for the planner's own stop, under its hyper-parameter posterior
        out["lower_bound"].update(
            marginal_whole_touches_at_stop=_mean(r["marginal_whole_touches_at_stop"]
                                                 for r in marginal
                                                 if np.isfinite(r["marginal_whole_touches_at_stop"])),
            adaptive_over_marginal_whole_at_stop=_mean(
                to_bound(r) / r["marginal_whole_touches_at_stop"] for r in marginal
                if np.isfinite(r["marginal_whole_touches_at_stop"])),
            adaptive_below_marginal_plates=sum(
                to_bound(r) < r["marginal_whole_touches_at_stop"] for r in marginal
                if np.isfinite(r["marginal_whole_touches_at_stop"])))
    greedy = [r for r in lb if r.get("greedy_known_touches")]
    if greedy:  # a feasible integer design under the same hyper-parameters: brackets the best one
        out["lower_bound"].update(
            greedy_known_touches=_mean(r["greedy_known_touches"] for r in greedy),
            greedy_known_over_relaxed=_mean(r["greedy_known_touches"] / r["relaxed_touches"]
                                            for r in greedy if r["relaxed_touches"]),
            adaptive_over_greedy_known=_mean(to_bound(r) / r["greedy_known_touches"]
                                             for r in greedy))
    papers = {r["plate"]: r for r in by.get("paper", [])}
    pairs = [(a, papers[a["plate"]]) for a in adaptive if a["plate"] in papers]
    if pairs:
        reach = []
        for a, p in pairs:
            hit = [t for t, _, rms in a["trajectory"] if rms <= p["true_rms_mm"]]
            reach.append(hit[0] if hit else None)
        got = [(t, p["touches"]) for t, (_, p) in zip(reach, pairs) if t is not None]
        level = float(np.mean([p["true_rms_mm"] for _, p in pairs]))
        pop = [next((t for t, _, rms in a["trajectory"] if rms <= level), budget) for a, _ in pairs]
        out["adaptive_vs_paper"] = {
            "plates": len(pairs),
            "paper_touches_mean": float(np.mean([p["touches"] for _, p in pairs])),
            "paper_true_rms_mm_mean": float(np.mean([p["true_rms_mm"] for _, p in pairs])),
            "adaptive_touches_to_paper_accuracy_mean": _mean(t for t, _ in got),
            "reached": len(got) / len(pairs),
            "touch_ratio_mean": _mean(t / n for t, n in got),
            "touch_ratio_of_means": (float(np.mean([t for t, _ in got])
                                           / np.mean([n for _, n in got])) if got else None),
            # against the paper's mean accuracy (free of the paper's luck on single plates)
            "adaptive_touches_to_paper_mean_accuracy": float(np.mean(pop)),
            "touch_ratio_mean_accuracy": float(np.mean(pop) / np.mean([p["touches"]
                                                                       for _, p in pairs])),
        }
        native = [(a, p) for a, p in pairs if p.get("native_true_rms_mm") is not None]
        if native:
            # the paper's procedure as published: its own map (last round, interpolated)
            t_native = [next((t for t, _, rms in a["trajectory"]
                              if rms <= p["native_true_rms_mm"]), budget) for a, p in native]
            n_paper = float(np.mean([p["touches"] for _, p in native]))
            out["adaptive_vs_paper"].update(
                paper_native_true_rms_mm_mean=float(np.mean([p["native_true_rms_mm"]
                                                             for _, p in native])),
                adaptive_touches_to_paper_native_accuracy_mean=float(np.mean(t_native)),
                touch_ratio_native=float(np.mean(t_native) / n_paper))
    return out


def _f(v, scale=1.0, fmt="{:.1f}"):
    return "-" if v is None else fmt.format(v * scale)


def _ci(iv, fmt="{:.1f}", around="{}") -> str:
    """"lo-hi" of an interval (``ci95``), in ``around``; "-" (or nothing, with ``around``)
    where there is none."""
    if not iv:
        return "" if around != "{}" else "-"
    return around.format(f"{fmt.format(iv[0])}-{fmt.format(iv[1])}")


def table(summary: dict) -> str:
    """The headline table (markdown): touches and robot time to the bound on the true error;
    true error and coverage at each strategy's own stop."""
    b = summary["bound"]
    lines = [f"bound: RMS posterior std {b['mean_std_mm'] * 1e3:.1f} um (own stop), true RMS "
             f"error {(b['true_rms_mm'] or b['mean_std_mm']) * 1e3:.1f} um; "
             f"{count(summary['plates'])}", "",
             "| strategy | touches to true bound (mean / p90) | robot time (s) | reached | "
             "touches at own stop | robot time at own stop (s) | true RMS (um) | true max (um) | "
             "coverage95 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, s in summary["strategies"].items():
        lines.append(
            f"| {name} | {s['touches_mean']:.1f} / {s['touches_p90']:.0f} | "
            f"{_f(s['robot_time_s_mean'], fmt='{:.0f}')} | {s['true_bound_reached']:.0%} | "
            f"{_f(s['stop_touches_mean'])} | {_f(s['stop_robot_time_s_mean'], fmt='{:.0f}')} | "
            f"{_f(s['true_rms_mm_mean'], 1e3, '{:.2f}')} | "
            f"{_f(s['true_max_mm_mean'], 1e3, '{:.1f}')} | {_f(s['coverage95_mean'], 1, '{:.3f}')} |")
    if summary["strategies"]:
        budget = b.get("max_touches")
        missed = [f"{name} {s['true_bound_reached']:.0%}" for name, s in
                  summary["strategies"].items() if s["true_bound_reached"] < 1]
        lines += ["", "touches to true bound: a plate that never reached it counts at the touch "
                  f"budget (max_touches{'' if budget is None else f' = {budget}'}); reached: "
                  + (", ".join(missed) if missed else "every plate, every strategy")
                  + " (the 'reached' column)"
                  + ("; its robot time is the mean over the plates that reached it only"
                     if missed else "")]
        cis = [f"{name}: touches to true bound {_ci(s.get('touches_mean_ci95'))}, at own stop "
               f"{_ci(s.get('stop_touches_mean_ci95'))}, coverage95 "
               f"{_ci(s.get('coverage95_mean_ci95'), '{:.3f}')}"
               for name, s in summary["strategies"].items() if s.get("stop_touches_mean_ci95")]
        if cis:
            lines += ["", "95 % intervals of the means over the plates (percentile bootstrap, "
                      "plates resampled): " + "; ".join(cis)]
    lb = summary.get("lower_bound") or {}
    if lb.get("plates_beyond_budget"):
        lines += ["", f"lower bound: on {count(lb['plates_beyond_budget'])} no design meets the "
                  f"bound within the touch budget (max_touches = {b.get('max_touches')}): left out of "
                  "the bound's figures below"]
    if lb.get("plates"):
        lines += ["", f"lower bound (relaxed optimal design, same hyper-parameters, first "
                  f"{count(lb['plates'])}): {_f(lb['relaxed_touches'])} touches; best integer "
                  f"design: {_f(lb['best_integer_touches']) if lb['best_integer_touches'] else 'not computed (too many designs)'}; "
                  f"adaptive at its own stop, closure touch excluded (as in every ratio of this "
                  f"paragraph) / relaxed: {_f(lb['adaptive_over_relaxed'], 1, '{:.2f}')}"]
        if lb.get("relaxed_whole_touches"):
            lines[-1] += (f"; the relaxed bound in whole touches: "
                          f"{_f(lb['relaxed_whole_touches'])}, adaptive / that: "
                          f"{_f(lb['adaptive_over_relaxed_whole'], 1, '{:.2f}')}")
        if lb.get("marginal_whole_touches_at_stop"):
            lines[-1] += (f"; for the planner's own stop (its belief mixes the posteriors under "
                          f"the hyper-parameter points it held then): "
                          f"{_f(lb['marginal_whole_touches_at_stop'])} whole touches, adaptive / "
                          f"that: {_f(lb['adaptive_over_marginal_whole_at_stop'], 1, '{:.2f}')}")
        if lb.get("greedy_known_touches"):
            lines[-1] += (f". The best integer design lies between the relaxed bound and the greedy "
                          f"design with the same hyper-parameters known from the start "
                          f"({_f(lb['greedy_known_touches'])} touches, "
                          f"{lb['greedy_known_over_relaxed']:.2f} x relaxed); adaptive / greedy "
                          f"known: {lb['adaptive_over_greedy_known']:.2f} (mean of per-plate ratios)")
    vg = summary.get("adaptive_vs_grid")
    if vg:
        lines += ["", f"adaptive / grid at each one's own stop ({count(vg['plates'])}, ratio of "
                  f"means): touches {vg['touch_ratio']:.2f} x"
                  + _ci(vg.get("touch_ratio_ci95"), "{:.2f}", " (95 % {})")
                  + f", robot time {vg['robot_time_ratio']:.2f} x"
                  + _ci(vg.get("robot_time_ratio_ci95"), "{:.2f}", " (95 % {})")]
    vp = summary.get("adaptive_vs_paper")
    if vp:
        lines += ["", f"paper's procedure: {vp['paper_touches_mean']:.1f} touches, true RMS "
                  f"{vp['paper_true_rms_mm_mean'] * 1e3:.2f} um; adaptive reaches each plate's "
                  f"paper accuracy with {_f(vp['adaptive_touches_to_paper_accuracy_mean'])} "
                  f"touches ({vp['reached']:.0%} of plates), ratio of means "
                  f"{_f(vp['touch_ratio_of_means'], 1, '{:.2f}')}; to the paper's mean accuracy "
                  f"{_f(vp.get('adaptive_touches_to_paper_mean_accuracy'))} touches (ratio "
                  f"{_f(vp.get('touch_ratio_mean_accuracy'), 1, '{:.2f}')})"
                  + (f". The paper's own map (last round's readings interpolated) has true RMS "
                     f"{vp['paper_native_true_rms_mm_mean'] * 1e3:.2f} um on average; adaptive reaches "
                     "each plate's own-map accuracy with "
                     f"{vp['adaptive_touches_to_paper_native_accuracy_mean']:.1f} touches "
                     f"(ratio {vp['touch_ratio_native']:.2f})" if "touch_ratio_native" in vp
                     else "")]
    return "\n".join(lines)


def to_bound(r: dict) -> int:
    """Touches a record made to meet its bound: its own-stop touches less the closure touch
    (``run.loop``), which the lower bounds on touches do not count."""
    return int(r["touches"]) - int(bool(r.get("closure")))
