"""Every other candidate judged beside the verdict: the verdict's columns join the nuisance and
the candidate's search runs again (its look-elsewhere penalty included) -- "is it there as
well", not "does it explain the residual instead" (docs/explain.md, beside the verdict)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from adaptive_cal.analysis.explain.averaging import averaged
from adaptive_cal.analysis.explain.candidates import Candidate, Context, score_candidates
from adaptive_cal.analysis.explain.design import Design
from adaptive_cal.analysis.explain.evidence import Projector, log_evidence
from adaptive_cal.analysis.explain.params import effect_params, held, summary


def context_given(ctx: Context, winner: Candidate) -> Context:
    """The null model with the verdict's columns added to the nuisance (flat prior): a second
    candidate scored in it answers "is it there as well", not "does it explain the residual
    instead" -- what a cell file with the verdict among ``simulation.unknown`` would ask."""
    d = ctx.design
    N = np.hstack([ctx.nuisance, winner.columns])
    proj = Projector.of(N)
    yt = proj(d.target)
    m = d.n - proj.rank
    lz0, w0 = log_evidence(np.zeros((d.n, 0)), yt, np.zeros(0), m)
    return Context(d, N, proj, yt, m, lz0, w0)


def beside_verdict(ctx: Context, winner: Candidate, cands: list[Candidate],
                   left_out: list[dict], design: Design, threshold: float,
                   serial: dict | None) -> list[dict]:
    """Every other candidate scored again with the verdict in the model (``context_given``).
    A ``left_out`` entry gets ``given_verdict`` {``log_bayes_factor``, ``left_out`` (above the
    threshold), ``params``, ``params_std``}: each entry of ``left_out`` beats ``none`` alone,
    and most only stand in for the verdict's residual (Cheng's rounds: a warm-up of -808 um at
    log BF 36.8 against none is 1.5 beside the form, at -114 um). A candidate below the
    threshold alone that passes it beside the verdict -- an effect hidden by a larger one (a
    200 um bump under Cheng's 0.6 mm form: 0.5 alone, 1.5 beside it after the serial-correlation
    scaling, 9.5 before) -- is appended to
    ``left_out`` with its fit beside the verdict. Evidence scaled for serially correlated
    readings as the main scores are; not lowered for heavy-tailed noise (``readings.noise``).
    Returns ``left_out``."""
    given = context_given(ctx, winner)
    factor = serial["evidence_factor"] if serial else 1.0
    alone = {c.effect: c for c in cands}
    listed = {e["effect"]: e for e in left_out}
    for c in score_candidates(given, skip=frozenset(design.untestable) | {winner.effect}):
        lbf = c.log_bf * (factor if c.log_bf > 0 else 1.0)
        e = listed.get(c.effect)
        if e is None and lbf <= threshold:
            continue
        if lbf > threshold:
            c = averaged(given, replace(c, log_bf=lbf))
        params, stds, iv95 = effect_params(c, design, intervals_95=True)
        gv = {"log_bayes_factor": float(lbf), "left_out": bool(lbf > threshold),
              "params": params, "params_std": stds}
        if e is not None:
            e["given_verdict"] = gv
            continue
        first = alone.get(c.effect)
        left_out.append({"effect": c.effect, "params": params, "params_std": stds,
                         "parameter_interval_95": iv95, "held": sorted(held(c)),
                         "log_bayes_factor": float(first.log_bf) if first else None,
                         "summary": summary(c, params, stds, design) + " (beside the verdict)",
                         "sharing": c.sharing, "given_verdict": gv})
    return left_out
