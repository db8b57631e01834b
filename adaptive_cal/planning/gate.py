"""The gate, its retake and the reading's outlier probability: one pure judgement.

The likelihood of a reading is a mixture (an explicit outlier model): with probability
1 - eps it is the surface plus Gaussian noise, y ~ N(h^T m, s), s = h^T C h + r; with
probability eps (``OUTLIER_PRIOR``) it is a gross error that says nothing about the surface,
spread uniformly over the probe's usable stroke (density u = 1 / stroke width, mm^-1). The
posterior outlier probability of a reading is

    p = eps u / (eps u + (1 - eps) N(y; h^T m, s)).

The belief stays Gaussian: a fused reading gets the expected noise precision of the mixture,
(1 - p) / r (the EM / variational weight w = 1 - p; a gross error carries no precision), so it
is fused with noise r / w. Below ``FLAG_P`` a reading is fused as the plain Gaussian update
(w = 1, no flag); from ``FLAG_P`` on its p is written in the flags as ``outlier=0.12`` (two
decimals, ``OUTLIER_FLAG``) and the fusion, replay and refits use that rounded p, so a
recording reproduces every decision -- the gate's too: "p" below is the rounded p, so a reading
at 0.495 <= p < 0.5 (written ``outlier=0.50``) is gated. A reading more likely an outlier than not, or beyond the
Mahalanobis gate d = |y - h^T m| / sqrt(s) > g, is not fused but retaken:

* no retake pending, d <= g and p < ``GATE_P``: fused (weight 1 - p);
* no retake pending, otherwise: ``gated``, not fused; the same point is taken once more;
* the retake, d <= g and p < ``GATE_P``: fused (``retake``, weight 1 - p);
* the retake, otherwise but |y - y_first| <= g sqrt(2 r): fused with full weight (``retake``,
  ``surprise``: the surface really is there);
* otherwise: ``retake``, ``rejected``; neither reading is fused.

``judge`` takes the predictive (mean, variance) as a mixture of components (one Gaussian
usually; before the first refit, one per hyper-parameter point of the hyper-prior, see
``survey.judge``): an unlearned form amplitude no longer makes the gate retake genuine readings.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: prior probability that a reading is a gross error (the outlier component's weight)
OUTLIER_PRIOR = 0.01
#: posterior outlier probability from which the reading is flagged and down-weighted
FLAG_P = 0.05
#: posterior outlier probability from which the reading is retaken instead of fused
GATE_P = 0.5
#: the flag carrying a fused reading's outlier probability: ``outlier=0.12``
OUTLIER_FLAG = "outlier="
W_MIN = 1e-6  # the least weight a fused reading keeps: r / W_MIN, 5 um -> 5 mm, no pull


#: a retake is told at the gated reading's point: within this (mm) of its x, y. A robot that
#: reports where it stood, not where it was sent, is microns off: at 1 um a retake told 2 um away
#: went unrecognised and the same point was gated 99 times over (an outside audit, 2026-12-01);
#: two places the planner picks apart are a millimetre or more apart
SAME_POINT_MM = 0.1


class Retake(NamedTuple):
    """A gated reading that owes a second touch at the same point and approach height (mm)."""

    x_mm: float
    y_mm: float
    z_mm: float
    height_mm: float

    def at(self, x_mm: float, y_mm: float) -> bool:
        """True for a touch at this retake's point: only that one is its retake."""
        return abs(x_mm - self.x_mm) <= SAME_POINT_MM and abs(y_mm - self.y_mm) <= SAME_POINT_MM


class Told(NamedTuple):
    """The judgement of one reading: fused or not, the flags for the recording, the Mahalanobis
    distance, and whether the next ask is a retake. Carries the touch (position, approach
    height, the height it implies) so that ``survey.fuse`` needs nothing else; ``outlier_p`` is
    the posterior outlier probability the fusion uses: for a fused reading as flagged (0 below
    ``FLAG_P``); 0 for one not fused (nothing uses it; its ``outlier=p`` flag has the figure)."""

    fused: bool
    flags: tuple[str, ...]
    mahalanobis: float
    retake_next: bool = False
    x_mm: float = float("nan")
    y_mm: float = float("nan")
    z_mm: float = float("nan")
    height_mm: float = float("nan")
    outlier_p: float = 0.0

    @property
    def weight(self) -> float:
        """w = 1 - p: the share of the noise precision 1 / r a fused reading carries."""
        return 1.0 - self.outlier_p


class Predictive(NamedTuple):
    """The predictive law of a reading's height: a mixture of Gaussians N(mean_mm, var_mm2)
    with weights (one component for a plain Gaussian belief)."""

    means_mm: np.ndarray
    vars_mm2: np.ndarray
    weights: np.ndarray

    @staticmethod
    def gaussian(mean_mm: float, var_mm2: float) -> "Predictive":
        return Predictive(np.array([mean_mm]), np.array([var_mm2]), np.array([1.0]))

    def moments(self) -> tuple[float, float]:
        """Moment-matched (mean, variance) (mm, mm^2)."""
        w = self.weights / self.weights.sum()
        mean = float(w @ self.means_mm)
        return mean, float(w @ (self.vars_mm2 + (self.means_mm - mean) ** 2))

    def log_density(self, y_mm: float) -> float:
        """log sum_k w_k N(y; m_k, s_k) (mm^-1)."""
        w = self.weights / self.weights.sum()
        with np.errstate(divide="ignore"):  # a component of weight 0 (log 0 = -inf) adds nothing
            log_w = np.log(w)
        terms = (log_w - 0.5 * np.log(2 * np.pi * self.vars_mm2)
                 - 0.5 * (y_mm - self.means_mm) ** 2 / self.vars_mm2)
        top = terms.max()
        return float(top + np.log(np.exp(terms - top).sum()))


def outlier_probability(predictive: Predictive, y_mm: float, stroke_mm: float,
                        prior: float = OUTLIER_PRIOR) -> float:
    """p = eps u / (eps u + (1 - eps) f(y)), u = 1 / stroke_mm, f the predictive density."""
    if prior <= 0:
        return 0.0
    log_out = np.log(prior) - np.log(stroke_mm)
    log_in = np.log1p(-prior) + predictive.log_density(y_mm)
    return float(1.0 / (1.0 + np.exp(np.clip(log_in - log_out, -700, 700))))


def rounded_p(p: float) -> float:
    """The outlier probability as the flags carry it: 0 below ``FLAG_P``, else two decimals."""
    return 0.0 if p < FLAG_P else round(float(p), 2)


def outlier_flag(p: float) -> tuple[str, ...]:
    """``("outlier=0.12",)`` for a flagged probability, () for none."""
    return (f"{OUTLIER_FLAG}{p:.2f}",) if p >= FLAG_P else ()


def flagged_weight(flags) -> float:
    """The weight a recording row's flags give it: 1 - p, at least ``W_MIN`` (the run writes
    1.00 for p >= 0.995, and a weight of 0 is an infinite noise variance)."""
    return max(1.0 - flagged_p(flags), W_MIN)


def flagged_p(flags) -> float:
    """The outlier probability a recording row's flags carry (0 when none): replay's inverse
    of ``outlier_flag``."""
    for f in flags:
        if f.startswith(OUTLIER_FLAG):
            return float(f[len(OUTLIER_FLAG):])
    return 0.0


def judge(predictive: Predictive, height_mm: float, noise_var: float, gate_sigma: float,
          pending: Retake | None, x_mm: float, y_mm: float, z_mm: float, *,
          stroke_mm: float, outlier_prior: float = OUTLIER_PRIOR) -> Told:
    """The gate decision for one reading (see module docstring); changes nothing."""
    mean, var = predictive.moments()
    d = abs(height_mm - mean) / np.sqrt(var)
    p = rounded_p(outlier_probability(predictive, height_mm, stroke_mm, outlier_prior))
    where = (x_mm, y_mm, z_mm, height_mm)
    plausible = d <= gate_sigma and p < GATE_P
    flag = outlier_flag(p)
    if pending is None and not plausible:
        return Told(False, ("gated",) + flag, d, True, *where, 0.0)
    if pending is None or plausible:
        return Told(True, (("retake",) if pending else ()) + flag, d, False, *where, p)
    if abs(height_mm - pending.height_mm) <= gate_sigma * np.sqrt(2 * noise_var):
        return Told(True, ("retake", "surprise"), d, False, *where, 0.0)
    return Told(False, ("retake", "rejected") + flag, d, False, *where, 0.0)


def pending_after(told: Told, owed: Retake | None = None) -> Retake | None:
    """The retake owed after a judged reading: its own point when it was gated; else the one
    ``owed`` before it unless this reading was taken at its point (a reading elsewhere -- a
    batch told in order, a retake not taken -- is judged as a new one and leaves it owed)."""
    if told.retake_next:
        return Retake(told.x_mm, told.y_mm, told.z_mm, told.height_mm)
    if owed is not None and not owed.at(told.x_mm, told.y_mm):
        return owed
    return None
