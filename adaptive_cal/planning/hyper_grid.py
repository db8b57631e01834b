"""The hyper-parameter posterior on a grid, where its Laplace approximation fails: few readings.

``prior.hyper_posterior`` places 7 sigma points by the curvature at the MAP (Laplace). With few
readings (10-20 on a plate of 30 coarse coefficients) the posterior of theta = (sigma_f, l,
sigma_n) is broad and skewed along the (sigma_f, l) ridge; the MAP sits at its long-l end and
the curvature there says little about the mass. Measured at the stop of realistic plates
(benchmarks/bench_plates.py, seam family, 14-18 touches): the belief mixed over an exact 11^3
grid covered 0.88 / 0.93 of the plate where the sigma points covered 0.82 / 0.89.

Here: the log posterior log N(y; 0, H C0(theta) H^T + sigma_n^2 W^-1) + log hyper-prior (the
same terms ``prior.hyper_posterior`` maximises), exactly, at every node of a PER_AXIS^3 grid
in log theta centred on the MAP, HALF_WIDTH hyper-prior standard deviations each way (the
posterior is no wider than the prior; 2.5 sd holds 98.8 % of a Gaussian's mass per axis);
weights proportional to the density (equal cell volumes). Deterministic quadrature, closed form
at each node: no Monte Carlo. When one node holds more than CONCENTRATED of the mass the
posterior is narrower than the grid's spacing (many readings): the grid cannot resolve it and
the Laplace points (good there) are kept (``grid_points`` returns None)."""
from __future__ import annotations

import itertools

import numpy as np

from adaptive_cal.gaussian.prior import Hyper, PriorModel, log_evidence

PER_AXIS = 5  # nodes per hyper-parameter: 125 closed-form evidences, 0.2-0.4 s at 14-20 readings
HALF_WIDTH = 2.5  # hyper-prior sds each way from the MAP
CONCENTRATED = 0.5  # one node with more mass: the grid does not resolve the posterior
NEGLIGIBLE = 1e-3  # nodes below this share of the largest weight are dropped (renormalised)


def grid_points(model: PriorModel, rows, heights, weights, extra, centre: Hyper,
                per_axis: int = PER_AXIS) -> list[tuple[Hyper, float]] | None:
    """Weighted hyper-parameter points of the posterior on the grid around ``centre`` (the MAP,
    first in the list), or None when the grid does not resolve it (see the module)."""
    mu = np.log(np.asarray(model.hyper0, float))
    sd = np.asarray(model.hyper_log_std, float)
    best = np.log(np.asarray(centre, float))
    axes = [best[k] + HALF_WIDTH * sd[k] * np.linspace(-1, 1, per_axis) for k in range(3)]
    rows, heights = np.asarray(rows, float), np.asarray(heights, float)
    w = np.ones(len(heights)) if weights is None else np.asarray(weights, float)
    nodes, logp = [], []
    for x in itertools.product(*axes):
        h = Hyper(*np.exp(x).tolist())
        cov = model.belief(h, extra).cov
        lp = log_evidence(rows, heights, cov, h.noise_std_mm**2 / w)
        nodes.append(h)
        logp.append(float(lp) - 0.5 * float(np.sum(((np.asarray(x) - mu) / sd) ** 2)))
    logp = np.asarray(logp)
    if not np.all(np.isfinite(logp)):
        return None
    p = np.exp(logp - logp.max())
    p /= p.sum()
    if p.max() > CONCENTRATED:
        return None
    keep = p >= NEGLIGIBLE * p.max()
    centre_index = len(nodes) // 2  # the middle node of an odd grid is the MAP itself
    order = [centre_index] + [i for i in np.flatnonzero(keep) if i != centre_index]
    total = p[order].sum()
    return [(nodes[i], float(p[i] / total)) for i in order]
