"""Candidate effects from the effect library, each scored by its evidence against ``none``.

Priors. The linear parameters of an effect are independent zero-mean Gaussians with a common
standard deviation tau, and tau itself is log-uniform over a physical range (a scale mixture, a
proper prior): a plate bowed 0.3 mm and a drift of 1 um per touch are both inside the prior, and
the Occam factor stays about log(range) instead of growing with a prior that is too wide.

The ranges and the search grids are the effects' own (``adaptive_cal.effects``; the table in
docs/explain.md is ``effects.markdown_table()``). How an effect is scored follows from its shape:

- only linear parameters (form, reversal, probe_gain, a linear thermal_drift): the scale mixture,
  shared and per round; an effect made of several kinds of shape (form: bow, twist, warp) with
  each kind present or not, the non-empty sets equally likely (``log_evidence_presence``);
- one linear parameter whose column needs a nonlinear one (arm_sag's p, the warm-up's tau_s):
  the mixture for each value of the effect's search grid, averaged over the grid (uniform);
- a centre and a radius (local_defect): radius uniform on its grid, centre uniform over a grid
  of spacing radius / 2, conditioned on the bump reaching at least two touches with at least a
  quarter of its height each, none of them carrying more than 3/4 of the bump's information
  (one touch, or a second touch at the bump's edge: an outlier);
- both a plain linear part and a searched one (thermal_drift: rate, or a warm-up amplitude with
  its tau_s): the plain form, replaced by the searched form when that one's evidence is larger
  by more than ``EXTENSION_NATS`` (a warm-up must earn its place against the straight line the
  way an effect earns its place against ``none``).

Nonlinear parameters are averaged over their prior (a discrete prior): that average is the
look-elsewhere penalty -- about log(number of effectively independent locations) below the best
single location, which is reported. For a defect the prior is uniform over the plate area,
conditioned on the bump reaching at least two touches: a bump seen by one touch cannot be told
from an outlier (the gate and the retake handle those), so it is not a hypothesis explain can
name, and it must not dilute the ones it can. With several rounds a linear effect
is either shared (one parameter set) or per round; both are scored and averaged with prior 1/2.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import logsumexp

from adaptive_cal import effects
from adaptive_cal.effects import Effect
from adaptive_cal.analysis.explain.design import Design
from adaptive_cal.analysis.explain.sharpen import sharpened
from adaptive_cal.analysis.explain.evidence import (Projector, log_evidence, log_evidence_columns_mixture,
                       log_evidence_mixture, log_evidence_presence, posterior)

TAU_PER_DECADE = 4
DEFECT_MIN_TOUCHES = 2  # a bump that reaches one touch is an outlier, not a nameable defect
DEFECT_MIN_WEIGHT = 0.25  # ... each carrying this share of the bump's height, and
DEFECT_MAX_SHARE = 0.75  # no touch carrying more of its information (sum of squared weights)
EXTENSION_NATS = 1.0  # the searched form of an effect replaces its plain form above this log BF
CANDIDATES = tuple(e.name for e in effects.LIBRARY if e.candidate)


def prior_grid(effect: Effect, names: tuple[str, ...] | None = None) -> np.ndarray:
    """The log-uniform grid of the prior standard deviation tau of an effect's parameters."""
    lo, hi = effect.prior_range(names)
    return np.geomspace(lo, hi, int(round(TAU_PER_DECADE * np.log10(hi / lo))) + 1)


def prior_scale(effect: Effect, names: tuple[str, ...] | None = None) -> float:
    """A representative prior size (geometric middle of the range), for detectability notes."""
    lo, hi = effect.prior_range(names)
    return float(np.sqrt(lo * hi))


GPRIOR_RIDGE = 0.01  # caps the design-scaled prior sd of a nearly absorbed direction at 10 tau


def prior_shape(Xt: np.ndarray, ridge: float = GPRIOR_RIDGE) -> np.ndarray | None:
    """Design-scaled prior shape S0 of a multi-parameter effect (theta ~ N(0, tau^2 S0)).

    Measured and not adopted (docs/explain.md); kept for the evidence's matrix-prior oracle test.
    S0 = lbar (Z^T Z + ridge lbar I)^-1 with Z the columns after the tilt is projected out and
    lbar = trace(Z^T Z) / k: Zellner's g-prior, scaled so the expected signal energy
    E|Z theta|^2 = tau^2 trace(Z^T Z) equals that of the i.i.d. prior theta ~ N(0, tau^2 I),
    but spread evenly over the directions the design can see. One-column effects: None.
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

    def log_marginal(self, cands: list["Candidate"]) -> dict[str, float]:
        """log p(y | M) of none and of each candidate (by effect name), with the flat nuisance's
        factor |N^T N|^(-1/2) (``evidence``): Bayes factors drop it, a comparison of the same
        models with and without a reading (``suspects.integrated_log_odds``) needs it."""
        base = self.log_z0 - 0.5 * float(np.linalg.slogdet(self.nuisance.T @ self.nuisance)[1])
        return {"none": base, **{c.effect: base + c.log_bf for c in cands}}


@dataclass(frozen=True)
class Candidate:
    """One effect's score and posterior (at the best nonlinear parameters)."""

    effect: str
    log_bf: float
    columns: np.ndarray  # n x k regressor actually fitted (shared or per round)
    prior_var: np.ndarray
    names: tuple[str, ...] = ()  # the linear parameters of the columns (one block per round)
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
    # the searched grid's posterior (values per nonlinear parameter, log weights, prior sd per
    # point; ``intervals``), and what it gives: sd and 95 % interval per parameter name
    support: dict | None = None
    param_std: dict = field(default_factory=dict)
    interval_95: dict = field(default_factory=dict)

    def fit_posterior(self, ctx: Context) -> "Candidate":
        """The same candidate with its posterior given the noise at its mode."""
        Xt = ctx.project(self.columns)
        _, w = log_evidence(Xt, ctx.yt, self.prior_var, ctx.m)
        noise_var = float(np.exp(w))
        mean, cov = posterior(Xt, ctx.yt, self.prior_var, noise_var)
        return replace(self, noise_var=noise_var, mean=mean, cov=cov)


def _plain(ctx: Context, effect: Effect, names: tuple[str, ...]) -> Candidate:
    """Linear parameters only: shared or, with rounds, per round (averaged, prior 1/2 each)."""
    d = ctx.design
    X = effect.regressor(d.features, d.geometry, names=names)
    taus = prior_grid(effect, names)

    def score(cols):
        Xt = ctx.project(cols)
        lz, best, _ = log_evidence_mixture(Xt, ctx.yt, taus, ctx.m)
        if len(names) > 1:  # kinds of shape (form: bow, twist, warp), each present or not
            kinds = np.arange(cols.shape[1]) % len(names)  # per-round copies share a kind
            lz = log_evidence_presence(Xt, ctx.yt, taus, ctx.m, kinds)
        return lz, taus[best] ** 2 * np.ones(cols.shape[1])

    lz_s, var_s = score(X)
    if d.rounds == 1:
        return Candidate(effect.name, lz_s - ctx.log_z0, X, var_s, names).fit_posterior(ctx)
    Xp = d.per_round(X)
    lz_p, var_p = score(Xp)
    lz = float(logsumexp([lz_s, lz_p]) - np.log(2.0))
    shared = lz_s >= lz_p
    cand = Candidate(effect.name, lz - ctx.log_z0, X if shared else Xp, var_s if shared else var_p,
                     names, "shared" if shared else "per_round", float(lz_s - lz_p))
    return cand.fit_posterior(ctx)


def _searched(ctx: Context, effect: Effect, names: tuple[str, ...]) -> Candidate:
    """One linear parameter whose column needs a nonlinear one: averaged over the search grid."""
    d = ctx.design
    (key, values), = effect.grid(d.features, d.geometry).items()
    values = np.asarray(values, float)
    X = np.stack([effect.regressor(d.features, d.geometry, {key: float(v)}, names)[:, 0]
                  for v in values], axis=1)
    taus = prior_grid(effect, names)
    lz, best_tau = log_evidence_columns_mixture(ctx.project(X), ctx.yt, taus, ctx.m)
    total = float(logsumexp(lz) - np.log(len(lz)))
    wts = np.exp(lz - logsumexp(lz))
    mean_v = float(wts @ values)
    best = int(np.argmax(lz))
    cand = Candidate(effect.name, total - ctx.log_z0, X[:, [best]],
                     np.array([taus[best_tau[best]] ** 2]), names,
                     fixed={key: float(values[best])}, nonlinear_mean={key: mean_v},
                     nonlinear_std={key: float(np.sqrt(wts @ (values - mean_v) ** 2))},
                     look_elsewhere=float(lz.max() - total), searched=len(lz),
                     support={"values": {key: values}, "log_w": lz - logsumexp(lz),
                              "tau": taus[best_tau], "columns": X})
    return cand.fit_posterior(ctx)


def nameable_reach(X) -> np.ndarray:
    """Touches that carry a bump (column of X: the bell's weight at each touch), or 0 where one
    touch carries more than DEFECT_MAX_SHARE of the bump's information: a hypothesis that rests
    on one reading is an outlier, not a defect (a spike, with a second touch at the bump's edge).
    X dense or scipy-sparse (the same numbers)."""
    from scipy import sparse

    if sparse.issparse(X):  # sums over the stored entries of each column
        X = X.tocoo()
        L, c, w2 = X.shape[1], X.col, X.data * X.data
        total, peak = np.bincount(c, w2, minlength=L), np.zeros(L)
        np.maximum.at(peak, c, w2)
        big = np.bincount(c, X.data >= DEFECT_MIN_WEIGHT, minlength=L).astype(int)
    else:
        w2 = X * X
        total, peak = w2.sum(axis=0), w2.max(axis=0, initial=0.0)
        big = np.count_nonzero(X >= DEFECT_MIN_WEIGHT, axis=0)
    lone = peak > DEFECT_MAX_SHARE * np.maximum(total, 1e-300)
    return np.where(lone, 0, big)


def bump_record(radius: float, gx, gy, lz, bt, counts, named, n_radii: int) -> tuple:
    """One radius of the bump search with its prior: uniform over the grid of centres and the
    radii, conditioned on the bump reaching at least DEFECT_MIN_TOUCHES touches (``counts``); a
    centre not ``named`` (one touch carries it) keeps the likelihood of none and is never named.
    (radius, gx, gy, log evidence, best tau index, log prior, named)."""
    logp = np.where(counts >= DEFECT_MIN_TOUCHES, -np.log(gx.size) - np.log(n_radii), -np.inf)
    return radius, gx, gy, lz, bt, logp, named


def bump_candidate(ctx: Context, effect: Effect, records: list[tuple], classes: int,
                   taus: np.ndarray) -> Candidate | None:
    """The bump candidate from the search's ``bump_record``s: its evidence averaged over the
    nameable (radius, centre) prior, held at the most probable one, with the grid posterior as
    ``support`` (for ``averaging``)."""
    d = ctx.design
    names = effect.searched
    prior_mass = float(logsumexp(np.concatenate([r[5] for r in records])))
    if not np.isfinite(prior_mass) or not classes:
        return None  # no bump of the searched radii is nameable on this design
    total = float(logsumexp(np.concatenate([r[3] + r[5] for r in records])) - prior_mass)
    logw = np.concatenate([np.where(r[6], r[3] + r[5], -np.inf) for r in records])
    # posterior over (radius, centre): the same prior, restricted to the nameable centres
    wts = np.exp(logw - logsumexp(logw))
    allx = np.concatenate([r[1] for r in records])
    ally = np.concatenate([r[2] for r in records])
    allr = np.concatenate([np.full(r[1].size, r[0]) for r in records])
    best = int(np.argmax(logw))
    mean = {k: float(wts @ v) for k, v in (("x_mm", allx), ("y_mm", ally), ("radius_mm", allr))}
    std = {k: float(np.sqrt(wts @ (v - mean[k]) ** 2))
           for k, v in (("x_mm", allx), ("y_mm", ally), ("radius_mm", allr))}
    fixed = {"x_mm": float(allx[best]), "y_mm": float(ally[best]), "radius_mm": float(allr[best])}
    X = effect.regressor(d.features, d.geometry, fixed, names)
    lz_best = max(float(r[3].max()) for r in records)
    all_tau = np.concatenate([taus[r[4]] for r in records])
    cand = Candidate(effect.name, total - ctx.log_z0, X, np.array([all_tau[best] ** 2]), names,
                     fixed=fixed, nonlinear_mean=mean, nonlinear_std=std,
                     look_elsewhere=lz_best - total, searched=int(classes),
                     support={"values": {"x_mm": allx, "y_mm": ally, "radius_mm": allr},
                              "log_w": logw, "tau": all_tau}).fit_posterior(ctx)
    return sharpened(ctx, cand, records, taus, nameable_reach)  # a peak the grid cannot resolve


def _centres(ctx: Context, effect: Effect, bells=None) -> Candidate | None:
    """A bump: radius on the effect's grid, centre uniform over ``effects.defect_centres``.
    ``bells``: radius -> ``defect_regressor_sparse`` of the design, if already at hand."""
    from adaptive_cal.effects.plate import defect_regressor_sparse

    d = ctx.design
    names = effect.searched
    taus = prior_grid(effect, names)
    records, classes = [], 0
    n_radii = len(effect.grid(d.features, d.geometry)["radius_mm"])
    Q, root = ctx.project.basis, float(np.sqrt(max(float(ctx.yt @ ctx.yt), 1e-300)))
    for radius in effect.grid(d.features, d.geometry)["radius_mm"]:
        radius = float(radius)
        gx, gy = effects.defect_centres(d.geometry, radius)
        S = (bells(radius) if bells else  # touches x centres, the bells
             defect_regressor_sparse(d.features, d.geometry, radius))
        seen = np.flatnonzero(nameable_reach(S) >= DEFECT_MIN_TOUCHES)
        lz, bt = np.full(gx.size, ctx.log_z0), np.zeros(gx.size, int)
        col = lambda w: np.bincount(S.col, w, minlength=gx.size)  # a sum over each bell
        counts, named = col(None), np.isin(np.arange(gx.size), seen)
        if seen.size:
            # |M x|^2 = |x|^2 - |Q^T x|^2 and (M x)^T yt = x^T yt (yt = M y) for every column x
            # at once (one pass over the bells: S^T [yt Q]); the columns enter the evidence only
            # through these and |yt|^2, so a two-row stand-in with the same three numbers gives
            # the same evidence
            P = (S.tocsr().T @ np.column_stack([ctx.yt, Q]))[seen]
            b = P[:, 0]
            s2 = col(S.data * S.data)[seen] - (P[:, 1:] ** 2).sum(axis=1)
            stand_in = np.stack([b / root, np.sqrt(np.maximum(s2 - (b / root) ** 2, 0.0))])
            lz[seen], bt[seen] = log_evidence_columns_mixture(  # in chunks that stay in cache
                stand_in, np.array([root, 0.0]), taus, ctx.m)
        # the prior: uniform over the grid of centres, conditioned on the bump reaching at least
        # DEFECT_MIN_TOUCHES touches (a bump no two touches see is not a hypothesis about these
        # data). Where one touch would carry it (``nameable_reach``) it cannot be told from an
        # outlier: such a bump explains nothing (the likelihood of none) and is never named.
        records.append(bump_record(radius, gx, gy, lz, bt, counts, named, n_radii))
        classes += int(np.count_nonzero(named))
    return bump_candidate(ctx, effect, records, classes, taus)


def score_effect(ctx: Context, effect: Effect, bells=None) -> Candidate | None:
    """The candidate of one effect, scored the way its shape asks (module docstring)."""
    if {"x_mm", "y_mm"} <= set(effect.nonlinear):
        return _centres(ctx, effect, bells)
    plain = _plain(ctx, effect, effect.plain) if effect.plain else None
    if not effect.searched:
        return plain
    searched = _searched(ctx, effect, effect.searched)
    if plain is None or searched.log_bf - plain.log_bf > EXTENSION_NATS:
        return searched
    return plain


def score_candidates(ctx: Context, skip: frozenset[str] = frozenset(),
                     bells=None) -> list[Candidate]:
    """Every testable candidate, best evidence first (``bells``: ``_centres``)."""
    out = []
    for name in CANDIDATES:
        if name in skip or name in ctx.design.unknown:
            continue
        cand = score_effect(ctx, effects.get(name), bells)
        if cand is not None:
            out.append(cand)
    return sorted(out, key=lambda c: -c.log_bf)
