"""``explain``: calibrate, locate the mismatch, name the left-out physics, model it, show the fit.

The verdict is the candidate with the largest evidence (the most probable effect: the Bayes
decision) when its log Bayes factor against ``none`` exceeds ``THRESHOLD`` (calibrated on null
recordings, benchmarks/bench_explain.py); otherwise ``none``. A tool that names the wrong physics
with confidence is worse than none, so the findings say how sure they are: ``verdict_probability``
(posterior probability of the verdict: none has prior 1/2, the candidates share the other half;
``verdict_probabilities`` gives back to a runner-up that fits as well the part of the lead that is
only its prior's Occam factor, up to ``OCCAM_NATS``) and
``ambiguous_with`` (candidates whose posterior odds against the verdict, in those same
probabilities, are at least 1 : 9, i.e. within ``AMBIGUOUS`` = ln 9 nats -- on a plate design
with the robot base along x, arm_sag and a bow are the usual pair: sag with p near 1 is a bow
across the reach, ``benchmarks/explain_separability.py``).

Readings that disagree with every probable model are suspect readings (``suspects``): listed in
``suspect_readings``, counted in ``readings`` and kept out of everything else (``_screened``).
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, replace

import numpy as np

from adaptive_cal import effects
from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.recording import Recording
from adaptive_cal.analysis.explain.averaging import averaged
from adaptive_cal.analysis.explain.beside import beside_verdict
from adaptive_cal.analysis.explain.params import effect_params, held, summary as _summary
from adaptive_cal.analysis.explain.candidates import Candidate, Context
from adaptive_cal.analysis.explain.design import Design, build_design
from adaptive_cal.analysis.explain.evidence import Projector, loo_residuals, prior_precision
from adaptive_cal.analysis.explain.heavy import heavy_tailed
from adaptive_cal.analysis.explain.identify import not_identifiable
from adaptive_cal.analysis.explain.inputs import (checked_recording, checked_threshold,
                                                  plausible_tilt)
from adaptive_cal.analysis.explain.locate import locate
from adaptive_cal.analysis.explain.rounds import flatness_change
from adaptive_cal.analysis.explain.spans import covering
from adaptive_cal.analysis.explain.structure import residual_structure, structure_probability
from adaptive_cal.analysis.explain.suspects import model_probabilities, screened

THRESHOLD = 1.0  # log Bayes factor against none; on 1,200 nulls: FP 3.75 % (docs/explain.md)
# A runner-up is ``ambiguous_with`` the verdict while the two's posterior odds (the probabilities
# explain reports, ``verdict_probabilities``) are below 9 : 1 -- the verdict's probability
# against that runner-up alone below 0.9, the lowest class the calibration calls sure (at most
# 10 % wrong at 0.9-0.99). So a verdict given below 0.9 because of a runner-up always names it;
# at >= 0.9 this rule lists none (every other candidate holds <= 0.1 <= p / 9), only ``covering``
# may (a span that holds the verdict's signature and fits as well).
AMBIGUOUS = float(np.log(9.0))  # nats of posterior log odds, verdict over runner-up


@dataclass
class Explanation:
    """Everything explain found: ``findings`` (the JSON the command prints and writes) and the
    arrays the figures need."""

    findings: dict
    context: Context
    candidates: list[Candidate]
    winner: Candidate | None
    residual_before: np.ndarray
    residual_after: np.ndarray


def _calibration(ctx: Context, sigma: float, winner: Candidate | None = None) -> list[dict]:
    """The tilt of every round: least squares on the nuisance alone, or, with a verdict, beside
    the named effect (its columns under the prior the evidence gave it, as the refit's leave-one
    -out): a drift taken for tilt had put b 21 sd off its truth (an outside audit, 2026-11-29)."""
    n, y = ctx.nuisance, ctx.design.target
    if winner is None:
        coef, *_ = np.linalg.lstsq(n, y, rcond=None)
        cov = sigma ** 2 * np.linalg.pinv(n.T @ n)
    else:
        d, k0 = np.hstack([n, winner.columns]), n.shape[1]
        a = d.T @ d
        a[k0:, k0:] += winner.noise_var * prior_precision(winner.prior_var)
        a_inv = np.linalg.pinv(a)
        coef, cov = (a_inv @ d.T @ y)[:k0], winner.noise_var * a_inv[:k0, :k0]
    from adaptive_cal.analysis.flatness import tilt_correction_deg

    out = []
    for r in range(ctx.design.rounds):
        a, b, c = coef[3 * r:3 * r + 3]
        sa, sb, sc = np.sqrt(np.diag(cov)[3 * r:3 * r + 3])
        rx, ry = tilt_correction_deg(float(a), float(b))  # result.json's correction, its signs
        out.append({"a": float(a), "b": float(b), "c": float(c), "a_std": float(sa),
                    "b_std": float(sb), "c_std": float(sc),
                    # the slope angles atan(a), atan(b): not the correction (kept as they were)
                    "about_y_deg": float(np.degrees(np.arctan(a))),
                    "about_x_deg": float(np.degrees(np.arctan(b))),
                    "rx_deg": rx, "ry_deg": ry})
    return out


OCCAM_NATS = 2.0  # the part of an evidence lead that is prior, not fit, is trusted only beyond this


def verdict_probabilities(ctx: Context, cands: list[Candidate]) -> np.ndarray:
    """``model_probabilities`` made robust to the effects' priors: where a runner-up fits the data
    about as well as the best candidate (its residual sum of squares, at the posterior mean, is at
    most the best's plus 2 v x its evidence deficit), the deficit is the Occam factor of its
    prior (more parameters, a wider prior), not the data's word, and it is the least certain
    part of the answer: up to ``OCCAM_NATS`` of that prior part is given back to the runner-up
    (prior odds known within a factor e^2). sag inside form's span, a bow named arm_sag at
    p 0.976 for its one parameter: the probability falls below 0.9."""
    if not cands:
        return model_probabilities(cands)
    rss = np.array([float(np.sum((ctx.yt - ctx.project(c.columns) @ c.mean) ** 2)) for c in cands])
    lbf = np.array([c.log_bf for c in cands])
    b = int(np.argmax(lbf))
    v = cands[b].noise_var
    gap = np.maximum(rss - rss[b], 0.0)
    # an exact fit (every reading the nominal: v = 0) has no Occam part to give back
    fit_gap = np.divide(gap, 2.0 * v, out=np.where(gap > 0, np.inf, 0.0), where=v > 0)
    lift = np.clip(lbf[b] - lbf - fit_gap, 0.0, OCCAM_NATS)
    return model_probabilities([replace(c, log_bf=float(l)) for c, l in zip(cands, lbf + lift)])


def ambiguous_runner_ups(cands: list[Candidate], prob: np.ndarray, winner: Candidate | None,
                         threshold: float = THRESHOLD) -> list[str]:
    """Candidates above the threshold whose probability (``prob``: none first, then ``cands``,
    as ``verdict_probabilities`` gives them) is at least the verdict's / e^AMBIGUOUS (odds 1 : 9),
    most probable first: the verdict is not sure against any of them alone."""
    if winner is None:
        return []
    pw = float(prob[1 + cands.index(winner)])
    out = [(float(prob[1 + i]), c.effect) for i, c in enumerate(cands)
           if c is not winner and c.log_bf > threshold
           and np.log(pw) - np.log(max(float(prob[1 + i]), 1e-300)) < AMBIGUOUS]
    return [name for _, name in sorted(out, key=lambda t: -t[0])]


def _screened(design: Design):
    """Score, judge every reading against every model (``suspects.screened``), set the most
    probable suspects aside and score again, until no reading is a suspect: the suspects are
    kept out of the evidence, the verdict and the refit. Inside the fitted bump's reach only the
    most probable suspect goes in a pass (``suspects.apart``), so a spike does not make its
    neighbour look bad through a bump fitted to the spike, and it is judged with the bump's
    centre and radius integrated out, its state integrated out of the evidence. Then ``heavy``:
    where the residuals (the suspects' included) say the noise is heavy-tailed, every log BF is
    lowered to what it is against a heavy-tailed none."""
    scored_design, ctx, cands, found = screened(design)
    f = design.features
    suspects = [{"seq": int(design.seq[i]), "x_mm": float(f.x_mm[i]), "y_mm": float(f.y_mm[i]),
                 "residual_mm": res, "probability": prob,
                 **({"round": int(design.round_index[i])} if design.rounds > 1 else {})}
                for i, prob, res in sorted(found)]
    cands, noise = heavy_tailed(ctx, cands, np.array([res for _, _, res in found]))
    return scored_design, ctx, cands, suspects, noise


def serially_deflated(cands: list[Candidate], structure: dict) -> tuple[list[Candidate], dict | None]:
    """Every log BF scaled by the readings' effective share where the residual of the library's
    best explanation says consecutive readings are correlated (the serial-correlation test of
    ``structure`` is real): the candidates, best first, and {lag1_correlation,
    evidence_factor}; unchanged and None otherwise.

    The evidence takes the readings as independent. Under an AR(1) disturbance of lag-1
    correlation rho, a slowly varying column's least-squares coefficient has about
    (1 + rho) / (1 - rho) times the variance that independence gives -- n readings are worth
    n (1 - rho) / (1 + rho) (Bayley & Hammersley 1946, "The effective number of independent
    observations in an autocorrelated time series", JRSS Suppl. 8, 184-197) -- so its chi-square
    and the log BF that grows with it are scaled by that share. rho is the disturbance's own
    (``structure.ar1_rho``): the residual's lag-1 correlation understates it, as the library's
    fit has taken up part of the disturbance, and the AR(1) process whose residual after the
    same fit has that correlation is solved for. A disturbance that
    lasts from touch to touch makes a wander along the path look like drift, form or sag (25 %
    of 100 AR(1) nulls, rho = 0.5, named a library effect before the test, 19 % after, 1 at p >= 0.9;
    benchmarks/bench_explain_noise.py)."""
    test = structure.get("tests", {}).get("serial correlation")
    if not test or not test.get("real"):
        return cands, None
    rho = float(np.clip(test["rho"], 0.0, 0.95))
    factor = (1.0 - rho) / (1.0 + rho)
    out = sorted((replace(c, log_bf=float(c.log_bf * factor)) if c.log_bf > 0 else c
                  for c in cands), key=lambda c: -c.log_bf)
    return out, {"lag1_correlation": float(test["lag1_correlation"]),
                 "evidence_factor": float(factor)}


def _separated(entries: list[dict], verdict: str, ambiguous: list[str]) -> list[dict]:
    """The verdict is never listed as not identifiable where the data separated it (nothing is
    ``ambiguous_with`` it): a named bump is not also "not identifiable" for the design's
    coverage (a smaller one may still sit between touches; the coverage note stays for bumps
    when local_defect is not the verdict)."""
    if ambiguous:
        return entries
    return [e for e in entries if e["effect"] != verdict or e.get("not_testable")]


def explain_design(design: Design, *, threshold: float = THRESHOLD,
                   rng: np.random.Generator | int = 0, identifiability: bool = True) -> Explanation:
    """Run the whole analysis on a built design (see ``explain`` for recordings and a cell).

    ``rng``: a Generator, or the seed of one, for the bootstrap of the round-to-round flatness
    change (the CLI's ``--seed``).
    """
    # readings exactly the nominal after the tilt: every model fits exactly, its evidence is
    # 0/0 (NaN, taken as no preference below the readout step); numpy's warnings say no more
    nuisance = design.nuisance()[0]
    plausible_tilt(design, nuisance)  # positions in m: refused before the search, not after it
    exact = not np.any(Projector.of(nuisance)(design.target))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore") if exact else nullcontext():
        design, ctx, cands, suspects, noise = _screened(design)
    sigma = float(np.sqrt(ctx.yt @ ctx.yt / max(ctx.m, 1)))
    # the whole mismatch below the probe's readout step (a noise-free simulation written to a
    # few decimals): what is left is rounding, not physics -- no effect can be shown
    readout = sigma < design.readout_mm
    if readout:  # an exact fit (sigma 0) has no finite evidence: the data cannot tell, 0
        cands = [replace(c, log_bf=min(c.log_bf, 0.0) if np.isfinite(c.log_bf) else 0.0)
                 for c in cands]
    # the named candidates' sds and intervals averaged over their searched grids
    cands = [averaged(ctx, c) if c.log_bf > threshold else c for c in cands]
    best = cands[0] if cands else None
    winner = best if best and best.log_bf > threshold else None
    # rounding has no structure to test (a lag-1 correlation of 1e-17 residuals is not one)
    structure = residual_structure(ctx, cands, winner, threshold, design.noise_stated_mm,
                                   tested=not readout)
    cands, serial = serially_deflated(cands, structure)
    if serial is not None:  # the evidence re-judged: where no library effect survives it, the
        best = cands[0] if cands else None  # readings' correlation is the finding
        winner = best if best and best.log_bf > threshold else None
        if winner is None and structure.get("finding"):
            structure["unexplained"] = True
    unexplained = structure.pop("unexplained") and not readout
    nearest = winner
    if unexplained:
        winner = None  # the library names less than half of the structure: no library name
    left_out = []
    for c in cands:
        if c.log_bf <= threshold:
            continue
        params, stds, iv95 = effect_params(c, design, intervals_95=True)
        left_out.append({"effect": c.effect, "params": params, "params_std": stds,
                         "parameter_interval_95": iv95, "held": sorted(held(c)),
                         "log_bayes_factor": float(c.log_bf), "summary": _summary(c, params, stds, design),
                         "sharing": c.sharing})
    if winner is not None:
        beside_verdict(ctx, winner, cands, left_out, design, threshold, serial)
    before = ctx.yt
    N = ctx.nuisance
    loo0 = loo_residuals(N, design.target, np.zeros(N.shape[1]))
    if winner is not None:
        after = before - ctx.project(winner.columns) @ winner.mean
        D = np.hstack([N, winner.columns])
        k0, k1 = N.shape[1], winner.columns.shape[1]
        pen = np.zeros((k0 + k1, k0 + k1))
        pen[k0:, k0:] = winner.noise_var * prior_precision(winner.prior_var)
        loo1 = loo_residuals(D, design.target, pen)
    else:
        after, loo1 = before, loo0
    rms = lambda r: float(np.sqrt(np.mean(r ** 2)))
    prob = verdict_probabilities(ctx, cands)
    ambiguous = ambiguous_runner_ups(cands, prob, winner, threshold)
    ambiguous += [n for n in covering(ctx, winner, cands, threshold) if n not in ambiguous]
    verdict = "unexplained" if unexplained else (winner.effect if winner else "none")
    findings = {
        "verdict": verdict,
        "verdict_probability": (structure_probability(structure["finding"]["p_value"]) if unexplained else
                                float(prob[1 + cands.index(winner)] if winner else prob[0])),
        "ambiguous_with": ambiguous,
        "left_out": left_out,
        "suspect_readings": suspects,
        "readings": {"total": design.n + len(suspects), "used": design.n,
                     "suspect": len(suspects), "noise": {
                         "distribution": "gaussian" if noise["nu"] is None else "student_t",
                         "dof": noise["nu"], "log_lr_vs_gaussian": noise["log_lr_vs_gaussian"],
                         "judged_under": noise["judged_under"],
                         **({"serial": serial} if serial is not None else {})}},
        # below the readout step no effect has a size in sigmas (sigma is rounding, or 0)
        "not_identifiable": (_separated(not_identifiable(
            ctx, None if readout else sigma, verdict=verdict, ambiguous=tuple(ambiguous)),
            verdict, ambiguous) if identifiability else []),
        "mismatch": locate(ctx),
        "fit": {"rms_before_mm": rms(before), "rms_after_mm": rms(after),
                "cv_rms_before_mm": rms(loo0), "cv_rms_after_mm": rms(loo1),
                "log_bayes_factor": float(winner.log_bf) if winner else 0.0,
                "cv": "leave-one-out (exact shortcut; nonlinear parameters held at their best value)"},
        "model": None,
        "candidates": [{"effect": c.effect, "log_bayes_factor": float(c.log_bf),
                        "sharing": c.sharing} for c in cands],
        "calibration": _calibration(ctx, sigma, winner),
        "threshold": {"log_bayes_factor": threshold},
        "structure_after_model": structure,
    }
    if readout:
        findings["readout_limited"] = {
            "rms_mm": sigma, "readout_mm": design.readout_mm,
            "is": "the mismatch's RMS after the tilt is below the probe's readout step "
                  "(probe.resolution_mm): no effect is named, every log Bayes factor is at most 0"}
    if unexplained:
        findings["unexplained"] = structure["finding"]
        findings["unexplained"]["nearest_library_effect"] = nearest.effect if nearest else None
    if design.rounds > 1:
        findings["rounds"] = flatness_change(design, np.random.default_rng(rng))
    return Explanation(findings, ctx, cands, winner, before, after)


def explain(recordings, cell, *, threshold: float = THRESHOLD,
            rng: np.random.Generator | int = 0, identifiability: bool = True) -> Explanation:
    """Calibrate the cell's unknowns on the recordings (rounds), then ``explain_design``.

    ``recordings``: a Recording or a recording's path, or a list of them (one per round, in
    order); ``cell``: a Cell or the cell file's path. A recording or cell file that cannot be
    read raises the reader's error (it names the file and the line). ``threshold``, ``rng``,
    ``identifiability``: as ``explain_design``."""
    import os

    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording

    if isinstance(recordings, (Recording, str, os.PathLike)):
        recordings = [recordings]
    # one built in memory is checked as the reader checks a file (``inputs``)
    recordings = [checked_recording(r, r.path or f"recording {i}") if isinstance(r, Recording)
                  else read_recording(r) for i, r in enumerate(recordings)]
    if not recordings:
        raise ValueError("explain needs at least one recording")
    threshold = checked_threshold(threshold)
    if not isinstance(cell, Cell):
        cell = load_cell(cell)
    if not isinstance(rng, np.random.Generator) and (
            isinstance(rng, bool) or not isinstance(rng, (int, np.integer)) or rng < 0):
        raise ValueError(f"rng = {rng!r}: a numpy Generator or a seed (an integer >= 0)")
    return explain_design(build_design(recordings, cell), threshold=threshold, rng=rng,
                          identifiability=identifiability)


def belief_rows(effect: str, params: dict, features: effects.Features,
                geometry: effects.Geometry) -> tuple[np.ndarray, tuple[str, ...]]:
    """Measurement rows of an effect's linear parameters, for a belief that keeps estimating them.

    reading_change(effect, params) = rows @ theta; theta named by the returned tuple (form: shape
    coefficients in mm). Nonlinear parameters are held at ``params``; linear parameters that
    ``params`` does not name and that need a search are left out (a linear drift: no warm-up row).
    """
    e = effects.get(effect)
    fixed = {k: v for k, v in params.items() if k in e.nonlinear}
    names = tuple(k for k in e.linear if k in e.plain or k in params)
    return e.regressor(features, geometry, fixed, names), names


__all__ = ["explain", "explain_design", "Explanation", "belief_rows", "effect_params",
           "ambiguous_runner_ups", "THRESHOLD", "AMBIGUOUS"]
