"""``adaptive-cal flatness``: the flatness of a recording with 95 % intervals.

Of the touched points (least-squares plane, eqs. 1-6 of Cheng et al., and the ISO 1101 minimum
zone), so they compare with published numbers. In a run folder (beside cell.yaml and belief.npz)
or with ``--robot CELL.yaml`` (the recording replayed to a map) also of the whole plate, from the
map: ``analysis.flatness_answer``, the same lines and digits as ``run`` and the report. A bare
recording's interval comes from its own prior (``analysis.flatness_intervals``). ``--compare``
gives the probability that a later round's flatness is larger."""
from __future__ import annotations

import json
import sys

from adaptive_cal.cli.common import UserError, at_least, check_recording


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="RECORDING.csv", help="a v1 recording; in a run folder "
                   "(beside cell.yaml and belief.npz) the whole plate's flatness is given too")
    p.add_argument("--robot", metavar="CELL.yaml", help="the cell file the recording was taken "
                   "with: replay it to a map and give the whole plate's flatness too")
    p.add_argument("--compare", metavar="OTHER.csv", help="a later round: probability that its "
                   "flatness (of the touched points) is larger, and the interval of the difference")
    p.add_argument("--round", type=float, default=None, metavar="R", help="of a recording whose "
                   "round column holds several rounds, the one numbered R (a text label counts "
                   "in order of first appearance from 0, as the reader says)")
    p.add_argument("--compare-round", type=float, default=None, metavar="R", help="the round of "
                   "--compare's file (to compare two rounds of one file: give it as --compare "
                   "too)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--samples", type=at_least(2, 100_000, " (each sample is a whole minimum-zone "
                                              "fit: 100,000 take minutes)"),
                   default=None, help="posterior samples for the intervals (default: 200 with a "
                   "map, as in run, so the digits are the run's; 400 for a bare recording; fewer than "
                   "40 make a coarse 95 %% interval)%(default).0s")
    p.add_argument("--seed", type=at_least(0), default=0, help="seed of the posterior samples")


NO_PLATE = ("needs a map: give the cell file (--robot CELL.yaml), or the recording of a run "
            "folder (beside its cell.yaml and belief.npz)")


def command(args) -> int:
    import numpy as np

    from adaptive_cal.analysis.flatness_intervals import compare, recording_flatness, touches_differ
    from adaptive_cal.cli.common import check_cell_file

    check_recording(args.recording)
    bare_samples = args.samples or 400
    if args.robot:
        from pathlib import Path

        from adaptive_cal.cli.run_guards import replay_cell_warning

        check_cell_file(args.robot)
        said = None if args.compare else replay_cell_warning(Path(args.recording),
                                                             Path(args.robot))
        if said:
            print(said, file=sys.stderr)
    if args.compare_round is not None and not args.compare:
        raise UserError("--compare-round needs --compare OTHER.csv (the same file for two "
                        "rounds of one recording)")
    first = _picked(args.recording, args.round, "--round")
    if args.compare:
        check_recording(args.compare)
        second = _picked(args.compare, args.compare_round, "--compare-round")
        _not_itself(args.recording, args.compare, first, second,
                    files=args.round is None and args.compare_round is None)
        differ = touches_differ(first, second)
        for said in _compare_notes(args, first, second, differ):
            print(said, file=sys.stderr)
        rng = np.random.default_rng(args.seed)
        out, _, sampled = recording_flatness(first, rng, bare_samples)
        other, _, sampled_b = recording_flatness(second, rng, bare_samples)
        change = compare(sampled, sampled_b)
        for k, c in change.items():  # the table's "change": the figures as measured
            c["measured_mm"] = other["flatness_mm"][k]["value"] - out["flatness_mm"][k]["value"]
        out = {"first": out, "second": other, "change": change,
               "touches_differ": differ}
    else:
        out = map_flatness(args, first) or recording_flatness(first, np.random.default_rng(
            args.seed), bare_samples)[0]
    if args.json:
        json.dump(out, sys.stdout, indent=2, allow_nan=False)
        print()
    else:
        _print(out)
    return 0


def _compare_notes(args, first, second, differ) -> list[str]:
    """What --compare does not do: use --robot (the change is of the touched points' figures,
    every reading as recorded), or compare like with like where the touches differ
    (``differ``: ``touches_differ``'s)."""
    notes = [f"note: --robot {args.robot} is not used by --compare: the change is of the touched "
             "points' figures, every reading as recorded"] if args.robot else []
    if differ:
        a, b = differ["first_only"], differ["second_only"]
        notes.append(f"warning: the recordings' touches differ ({a} of {differ['first_places']} "
                     f"places of {args.recording} not in {args.compare}, {b} of "
                     f"{differ['second_places']} the other way, to 0.5 mm): each figure is of its "
                     "own points, so their change is not the plate's alone")
    return notes


def map_flatness(args, picked=None) -> dict | None:
    """Both answers (touched points and whole plate) from the run folder's saved belief, or from
    the recording replayed with --robot; None for a bare recording without a cell. ``picked``:
    the recording as read (the rows of --round), else read from its path."""
    from pathlib import Path

    import numpy as np

    rec_path = Path(args.recording)
    folder = rec_path.parent
    saved = folder / "belief.npz"
    if not args.robot and not ((folder / "cell.yaml").exists() and saved.exists()):
        return None
    from adaptive_cal.analysis.flatness_answer import SAMPLES, flatness_answer, largest_gap
    from adaptive_cal.analysis.flatness_intervals import spans_area
    from adaptive_cal.analysis.local_features import confirmed, feature_var_mm2, weighted_out
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.cell.run_cell import load_run_cell
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.gaussian.belief import Belief
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.gate import flagged_weight
    from adaptive_cal.run.results import touched_heights

    cell = load_cell(args.robot) if args.robot else load_run_cell(folder / "cell.yaml")
    plan = survey_plan(cell)
    rec = picked if picked is not None else read_recording(rec_path)
    rec = rec.one_round("flatness")
    if args.robot:
        from adaptive_cal.report.replay import for_replay

        rec = for_replay(rec, cell, args.robot)  # judged as the run judges a reading
        state = sv.replay(plan, sv.start(plan), rec)
        belief, noise_mm, source = state.belief, state.hyper.noise_std_mm, f"replayed with {args.robot}"
        unresolved = sv.unresolved_var_mm2(plan, state, plan.eval_xy)
        weights = state.fused_weights
    else:
        from adaptive_cal.cli.run_guards import refuse_stale_map
        from adaptive_cal.formats.npz import read_npz, unresolved_at

        data = read_npz(saved)
        check_belief(folder, plan.model.surface, data)
        refuse_stale_map(folder, "flatness")
        belief = Belief(data["mean"], data["cov"])
        unresolved = unresolved_at(data, plan.eval_xy[:, 0], plan.eval_xy[:, 1])
        noise_mm = float(data["hyper"][2])
        source = f"the map saved in {saved}"
        weights = ([flagged_weight(f) for f, k in zip(rec.flags, rec.fused) if k]
                   if rec.flags else None)
    xyz = touched_heights(plan, rec)
    if (n := len(xyz[2])) < 4:
        raise UserError(f"{rec_path}: {n} usable touch{'es' * (n != 1)}; flatness needs at "
                        "least 4")
    spans_area(xyz[0], xyz[1], rec_path)
    features = confirmed(plan.model.surface, belief, noise_mm, rec, plan.zero_mm)
    if not args.robot:  # belief.npz's grid holds the features' band too; the whole plate's
        # answer draws them as points instead, as the run does (the same digits)
        unresolved = np.maximum(unresolved - feature_var_mm2(features, *plan.eval_xy.T), 0.0)
    out = flatness_answer(plan, belief, noise_mm, xyz, np.random.default_rng(args.seed),
                          args.samples or SAMPLES, unresolved, features, plan.learn)
    seq = rec.seq[rec.fused]
    out["weighted_out"] = (weighted_out(seq, weights if len(weights) == len(seq) else [])
                           if weights is not None else [])
    return {"recording": str(rec_path) if args.round is None else picked.path,
            "map": source, "touches": len(xyz[2]),
            "noise_std_mm": noise_mm, **out, "local_features": features,
            "largest_gap": largest_gap(plan, np.c_[xyz[0], xyz[1]]),
            **({} if args.robot else _unfinished(folder))}


def _unfinished(folder) -> dict:
    """{"incomplete": why} for a run folder whose run did not finish (interrupted, budget spent
    with the bound unmet, ...; ``report.status.missing``), as run and report mark it."""
    from adaptive_cal.formats.jsonfile import read_result
    from adaptive_cal.report.status import missing, unfinished

    path = folder / "result.json"
    if not path.is_file():  # the same words as report's and compensate's for such a folder
        return {"incomplete": f"no result.json: {unfinished(folder, 'result.json')}"}
    gap = missing(read_result(path))
    return {"incomplete": gap} if gap else {}


def _picked(path: str, round_: float | None, option: str):
    """The recording at ``path``, read once; with ``round_`` that round's rows (UserError
    naming ``option`` where the file has no such round)."""
    from dataclasses import replace

    import numpy as np

    from adaptive_cal.formats.recording import read_recording

    rec = read_recording(path)
    if round_ is None:
        return replace(rec, path=path)  # named as given on the command line
    rounds = rec.rounds
    if round_ not in rounds:
        has = (f"its round column holds {', '.join(f'{r:g}' for r in rounds)}" if rounds
               else "it has no round column (one round)")
        raise UserError(f"{option} {round_:g}: {path} has no such round; {has}")
    return replace(rec.select(np.asarray(rec.extra["round"]) == round_),
                   path=f"{path} (round {round_:g})")


def _not_itself(first: str, second: str, a, b, files: bool) -> None:
    """--compare of a recording with itself (or a copy) reads zero change "within the noise":
    no second round was measured. Refused. ``a``, ``b``: the two as read; ``files``: no round
    was picked, so one file given twice is refused too (two rounds of one file are two
    rounds: then the rows decide)."""
    import filecmp
    import os

    same_file = files and (os.path.realpath(first) == os.path.realpath(second)
                           or filecmp.cmp(first, second, shallow=False))
    if same_file or _same_rows(a, b):  # a copy saved again (CRLF, a BOM): the same rows
        raise UserError(f"--compare {second}: the same recording as {first} (or a copy of it); "
                        "compare two rounds measured apart")


def _same_rows(a, b) -> bool:
    """Whether two recordings hold the same touches (positions and readings): a copy another
    program saved again differs in its bytes, not its rows (an outside audit compared such a
    copy as two rounds, 'change +0.0, P(worse) 0.50')."""
    import numpy as np

    return len(a) == len(b) and all(np.array_equal(getattr(a, k), getattr(b, k)) for k in
                                    ("x_mm", "y_mm", "z_mm", "reading_mm"))


def check_belief(folder, surface, data, command: str = "flatness") -> None:
    """UserError unless the map in ``folder``/belief.npz (``data``) is one the folder's cell.yaml
    gives (``surface``: its spline; ``run.results.belief_mismatch``). A run resumed with another
    cell, or a cell.yaml edited since, would be read as another map."""
    from pathlib import Path

    from adaptive_cal.formats.npz import broken_belief, broken_text
    from adaptive_cal.run.results import belief_mismatch

    folder = Path(folder)
    have = belief_mismatch(surface, data)
    bad = broken_belief(data) if have is None else None  # read as compensate reads it
    if bad:
        raise UserError(broken_text(folder / "belief.npz", bad))
    if have is not None:
        k = (len(surface.sx.knots), len(surface.sy.knots))
        raise UserError(
            f"{folder / 'belief.npz'} does not match {folder / 'cell.yaml'}: the map's knots are "
            f"{have}, the cell file gives {k[0]} x {k[1]} (its workplane or "
            "model.knots_x / knots_y differ: was the run resumed with another --robot, or "
            f"cell.yaml edited?). Give the cell file the map was made with: adaptive-cal {command} "
            f"{folder / 'recording.csv'} --robot CELL.yaml replays the recording with it")


def _one(r: dict, say_no_plate: bool = True) -> list[str]:
    from adaptive_cal.analysis.flatness_answer import answer_lines, value_text
    from adaptive_cal.report.sections import tilt_angles

    t = r["tilt"]
    if "map" in r:  # both answers, the tilt of the whole plate's map
        gap = r.get("incomplete")
        return ([f"{r['recording']}: {r['touches']} touches, reading noise "
                 f"{r['noise_std_mm'] * 1e3:.1f} um; map: {r['map']}"]
                + ([f"  INCOMPLETE: {gap}. Not a result: the figures are provisional"]
                   if gap else [])
                + [f"  tilt correction (whole plate): {tilt_angles(t)}"
                   + (" (provisional)" if gap else "")
                   + f"; a {t['a']:+.6f}, b {t['b']:+.6f} mm/mm, c {t['c']:+.4f} mm"]
                + ["  " + line for line in answer_lines(r, provisional=bool(gap))]
                + _weighted_out(r))
    touched = {**r["flatness_mm"], "points": r["touches"]}
    lines = [f"{r['recording']}: {r['touches']} touches, reading noise {r['noise_std_mm'] * 1e3:.1f} um",
             f"  tilt correction (touched points): rx {t['rx_deg']:+.4f}{_sd(t, 'rx_std_deg')} deg, "
             f"ry {t['ry_deg']:+.4f}{_sd(t, 'ry_std_deg')} deg"
             + " (1 sd over repeats at these touches)" * ("rx_std_deg" in t) + f"; a {t['a']:+.6f}, "
             f"b {t['b']:+.6f} mm/mm" + (f", c {t['c']:+.4f} mm" if "c" in t else "")]
    lines += ["  " + line for line in answer_lines({"touched_flatness_mm": touched},
                                                      no_plate=NO_PLATE if say_no_plate else None)]
    lines.append(f"  height spread of the touched points, max - min with the tilt included (not "
                 f"flatness): {value_text(r['flatness_mm']['range'])}")
    a = r["average_range_mm"]
    lines.append("  average range (Cheng Table 8, tilt included) " + ", ".join(
        f"along {k} {a[k] * 1e3:.1f} um" if a[k] is not None
        else f"{k} n/a (touches not on a grid along {k})" for k in ("x", "y")))
    return lines


def _sd(t: dict, key: str) -> str:
    return f" +- {t[key]:.4f}" if key in t else ""


def _weighted_out(r: dict) -> list[str]:
    """A line naming the readings the map weighted out as gross errors (p >= 0.5)."""
    from adaptive_cal.analysis.local_features import weighted_out_line

    line = weighted_out_line(r.get("weighted_out") or [])
    return [f"  {line}"] if line else []


LABELS = {"least_squares": "least squares", "minimum_zone": "minimum zone",
          "range": "range (tilt incl.)"}


def compare_table(out: dict) -> list[str]:
    """The change between two recordings as a table in um, with P(worse) = P(later > earlier),
    and what its interval is (of the change, given the data), beside explain's test of
    "unchanged" (a band of the change under no change, and a p-value)."""
    from pathlib import Path

    a, b = out["first"], out["second"]
    from adaptive_cal.analysis.flatness_intervals import verdict
    from adaptive_cal.formats.numbers import fixed

    um = lambda v, sign="": fixed(v * 1e3, 1, sign)  # noqa: E731 (um, never "-0.0")
    lines = [f"change from {Path(a['recording']).name} to {Path(b['recording']).name} "
             "(later minus earlier; um):",
             f"  {'figure':<19}{'earlier':>9}{'later':>9}{'change':>9}   {'95 % interval of change':<26}"
             f"{'P(worse)':>8}  verdict"]
    for k in ("least_squares", "minimum_zone", "range"):
        c = out["change"][k]
        va, vb = a["flatness_mm"][k]["value"], b["flatness_mm"][k]["value"]
        lo, hi = c["diff_ci95"]
        change = round(vb * 1e3, 1) - round(va * 1e3, 1)  # of the figures as printed
        lines.append(f"  {LABELS[k]:<19}{um(va):>9}{um(vb):>9}{fixed(change, 1, '+'):>9}   "
                     f"{um(lo, '+') + ' .. ' + um(hi, '+'):<26}{c['p_b_greater']:>8.2f}  "
                     f"{verdict(c)}{' (other points)' if out.get('touches_differ') else ''}")
    lines += ["  change: the later figure minus the earlier, as measured. 95 % interval of",
              "  change: of the plate's figure at the touches, given the two recordings (each",
              "  round's smooth surface fitted to it alone, the readings' noise removed; the",
              "  reading noise above is each round's scatter about it). P(worse): the probability",
              "  that the plate's figure grew (not a p-value). Range: max - min of the heights,",
              "  the tilt included (not flatness): a corrected tilt shows there.",
              "  A test of \"plate unchanged\" with a p-value instead: adaptive-cal explain FIRST.csv",
              "  LATER.csv --robot CELL.yaml (its repeatability, from the rounds' difference at the",
              "  same points, leaves out the form both share, so it is smaller)."]
    return lines


def _print(out: dict) -> None:
    if "change" not in out:
        print("\n".join(_one(out)))
        return
    print("\n".join(_one(out["first"], False) + _one(out["second"], False) + compare_table(out)))
