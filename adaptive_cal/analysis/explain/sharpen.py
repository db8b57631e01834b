"""A bump the search grid cannot resolve: its centre and radius refined continuously, and its
evidence integrated by Laplace's method about the refined point (an outside audit, 2026-12-01).

The bump search (``candidates._centres``) sums the evidence over a grid of centres (spacing
radius / 4) and radii ({15, 30, 60} mm): a Riemann sum of the integral over the continuous
prior, good while the likelihood is wider than a cell. A large bump on a dense design is far
sharper: 300 um of bell at radius 30 mm seen by 4,000 touches with 5 um noise pins its centre
to about 0.1 mm, and the nearest grid point (up to 3.75 mm off) leaves flank residuals of tens
of um. The sum then misses the peak, the fitted bump is wrong (338.6 +- 5.6 um for 300), its
touches look like gross errors to the suspect screen, the noise looks heavy-tailed, and the
verdict went to ``unexplained`` at a log Bayes factor of -800.

Here, where the evidence falls by more than ``SHARP_NATS`` within a quarter of the grid's
spacing from the best point (the peak far narrower than the cell), phi = (x, y, ln r) is refined
by Nelder-Mead on the one-column log evidence lz(phi) (the tau mixture, as the search's), and

    log Z = lz(phi*) + log p(phi*) + (3 / 2) log 2 pi - (1 / 2) log det H,

H the Hessian of -lz at phi* (central differences, steps a fifth of the posterior sds; the
peak must be Gaussian to 1 sd along each axis, within ``QUADRATIC_NATS``, else the grid's sum
stands: a bump's rim or the reach rule's edge near the peak breaks Laplace's method), p the
search's prior as a density: the centre uniform over the workplane, ln r uniform over cells of
the radius grid's log spacing about each radius, conditioned on the bump reaching two touches
(the share of the grid's prior that does). It replaces the grid's sum where it is larger and the
posterior is narrower than half a cell in x and y (a sharp peak the grid undercounts; a broad
or many-peaked posterior keeps the sum). The candidate is then held at phi*, its nonlinear sds
from H^-1. Its height, as ``averaging`` has it for the grid, is averaged over the profiles a
burr may have (``effects.DEFECT_PROFILES``, prior 1/3 each): each profile refined and
integrated the same way, its height's posterior N(m_p, var(h | phi_p) + g^T H_p^-1 g), g =
dh / dphi, weighted by its Laplace evidence; the reported height stays the bell's, its sd the
mixture's equivalent-normal sd about it (``intervals.two_sd_normal``). The log Bayes factor is
the bell's: the library's model.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from adaptive_cal.analysis.explain import intervals
from adaptive_cal.analysis.explain.evidence import log_evidence_columns_mixture, posterior
from adaptive_cal.effects import DEFECT_PROFILES, defect_regressor_grid

SHARP_NATS = 8.0  # the evidence falls by more than this a quarter-cell from the best point:
#                   the peak's sd is under 1/16 of the cell, and a peak between grid points is
#                   missed by 32 nats or more; the refined grid (``averaging``) serves below
QUADRATIC_NATS = 0.25  # lz at phi* +- 1 sd within this of the Gaussian's 1/2: Laplace holds
MIN_TOUCHES = 2  # the search's rule (``candidates.DEFECT_MIN_TOUCHES``)


def _values(phi) -> dict:
    return {"x_mm": float(phi[0]), "y_mm": float(phi[1]), "radius_mm": float(np.exp(phi[2]))}


def _hessian(f, phi, h) -> np.ndarray:
    """Central second differences of f at phi with steps h."""
    k = phi.size
    H = np.zeros((k, k))
    f0 = f(phi)
    for i in range(k):
        e = np.zeros(k)
        e[i] = h[i]
        H[i, i] = (f(phi + e) - 2 * f0 + f(phi - e)) / h[i] ** 2
        for j in range(i):
            d = np.zeros(k)
            d[j] = h[j]
            H[i, j] = H[j, i] = (f(phi + e + d) - f(phi + e - d) - f(phi - e + d)
                                 + f(phi - e - d)) / (4 * h[i] * h[j])
    return H


class _Bump:
    """The one-column evidence of a bump of one profile at phi = (x, y, ln r) (module docstring)."""

    def __init__(self, ctx, taus, reach, profile: str, lo: float, hi: float):
        self.ctx, self.taus, self.reach, self.profile, self.lo, self.hi = \
            ctx, taus, reach, profile, lo, hi
        self.root = float(np.sqrt(max(float(ctx.yt @ ctx.yt), 1e-300)))

    def column(self, phi) -> np.ndarray:
        v = _values(phi)
        return defect_regressor_grid(self.ctx.design.features, [v["x_mm"]], [v["y_mm"]],
                                     v["radius_mm"], self.profile)

    def lz(self, phi) -> float:
        if not self.lo <= phi[2] <= self.hi:
            return -np.inf
        x = self.column(phi)
        if self.reach(x)[0] < MIN_TOUCHES:
            return -np.inf
        x, yt, root = x[:, 0], self.ctx.yt, self.root
        b = float(x @ yt)
        s2 = float(x @ x) - float(np.sum((self.ctx.project.basis.T @ x) ** 2))
        stand = np.array([[b / root], [np.sqrt(max(s2 - (b / root) ** 2, 0.0))]])
        return float(log_evidence_columns_mixture(stand, np.array([root, 0.0]), self.taus,
                                                  self.ctx.m)[0][0])

    def peak(self, phi0, step: float, dlr: float):
        """(phi*, lz(phi*), H) by Nelder-Mead and central differences; None where H is not
        positive definite."""
        f = lambda p: -self.lz(p)  # noqa: E731
        simplex = phi0 + np.vstack([np.zeros(3), np.diag([step / 2, step / 2, dlr / 4])])
        res = minimize(f, phi0, method="Nelder-Mead", options={
            "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-3, "maxfev": 400})
        phi = res.x if res.fun <= f(phi0) else np.asarray(phi0, float)
        h = np.array([step / 40, step / 40, dlr / 40])
        for _ in range(2):  # steps a fifth of the posterior sd, once the sd is known
            H = _hessian(f, phi, h)
            if not np.all(np.isfinite(H)) or np.any(np.linalg.eigvalsh(H) <= 0):
                return None
            h = np.minimum(np.sqrt(np.diag(np.linalg.inv(H))) / 5, h * 4)
        top, sd = -f(phi), np.sqrt(np.diag(np.linalg.inv(H)))
        for e in np.diag(sd):  # the peak is Gaussian out to 1 sd (no rim, no reach's edge)
            if max(abs(top - self.lz(phi + s * e) - 0.5) for s in (-1, 1)) > QUADRATIC_NATS:
                return None
        return phi, top, H

    def height(self, phi, prior_var, noise_var, cov):
        """The height's posterior mean at phi and its variance with phi's part (delta method)."""
        def mean_at(p):
            Xt = self.ctx.project(self.column(p))
            return posterior(Xt, self.ctx.yt, prior_var, noise_var)

        (m,), c = mean_at(phi)
        sd = np.sqrt(np.diag(cov))
        g = np.array([(mean_at(phi + e)[0][0] - mean_at(phi - e)[0][0]) / (2 * e[i])
                      for i, e in enumerate(np.diag(sd / 5))])
        return float(m), float(c[0, 0] + g @ cov @ g)


def sharpened(ctx, cand, records: list[tuple], taus: np.ndarray, reach):
    """``cand`` (the bump search's candidate, held at its best grid point) refined where the
    grid cannot resolve its peak (module docstring); else ``cand`` itself. ``records``: the
    search's ``candidates.bump_record``s; ``reach(X)``: touches that carry the bump
    (``candidates.nameable_reach``)."""
    radii = np.array([r[0] for r in records], float)
    dlr = float(np.mean(np.diff(np.log(radii)))) if radii.size > 1 else np.log(2.0)
    lo, hi = np.log(radii.min()) - dlr / 2, np.log(radii.max()) + dlr / 2
    bell = _Bump(ctx, taus, reach, DEFECT_PROFILES[0], lo, hi)
    phi0 = np.array([cand.fixed["x_mm"], cand.fixed["y_mm"], np.log(cand.fixed["radius_mm"])])
    step = cand.fixed["radius_mm"] / 4.0  # the centre grid's spacing at the best radius
    z0 = bell.lz(phi0)
    near = [bell.lz(phi0 + d) for d in step / 4.0 * np.array([[1, 0, 0], [-1, 0, 0],
                                                             [0, 1, 0], [0, -1, 0]])]
    if not np.isfinite(z0) or z0 - min(near) <= SHARP_NATS:
        return cand
    peak = bell.peak(phi0, step, dlr)
    if peak is None:
        return cand
    phi, lz, H = peak
    cov = np.linalg.inv(H)
    sd = np.sqrt(np.diag(cov))
    if sd[0] > step / 2 or sd[1] > step / 2:
        return cand  # wider than the grid's cell: the sum stands
    (x0, x1), (y0, y1) = ctx.design.geometry.x_range_mm, ctx.design.geometry.y_range_mm
    reachable = float(np.exp(logsumexp(np.concatenate([r[5] for r in records]))))
    log_density = -np.log((x1 - x0) * (y1 - y0) * radii.size * dlr * reachable)
    occam = 1.5 * np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(H)[1]
    if lz + log_density + occam - ctx.log_z0 <= cand.log_bf:
        return cand
    fixed = _values(phi)
    out = replace(cand, log_bf=float(lz + log_density + occam - ctx.log_z0),
                  columns=bell.column(phi), fixed=fixed, nonlinear_mean=dict(fixed),
                  support=None, look_elsewhere=float(-log_density - occam),
                  nonlinear_std={"x_mm": float(sd[0]), "y_mm": float(sd[1]),
                                 "radius_mm": float(fixed["radius_mm"] * sd[2])}).fit_posterior(ctx)
    logz, means, var = [], [], []
    for profile in DEFECT_PROFILES:  # the height averaged over the profiles a burr may have
        bump = bell if profile == bell.profile else _Bump(ctx, taus, reach, profile, lo, hi)
        got = (phi, lz, H) if bump is bell else bump.peak(phi, step, dlr)
        if got is None:
            continue
        p_phi, p_lz, p_H = got
        m, v = bump.height(p_phi, out.prior_var, out.noise_var, np.linalg.inv(p_H))
        logz.append(p_lz - 0.5 * np.linalg.slogdet(p_H)[1]), means.append(m), var.append(v)
    (name,) = out.names
    sds, ivs = intervals.linear_summary(np.array(logz), np.array(means), np.array(var),
                                        float(out.mean[0]), name)
    return replace(out, param_std=sds, interval_95=ivs)
