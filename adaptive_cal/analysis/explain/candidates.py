"""Candidate effects from the effect library, each scored by its evidence against ``none``.

Priors. The linear parameters of an effect are independent zero-mean Gaussians with a common
standard deviation tau, and tau itself is log-uniform over a physical range (a scale mixture, a
proper prior): a plate bowed 0.3 mm and a drift of 1 um per touch are both inside the prior, and
the Occam factor stays about log(range) instead of growing with a prior that is too wide.

=============  =====================================  =======================================
effect         linear parameters: tau range           nonlinear parameters, prior
=============  =====================================  =======================================
form           bow_x, bow_y, twist, warp: 1 um..1 mm   --
thermal_drift  rate_mm_per_s: 1e-6..1e-3               --
reversal       span_mm: 1e-4..0.1                      --
arm_sag        sag_mm_at_1m: 1e-3..1                   p uniform on {1, 1.5, 2, 2.5, 3}
probe_gain     gain: 1e-5..1e-2                        --
local_defect   height_mm: 1e-3..1                      radius uniform on {15, 30, 60} mm, centre
                                                       uniform over a grid (spacing radius / 2);
                                                       conditioned on the bump reaching at least
                                                       two touches (one touch: an outlier)
=============  =====================================  =======================================

Nonlinear parameters are averaged over their prior (a discrete prior): that average is the
look-elsewhere penalty -- about log(number of effectively independent locations) below the best
single location, which is reported. For a defect the prior is uniform over the plate area,
conditioned on the bump reaching at least two touches: a bump seen by one touch cannot be told
from an outlier (the gate and the retake handle those), so it is not a hypothesis explain can
name, and it must not dilute the ones it can. With several rounds a linear effect
is either shared (one parameter set) or per round; both are scored and averaged with prior 1/2.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp

from adaptive_cal.effects import library as physics
from adaptive_cal.analysis.explain.design import Design
from adaptive_cal.analysis.explain.evidence import (Projector, log_evidence, log_evidence_columns_mixture,
                       log_evidence_mixture, posterior)

PRIOR_RANGE = {"form": (1e-3, 1.0), "thermal_drift": (1e-6, 1e-3), "reversal": (1e-4, 0.1),
               "arm_sag": (1e-3, 1.0), "probe_gain": (1e-5, 1e-2), "local_defect": (1e-3, 1.0)}
TAU_PER_DECADE = 4
PRIOR_SHAPE = "iid"  # multi-parameter effects: "iid" or "design" (prior_shape; measured, docs)
DEFECT_PRIOR = "area"  # defect centres: "area" (uniform over the grid) or "footprint" (measured, docs)
SAG_EXPONENTS = (1.0, 1.5, 2.0, 2.5, 3.0)
DEFECT_RADII_MM = (15.0, 30.0, 60.0)
DEFECT_MIN_TOUCHES = 2  # a bump that reaches one touch is an outlier, not a nameable defect


def prior_grid(name: str) -> np.ndarray:
    """The log-uniform grid of the prior standard deviation tau of an effect's parameters."""
    lo, hi = PRIOR_RANGE[name]
    return np.geomspace(lo, hi, int(round(TAU_PER_DECADE * np.log10(hi / lo))) + 1)


GPRIOR_RIDGE = 0.01  # caps the design-scaled prior sd of a nearly absorbed direction at 10 tau


def prior_shape(Xt: np.ndarray, ridge: float = GPRIOR_RIDGE) -> np.ndarray | None:
    """Design-scaled prior shape S0 of a multi-parameter effect (theta ~ N(0, tau^2 S0)).

    S0 = lbar (Z^T Z + ridge lbar I)^-1 with Z the columns after the tilt is projected out and
    lbar = trace(Z^T Z) / k: Zellner's g-prior, scaled so the expected signal energy
    E|Z theta|^2 = tau^2 trace(Z^T Z) equals that of the i.i.d. prior theta ~ N(0, tau^2 I)
    (tau keeps its physical meaning), but spread evenly over the directions the design can
    see. With the i.i.d. prior a signal along a weakly measured direction needs a large tau,
    and every well-measured direction then pays an Occam factor for it (about 7 nats for the
    four form shapes on a 10 x 4 grid, whose Z^T Z eigenvalues span a factor 24). The ridge
    keeps the prior proper and physical when a shape is nearly absorbed by the tilt. One-column
    effects keep S0 = 1 (None).
    """
    k = Xt.shape[1]
    if k <= 1:
        return None
    G = Xt.T @ Xt
    lbar = float(np.trace(G)) / k
    if lbar <= 0.0:
        return None
    A = 0.5 * (G + G.T) / lbar + ridge * np.eye(k)
    L = np.linalg.cholesky(A)
    Li = np.linalg.solve(L, np.eye(k))
    return Li.T @ Li


def prior_scale(name: str) -> float:
    """A representative prior size (geometric middle of the range), for detectability notes."""
    lo, hi = PRIOR_RANGE[name]
    return float(np.sqrt(lo * hi))
CANDIDATES = ("form", "thermal_drift", "reversal", "arm_sag", "probe_gain", "local_defect")


@dataclass(frozen=True)
class Context:
    """The calibrated null model: projector of the nuisance, projected target, its evidence."""

    design: Design
    nuisance: np.ndarray
    project: Projector
    yt: np.ndarray
    m: int
    log_z0: float
    w0: float

    @classmethod
    def of(cls, design: Design) -> "Context":
        N, _ = design.nuisance()
        proj = Projector.of(N)
        y = design.target
        yt = proj(y)
        m = design.n - proj.rank
        lz0, w0 = log_evidence(np.zeros((design.n, 0)), yt, np.zeros(0), m)
        return cls(design, N, proj, yt, m, lz0, w0)

    @property
    def null_residual(self) -> np.ndarray:
        return self.yt


@dataclass
class Candidate:
    """One effect's score and posterior (at the best nonlinear parameters)."""

    effect: str
    log_bf: float
    columns: np.ndarray  # n x k regressor actually fitted (shared or per round)
    prior_var: np.ndarray
    sharing: str = "shared"
    log_bf_shared_vs_per_round: float | None = None
    fixed: dict = field(default_factory=dict)  # nonlinear parameters at their best value
    nonlinear_mean: dict = field(default_factory=dict)
    nonlinear_std: dict = field(default_factory=dict)
    look_elsewhere: float = 0.0
    searched: int = 1
    mean: np.ndarray | None = None
    cov: np.ndarray | None = None
    noise_var: float = float("nan")

    def fit_posterior(self, ctx: Context) -> "Candidate":
        Xt = ctx.project(self.columns)
        _, w = log_evidence(Xt, ctx.yt, self.prior_var, ctx.m)
        self.noise_var = float(np.exp(w))
        self.mean, self.cov = posterior(Xt, ctx.yt, self.prior_var, self.noise_var)
        return self


def _linear(ctx: Context, name: str) -> Candidate:
    d = ctx.design
    X = physics.effect_regressor(name, d.features, d.geometry)
    taus = prior_grid(name)

    def score(cols):
        Xt = ctx.project(cols)
        S0 = prior_shape(Xt) if PRIOR_SHAPE == "design" else None
        lz, best, _ = log_evidence_mixture(Xt, ctx.yt, taus, ctx.m, S0)
        var = taus[best] ** 2 * (np.ones(cols.shape[1]) if S0 is None else S0)
        return lz, var

    lz_s, var_s = score(X)
    if d.rounds == 1:
        return Candidate(name, lz_s - ctx.log_z0, X, var_s).fit_posterior(ctx)
    Xp = d.per_round(X)
    lz_p, var_p = score(Xp)
    lz = float(logsumexp([lz_s, lz_p]) - np.log(2.0))
    shared = lz_s >= lz_p
    cand = Candidate(name, lz - ctx.log_z0, X if shared else Xp, var_s if shared else var_p,
                     "shared" if shared else "per_round", float(lz_s - lz_p))
    return cand.fit_posterior(ctx)


def _arm_sag(ctx: Context) -> Candidate:
    d = ctx.design
    X = np.stack([physics.effect_regressor("arm_sag", d.features, d.geometry, {"p": p})[:, 0]
                  for p in SAG_EXPONENTS], axis=1)
    taus = prior_grid("arm_sag")
    lz, best_tau = log_evidence_columns_mixture(ctx.project(X), ctx.yt, taus, ctx.m)
    total = float(logsumexp(lz) - np.log(len(lz)))
    wts = np.exp(lz - logsumexp(lz))
    ps = np.asarray(SAG_EXPONENTS)
    mean_p = float(wts @ ps)
    best = int(np.argmax(lz))
    cand = Candidate("arm_sag", total - ctx.log_z0, X[:, [best]],
                     np.array([taus[best_tau[best]] ** 2]),
                     fixed={"p": float(ps[best])}, nonlinear_mean={"p": mean_p},
                     nonlinear_std={"p": float(np.sqrt(wts @ (ps - mean_p) ** 2))},
                     look_elsewhere=float(lz.max() - total), searched=len(lz))
    return cand.fit_posterior(ctx)


def defect_grid(geometry: physics.Geometry, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres searched for a defect of this radius: spacing radius / 2 over the workplane."""
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    step = radius_mm / 2.0
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / step)) + 1))
    ys = np.linspace(y0, y1, max(2, int(np.ceil((y1 - y0) / step)) + 1))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return gx.ravel(), gy.ravel()


def _local_defect(ctx: Context) -> Candidate:
    d = ctx.design
    taus = prior_grid("local_defect")
    records, classes = [], 0
    chunk = max(1, int(min(2_000_000 // max(d.n, 1), 400_000 // taus.size)))
    for radius in DEFECT_RADII_MM:
        gx, gy = defect_grid(d.geometry, radius)
        lz = np.empty(gx.size)
        bt = np.empty(gx.size, int)
        bits, counts = [], []
        for s in range(0, gx.size, chunk):
            X = physics.defect_regressor_grid(d.features, gx[s:s + chunk], gy[s:s + chunk], radius)
            bits.append(np.packbits(X != 0.0, axis=0))
            reach = np.count_nonzero(X, axis=0)
            seen = np.flatnonzero(reach >= DEFECT_MIN_TOUCHES)
            lz[s:s + chunk], bt[s:s + chunk] = ctx.log_z0, 0
            counts.append(reach)
            if seen.size:
                lz[s + seen], bt[s + seen] = log_evidence_columns_mixture(
                    ctx.project(X[:, seen]), ctx.yt, taus, ctx.m)
        # a bump that reaches fewer than DEFECT_MIN_TOUCHES touches is an outlier, not a nameable
        # defect: the prior is conditioned on the defect being nameable by this design
        ok = np.concatenate(counts) >= DEFECT_MIN_TOUCHES
        if DEFECT_PRIOR == "footprint":
            # uniform over footprints (the distinct touch neighbourhoods), then over the centres
            # of a footprint: log prior weight of a centre = -log(classes) - log(class size)
            _, cls = np.unique(np.hstack(bits).T, axis=0, return_inverse=True)
            cls = np.asarray(cls).ravel()
            size = np.bincount(cls)
            logp = -np.log(size.size) - np.log(size[cls])
            classes += size.size
        else:  # uniform over the grid of centres (area)
            logp = np.full(gx.size, -np.log(gx.size))
            classes += int(ok.sum())
        logp = np.where(ok, logp - np.log(len(DEFECT_RADII_MM)), -np.inf)
        records.append((radius, gx, gy, lz, bt, logp))
    prior_mass = float(logsumexp(np.concatenate([logp for *_, logp in records])))
    if not np.isfinite(prior_mass):
        return None  # no bump of the searched radii reaches two touches of this design
    total = float(logsumexp(np.concatenate([lz + logp for _, _, _, lz, _, logp in records]))
                  - prior_mass)
    # posterior over (radius, centre): the same prior, restricted to the nameable centres
    logw = np.concatenate([lz + logp for _, _, _, lz, _, logp in records])
    wts = np.exp(logw - logsumexp(logw))
    allx = np.concatenate([gx for _, gx, _, _, _, _ in records])
    ally = np.concatenate([gy for _, _, gy, _, _, _ in records])
    allr = np.concatenate([np.full(gx.size, r) for r, gx, _, _, _, _ in records])
    best = int(np.argmax(logw))
    mean = {k: float(wts @ v) for k, v in (("x_mm", allx), ("y_mm", ally), ("radius_mm", allr))}
    std = {k: float(np.sqrt(wts @ (v - mean[k]) ** 2))
           for k, v in (("x_mm", allx), ("y_mm", ally), ("radius_mm", allr))}
    fixed = {"x_mm": float(allx[best]), "y_mm": float(ally[best]), "radius_mm": float(allr[best])}
    X = physics.effect_regressor("local_defect", d.features, d.geometry, fixed)
    lz_best = max(float(lz.max()) for _, _, _, lz, _, _ in records)
    all_tau = np.concatenate([taus[bt] for _, _, _, _, bt, _ in records])
    cand = Candidate("local_defect", total - ctx.log_z0, X, np.array([all_tau[best] ** 2]), fixed=fixed,
                     nonlinear_mean=mean, nonlinear_std=std, look_elsewhere=lz_best - total,
                     searched=int(classes))
    return cand.fit_posterior(ctx)


def score_candidates(ctx: Context, skip: frozenset[str] = frozenset()) -> list[Candidate]:
    """Every testable candidate, best evidence first."""
    out = []
    for name in CANDIDATES:
        if name in skip or name in ctx.design.unknown:
            continue
        if name == "arm_sag":
            out.append(_arm_sag(ctx))
        elif name == "local_defect":
            cand = _local_defect(ctx)
            if cand is not None:
                out.append(cand)
        else:
            out.append(_linear(ctx, name))
    return sorted(out, key=lambda c: -c.log_bf)
