"""A candidate's parameters as the effect table names and signs them, with their standard
deviations and 95 % intervals (``effect_params``), and its one-line summary (``summary``)."""
from __future__ import annotations

import numpy as np

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import Candidate
from adaptive_cal.analysis.explain.design import Design

Z95 = 1.959963984540054  # the normal 97.5 % quantile


def effect_params(cand: Candidate, design: Design, *, intervals_95: bool = False):
    """Parameters and standard deviations in the effect table's names and signs.

    Shared effects give numbers; effects fitted per round give one number per round. The sds
    are calibrated (``averaging``): a searched effect's are equivalent-normal sds of its refined
    grid posterior (``intervals``); a plain effect's come from its posterior averaged over the
    prior scale, and form's pv_mm from that posterior by the delta method (its interval clipped
    at zero). ``intervals_95``: also return the 95 % intervals (name -> [low, high], per round a
    list of them) as a third value.
    """
    effect = effects.get(cand.effect)
    names = cand.names
    k = len(names)
    blocks = 1 if cand.sharing == "shared" else design.rounds
    mean = cand.mean.reshape(blocks, k)
    std = np.sqrt(np.diag(cand.cov)).reshape(blocks, k)
    params, stds, ivs = [], [], []
    for b in range(blocks):
        cov = cand.cov[b * k:(b + 1) * k, b * k:(b + 1) * k]
        iv = {n: [float(m - Z95 * sd), float(m + Z95 * sd)] for n, m, sd in zip(names, mean[b], std[b])}
        if effect.derive is not None:  # form: pv_mm from the shape coefficients
            p, grads = effect.derive(mean[b], design.geometry)
            s = {n: float(np.sqrt(g @ cov @ g)) for n, g in grads.items()}
            iv.update({n: [max(p[n] - Z95 * s[n], 0.0), p[n] + Z95 * s[n]] for n in grads})
        else:
            p, s = {}, {}
        p.update({n: float(v) for n, v in zip(names, mean[b])})
        s.update({n: float(v) for n, v in zip(names, std[b])})
        s.update(cand.param_std)
        iv.update(cand.interval_95)
        p.update(cand.fixed)
        s.update({n: cand.nonlinear_std.get(n, 0.0) for n in cand.fixed})
        iv.update({n: [p[n] - Z95 * s[n], p[n] + Z95 * s[n]] for n in cand.fixed})
        for n, d in held(cand).items():  # in the effect's form, not fitted by this one
            p[n], s[n], iv[n] = d, 0.0, [d, d]
        params.append(p), stds.append(s), ivs.append(iv)
    if blocks == 1:
        out = params[0], stds[0], ivs[0]
    else:
        out = ({n: [p[n] for p in params] for n in params[0]},
               {n: [s[n] for s in stds] for n in stds[0]},
               {n: [i[n] for i in ivs] for n in ivs[0]})
    return out if intervals_95 else out[:2]


def held(cand: Candidate) -> dict[str, float]:
    """The effect's linear parameters that the candidate's form does not fit, at the value it
    holds them at (their default): a warm-up (amplitude_mm, tau_s) holds thermal_drift's
    rate_mm_per_s at 0, the linear drift holds amplitude_mm at 0. Every parameter DESIGN.md
    names is reported; these with sd 0 and the interval [value, value], listed as ``held``."""
    effect = effects.get(cand.effect)
    return {q.name: float(q.default) for q in effect.params
            if q.linear and q.name not in cand.names and q.name not in cand.fixed}


def summary(cand: Candidate, params: dict, stds: dict, design: Design) -> str:
    effect = effects.get(cand.effect)
    kept = held(cand)  # named last, not as the fitted main parameter
    text = effect.summary({k: v for k, v in params.items() if k not in kept}, stds)
    if cand.fixed:
        text += " at " + ", ".join(f"{k} = {v:g} (+- {cand.nonlinear_std.get(k, 0):.2g})"
                                   for k, v in cand.fixed.items())
        text += (f"; look-elsewhere penalty {cand.look_elsewhere:.2f} (log Bayes factor) over "
                 f"{cand.searched} values")
    if kept:
        text += "; " + ", ".join(f"{k} held at {v:g}" for k, v in kept.items())
    if design.rounds > 1 and cand.log_bf_shared_vs_per_round is not None:
        text += (f"; {cand.sharing.replace('_', ' ')} (log BF shared vs per round "
                 f"{cand.log_bf_shared_vs_per_round:.2f})")
    if effect.axis == "time" and design.time_blank:
        text += "; " + design.time_blank
    return text + f"; log BF vs none {cand.log_bf:.2f}"
