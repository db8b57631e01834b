"""Could the data have told the truth from the verdict? (issue 15, item 5; per case of a results
JSON of bench_explain_indep.py.)

For each miss (and, with ``--all``, each case) whose truth is ``form`` or ``arm_sag``, the case is
made again from its key and seed, read back as explain reads it, and the truth's noise-free
signature s (DESIGN.md's physics at the truth's parameters, at the touches) and the verdict's
columns X (its linear parameters; a searched one, arm_sag's p or the warm-up's tau_s, at every
value of its grid) are taken after explain's nuisance (each round's tilt and offset, M):

    cc   = |P_MX M s| / |M s|, best over the verdict's grid: the canonical correlation of the
           truth's signature with the verdict's span (1: the verdict reproduces it exactly);
    sep  = |M s - P_MX M s|^2 / (2 sigma^2) nats: the log likelihood ratio, at the truth, of the
           truth's own model over the verdict's best fit (sigma the case's noise sd). It is all
           the data can say for the truth against the verdict; the Occam factors of the two
           priors come on top (form's three unused shape directions cost about 1.5-2 nats each,
           arm_sag's p search at most ln 5).

A miss with sep below 1 nat (the truth less than e : 1 likelier than the verdict even knowing the
truth's parameters) is not separable on that design: the right answer there is the pair in
``ambiguous_with``, and any rule can only trade such misses of one effect for the other's.

    python benchmarks/explain_separability.py RESULTS.json [--all] [--family single]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from explain_indep import cases  # noqa: E402
from explain_indep import generate as gen  # noqa: E402

NOT_SEPARABLE_NATS = 1.0


def truth_signature(entry: dict, x: np.ndarray, y: np.ndarray, plate: str) -> np.ndarray | None:
    """The truth's reading change at the touches (mm), DESIGN.md's physics; None if not form or
    arm_sag."""
    if entry["effect"] == "form":
        return gen.form_shape(np.asarray(entry["weights_mm"], float), x, y, plate)
    if entry["effect"] == "arm_sag":
        r = np.hypot(x - gen.BASE[0], y - gen.BASE[1]) / 1000.0
        return entry["sag_mm_at_1m"] * r ** entry["p"]
    return None


def verdict_columns(name: str, params: dict, design) -> list[np.ndarray]:
    """The verdict's columns, one matrix per value of its searched parameter (else one)."""
    from adaptive_cal import effects
    from adaptive_cal.analysis.explain.core import belief_rows

    e = effects.get(name)
    first = {k: (v[0] if isinstance(v, list) else v) for k, v in (params or {}).items()}
    per_round = any(isinstance(v, list) for v in (params or {}).values())
    grid = e.grid(design.features, design.geometry) if e.searched else {}
    if not e.plain:  # only a searched linear part (arm_sag): its column is the effect
        first.update({n: first.get(n, 0.0) for n in e.searched})
    choices = [first]
    if len(grid) == 1 and not {"x_mm", "y_mm"} & set(grid):
        (key, values), = grid.items()
        choices = [{**first, key: float(v)} for v in values]
    out = []
    for p in choices:
        X, _ = belief_rows(name, p, design.features, design.geometry)
        out.append(design.per_round(X) if per_round and design.rounds > 1 else X)
    return out


def separation(rec: dict, seed: int) -> dict | None:
    """cc and sep of one case record (module docstring), or None where not computed."""
    from adaptive_cal.analysis.explain.candidates import Context
    from adaptive_cal.analysis.explain.design import build_design
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording

    truth = rec["truth"]["effects"]
    if len(truth) != 1 or rec["verdict"] in ("none", "unexplained", None):
        return None
    spec = next(s for s in cases.table(int(rec["key"].rsplit("/", 1)[1]) + 1)
                if cases.spec_key(s) == rec["key"])
    case = cases.build(spec, seed)
    with tempfile.TemporaryDirectory() as tmp:
        cell_path, paths = gen.write(case, Path(tmp))
        design = build_design([read_recording(p) for p in paths], load_cell(cell_path))
    f = design.features
    s = truth_signature(truth[0], np.asarray(f.x_mm), np.asarray(f.y_mm), case.plate)
    if s is None:
        return None
    ctx = Context.of(design)
    ms = ctx.project(s)
    best = np.inf
    for X in verdict_columns(rec["verdict"], rec.get("params"), design):
        Q, _ = np.linalg.qr(ctx.project(X))
        best = min(best, float(np.sum((ms - Q @ (Q.T @ ms)) ** 2)))
    norm2 = float(ms @ ms)
    return {"cc": float(np.sqrt(max(1.0 - best / norm2, 0.0))),
            "sep_nats": best / (2.0 * case.noise_mm ** 2),
            "deficit_nats": float(rec["candidates"].get(rec["verdict"], np.nan)
                                  - rec["candidates"].get(truth[0]["effect"], np.nan))}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("--all", action="store_true", help="every case, not only the misses")
    ap.add_argument("--family", default="single,rounds_shared_form")
    ap.add_argument("--min-sigma", type=float, default=6.0)
    args = ap.parse_args(argv)
    data = json.loads(args.results.read_text(encoding="utf-8"))
    fams = set(args.family.split(","))
    rows = []
    for rec in data["cases"]:
        if "error" in rec or rec["family"] not in fams or rec["k_sigma"] < args.min_sigma:
            continue
        names = [e["effect"] for e in rec["truth"]["effects"]]
        if names[0] not in ("form", "arm_sag") or (not args.all and rec["verdict"] in names):
            continue
        sep = separation(rec, data["seed"])
        if sep is None:
            continue
        rows.append((rec, sep))
        print(f"{rec['key']:<48} {rec['verdict']:>13} p {rec['probability']:.2f} "
              f"amb {','.join(rec['ambiguous_with']) or '-':<12} cc {sep['cc']:.4f} "
              f"sep {sep['sep_nats']:6.2f} nats, log BF deficit {sep['deficit_nats']:5.2f}")
    miss = [(r, s) for r, s in rows if r["verdict"] not in [e["effect"] for e in r["truth"]["effects"]]]
    if miss:
        k = sum(s["sep_nats"] < NOT_SEPARABLE_NATS for _, s in miss)
        k3 = sum(s["sep_nats"] < 3.0 for _, s in miss)
        flagged = sum(bool(r["ambiguous_with"]) for r, s in miss if s["sep_nats"] < NOT_SEPARABLE_NATS)
        print(f"{len(miss)} misses (form/arm_sag truth, >= {args.min_sigma:g} sigma, {sorted(fams)}): "
              f"{k} not separable (sep < {NOT_SEPARABLE_NATS:g} nat; {flagged} of them with "
              f"ambiguous_with), {k3} below 3 nats, {len(miss) - k3} at >= 3 nats")


if __name__ == "__main__":
    main()
