"""Heavy-tailed readings: a bump must beat "no bump with heavy-tailed noise", not only "no bump
with Gaussian noise".

The candidates' evidence (``evidence``) takes the reading noise as Gaussian. When a probe's
noise has heavy tails (Student-t), a few moderately large readings are expected anywhere, and
a bump fitted under one or two of them gains evidence it would not have against a heavy-tailed
``none``. So the noise model is judged on the residuals of the most probable model (the physics
accounted for, so a real effect does not pass for a tail), and where it is heavy-tailed every
candidate's log Bayes factor is corrected to the Student-t likelihood.

The noise model. Each reading's error is Student-t with nu degrees of freedom and scale s (a
scale mixture of normals: e_i ~ N(0, s^2 / w_i), w_i ~ Gamma(nu/2, nu/2)). For a fixed model
(columns D, penalty P of its prior) the maximum likelihood fit is found by EM (IRLS):

    w_i = (nu + 1) / (nu + r_i^2 / s^2),   coef = (D^T W D + P)^-1 D^T W y,
    s^2 = sum w_i r_i^2 / n.

Which noise. The Gaussian has prior ``GAUSSIAN_PRIOR`` = 1/2 (what the evidence assumes), the
rest is spread evenly over ``NU_GRID`` (Cauchy to nearly Gaussian); the most probable one given
the residuals of the most probable model is adopted, so a t is taken only when it gains more
than log(len(NU_GRID)) = 2.2 nats of likelihood over the Gaussian (measured: Gaussian residuals
of 72 readings are kept Gaussian in 98.5 %; tests/test_explain_heavy.py). The residuals are
those of the kept readings plus the leave-one-out residuals of the readings already set aside as
suspects: a suspect is a tail reading. A spurious bump that ate the two largest readings of a
heavy-tailed recording leaves Gaussian-looking residuals; the suspect it leaves does not. Under
the Gaussian a suspect is the screen's gross error (``screened_gains``), not a Gaussian reading.

The correction (Laplace: evidence = best likelihood x Occam factor; the Occam factors of the
prior are the same under either noise model to first order):

    log BF_t(M) = log BF(M) + [l_t(M) - l_N(M)] - [l_t(none) - l_N(none)],

l_t, l_N the maximised log likelihoods of model M (at its best nonlinear parameters) under the
t at the recording's nu and under the Gaussian. A bump that only explains a few tail readings
gains less over a heavy-tailed ``none`` than over a Gaussian one: its log BF drops. It is never
raised: an effect is named only where it beats ``none`` under both noise models the data allow
(the correction is a plug-in approximation, trusted to take evidence away, not to add it).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from adaptive_cal.analysis import tails
from adaptive_cal.analysis.explain.suspects import RATE, SCALE, _gross_logpdf, model_terms
from adaptive_cal.analysis.tails import t_loglik_at, t_scale_em

NU_GRID = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.0, 20.0, 50.0)  # Student-t dof tried; inf = Gaussian
GAUSSIAN_PRIOR = 0.5  # prior probability of Gaussian noise; the rest spread over NU_GRID


def _fit(D: np.ndarray, y: np.ndarray, penalty: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Residuals of the weighted penalised least squares fit (D^T W D + P) coef = D^T W y."""
    A = D.T @ (w[:, None] * D) + penalty
    A = 0.5 * (A + A.T) + 1e-12 * max(np.trace(A), 1e-300) / A.shape[0] * np.eye(A.shape[0])
    return y - D @ np.linalg.solve(A, D.T @ (w * y))


def gaussian_loglik(D: np.ndarray, y: np.ndarray, penalty: np.ndarray) -> float:
    """max log likelihood under Gaussian noise: -n/2 log(2 pi s^2) - n/2, s^2 = RSS / n."""
    return tails.gaussian_loglik_at(_fit(D, y, penalty, np.ones(y.size)))


def t_loglik(D: np.ndarray, y: np.ndarray, penalty: np.ndarray, nu: float) -> float:
    """max log likelihood under Student-t noise of ``nu`` dof (EM in the module docstring)."""
    r, s2 = t_scale_em(_fit(D, y, penalty, np.ones(y.size)), nu, lambda w: _fit(D, y, penalty, w))
    return t_loglik_at(r, s2, nu)


def tail_gains(residual: np.ndarray) -> np.ndarray:
    """l_nu - l_N per nu in ``NU_GRID`` of residuals held fixed (``analysis.tails.tail_gains``)."""
    return tails.tail_gains(residual, NU_GRID)


def screened_gains(kept: np.ndarray, set_aside: np.ndarray) -> np.ndarray:
    """l_nu - l_N per nu with the readings set aside as suspects explained as the screen explains
    them, gross errors at its rate (``suspects.RATE``, a normal of ``SCALE`` noise sds with a
    Cauchy tail), under the Gaussian; under each t either so or as its own tail, whichever is
    likelier. Judged as plain Gaussian readings, one spike on a Gaussian null made the noise a
    Student-t of 1.5 dof, set aside and counted as a tail both (an outside audit, 2026-12-01).
    Without suspects: ``tail_gains`` of the kept residuals, as before."""
    if not set_aside.size or not np.any(kept):
        return tail_gains(np.concatenate([kept, set_aside]))
    s = np.sqrt(max(float(kept @ kept) / kept.size, 1e-300))
    gross = float(np.sum(np.log(RATE) + _gross_logpdf(set_aside, SCALE * s)))
    t_every = tails.t_logliks(np.concatenate([kept, set_aside]), NU_GRID)
    t_kept = tails.t_logliks(kept, NU_GRID)
    return np.maximum(t_every, t_kept + gross) - (tails.gaussian_loglik_at(kept) + gross)


def noise_dof(gain: np.ndarray) -> float:
    """The most probable noise model given the gains l_nu - l_N: the Gaussian (inf) with prior
    ``GAUSSIAN_PRIOR``, each nu of ``NU_GRID`` with the rest shared evenly. With prior 1/2 the
    Gaussian is kept unless a t gains more than log(len(NU_GRID)) = 2.2 nats (the prior's
    Occam factor)."""
    logp = np.log((1.0 - GAUSSIAN_PRIOR) / len(NU_GRID)) + np.asarray(gain)
    best = int(np.argmax(logp))
    return NU_GRID[best] if logp[best] > np.log(GAUSSIAN_PRIOR) else float("inf")


def heavy_tailed(ctx, cands: list, set_aside: np.ndarray = np.zeros(0)) -> tuple[list, dict]:
    """The candidates with log BFs corrected to the recording's Student-t noise (module
    docstring), best first, and the noise finding {nu (None: Gaussian), log_lr_vs_gaussian,
    judged_under}. The noise is judged on the residuals of the most probable model, with the
    readings already ``set_aside`` as suspects (their leave-one-out residuals): a suspect is a
    tail reading, and a recording that has them is evidence of heavy tails."""
    terms = model_terms(ctx.nuisance, cands)
    y = ctx.design.target
    judge = int(np.argmax([0.0] + [c.log_bf - np.log(len(cands)) for c in cands]))  # none: 1/2
    D, P = terms[judge]
    gain = screened_gains(_fit(D, y, P, np.ones(y.size)), np.asarray(set_aside, float))
    nu = noise_dof(gain)
    noise = {"nu": None if np.isinf(nu) else nu, "log_lr_vs_gaussian": float(gain.max()),
             "judged_under": "none" if judge == 0 else cands[judge - 1].effect}
    if np.isinf(nu):
        return cands, noise
    delta = [t_loglik(D, y, P, nu) - gaussian_loglik(D, y, P) for D, P in terms]
    # the effect must beat none under both noise models the data allow: never raised
    out = [replace(c, log_bf=float(c.log_bf + min(d - delta[0], 0.0)))
           for c, d in zip(cands, delta[1:])]
    return sorted(out, key=lambda c: -c.log_bf), noise

