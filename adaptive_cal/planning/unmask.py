"""A gross error that hides in the noise it inflated (an outside audit, 2026-12-01).

A fused reading is judged again at each refit under its leave-one-out predictive with the
learned noise (``survey.reweighed``). But the noise was learned with the gross error in: one
reading 55 um off among 30 of a 6 um probe was learned as 11.2 um of noise, under which it
sits 4 sd out, short of a flag; it kept its full weight, held the map 20 um off there, and the
run never met its bound (its twin without the error stopped at 30 touches).

Here the reading most at odds with the others (the largest |leave-one-out z|, at least
``Z_TRIAL``, among those not yet weighted out) is judged by comparing two models of all the
readings, each with its own hyper-parameters integrated out (Laplace's method,
``prior.log_evidence_kernel``):

    good:   p(y | all genuine) (1 - eps)
    gross:  p(y without i | the rest genuine) eps / stroke        (the gate's outlier law)

so under "gross" the noise is learned without the reading. Its probability of being a gross
error is the second's share; its weight falls to 1 - p where p reaches ``gate.FLAG_P``.
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.gaussian import checks
from adaptive_cal.gaussian.prior import log_evidence_kernel
from adaptive_cal.planning.gate import FLAG_P, OUTLIER_PRIOR, W_MIN

Z_TRIAL = 2.5  # a reading this many sd from its leave-one-out predictive is judged this way


def unmasked(model, prior, rows, heights_mm, weights, hyper, extra, stroke_mm):
    """The weights with the most discordant reading's lowered (module docstring), or None."""
    rows, y = np.asarray(rows, float), np.asarray(heights_mm, float)
    w = np.asarray(weights, float)
    if len(y) < 4:
        return None
    r = hyper.noise_std_mm ** 2
    loo = checks.leave_one_out(rows, y, prior.mean, prior.cov, r / w)
    z = np.where(w > 0.5, np.abs(loo.residual_mm) / np.sqrt(loo.variance_mm2), 0.0)
    i = int(np.argmax(z))
    if z[i] < Z_TRIAL:
        return None
    keep = np.arange(len(y)) != i
    genuine = w.copy()
    genuine[i] = 1.0  # judged as a reading, not at the weight an earlier judgement left it
    good = log_evidence_kernel(model, rows, y, hyper, genuine, extra) + np.log1p(-OUTLIER_PRIOR)
    gross = (log_evidence_kernel(model, rows[keep], y[keep], hyper, w[keep], extra)
             + np.log(OUTLIER_PRIOR) - np.log(stroke_mm))
    p = float(1.0 / (1.0 + np.exp(np.clip(good - gross, -700, 700))))
    if p < FLAG_P or max(1.0 - p, W_MIN) >= w[i] - 1e-12:
        return None
    out = w.copy()
    out[i] = max(1.0 - p, W_MIN)  # never raised, as every judgement of a reading
    return out
