"""Linear-Gaussian evidence with nuisance parameters integrated out.

Model: y = N beta + X theta + e, e ~ N(0, v I), beta (tilt per round, offsets, calibrated unknowns)
with a flat prior, theta ~ N(0, diag(tau^2)) (the effect's parameters, proper prior), and the
noise variance v with the scale-invariant prior p(sigma) ~ 1/sigma.

Integrating the flat beta leaves the density of z = Q^T y, Q an orthonormal basis of the
complement of span(N) (dimension m = n - rank N), up to the factor |N^T N|^(-1/2) that every model
shares (so it cancels in Bayes factors):

    z ~ N(0, v I_m + Z S Z^T),   Z = Q^T X,  S = diag(tau^2).

With A = S^(1/2) Z^T Z S^(1/2) = U diag(lam) U^T and c_j = u_j^T S^(1/2) Z^T z / sqrt(lam_j):

    log p(z | v) = -m/2 log(2 pi) - (m-k)/2 log v - 1/2 sum log(v + lam_j)
                   - 1/2 [(z^T z - sum c_j^2) / v + sum c_j^2 / (v + lam_j)].

Only k x k quantities are needed (Z^T Z = X^T M X, Z^T z = X^T M y, M the residual projector),
so thousands of rows cost one projection. v is integrated numerically: a coarse grid in
w = log v (``coarse_grid``), Newton steps to the mode, then the trapezoid rule on a fixed grid of
posterior sds of w about the mode, +-9 sds wide (``quadrature``): 73 points where m - k < 20
(the integrand is lopsided there), 49 below 100, 25 from 100 on; from 1,000 on, Gauss-Hermite's
9 points where the effect explains little (``near_gaussian``). Against scipy's adaptive
quadrature, over random spectra with k = 1-8 (tests/test_explain_quadrature.py), each rule is
within the reference's own precision from m - k = 20 (a few 1e-9 nats at 20-60, 1e-11 from
100, 1e-10 for Gauss-Hermite); below that the cut at +-9 sds dominates every rule (up to 5e-5
nats at m - k = 10, 6e-4 at m = 2), the 73-point rule the code has always used there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy.special import logsumexp

from adaptive_cal.analysis.explain.evidence1 import log_evidence_spectral1
from adaptive_cal.analysis.explain.quadrature import (LOG2PI, NEWTON_TOL, _log_integral,
                                                      coarse_grid, rules)
# re-exported for tests/test_explain_quadrature.py, which checks the rules through this module
from adaptive_cal.analysis.explain.quadrature import (  # noqa: F401
    GAUSS_HERMITE, near_gaussian, quadrature)


@dataclass(frozen=True)
class Projector:
    """The residual projector M = I - Qn Qn^T of the nuisance columns N."""

    basis: np.ndarray  # n x rank(N), orthonormal

    @classmethod
    def of(cls, nuisance: np.ndarray, rtol: float = 1e-10) -> "Projector":
        q, r, _ = linalg.qr(nuisance, mode="economic", pivoting=True)  # rank-revealing: its
        d = np.abs(np.diag(r))  # leading columns span N where N is rank-deficient too
        return cls(q[:, :int(np.count_nonzero(d > rtol * max(d.max(initial=0.0), 1e-300)))])

    @property
    def rank(self) -> int:
        return int(self.basis.shape[1])

    def __call__(self, a: np.ndarray) -> np.ndarray:
        """M a for a vector or a matrix of columns."""
        return a - self.basis @ (self.basis.T @ a)


def _spectral(lam: np.ndarray, c2: np.ndarray, yy, m, w: np.ndarray) -> np.ndarray:
    """log p(z | v = e^w), broadcasting: lam, c2 (..., k); w (..., G) -> (..., G)."""
    v = np.exp(w)[..., None, :]  # (..., 1, G)
    lam = lam[..., :, None]
    c2 = c2[..., :, None]
    k = lam.shape[-2]
    yy = np.asarray(yy, float)[..., None]
    rest = np.maximum(yy - c2.sum(-2), 1e-12 * yy)  # >= 0 up to round-off
    return (-0.5 * m * LOG2PI - 0.5 * (m - k) * w - 0.5 * np.log(v + lam).sum(-2)
            - 0.5 * (rest / v[..., 0, :] + (c2 / (v + lam)).sum(-2)))


def _derivs(lam, c2, yy, m, w):
    """First and second derivative of _spectral in w (shapes as _spectral, G = 1)."""
    v = np.exp(w)[..., None]
    k = lam.shape[-1]
    rest = np.maximum(np.asarray(yy, float) - c2.sum(-1), 1e-12 * yy)
    d1 = (-0.5 * (m - k) - 0.5 * (v / (v + lam)).sum(-1) + 0.5 * rest / v[..., 0]
          + 0.5 * (c2 * v / (v + lam) ** 2).sum(-1))
    d2 = (-0.5 * (v * lam / (v + lam) ** 2).sum(-1) - 0.5 * rest / v[..., 0]
          + 0.5 * (c2 * v * (lam - v) / (v + lam) ** 3).sum(-1))
    return d1, d2


def log_evidence_spectral(lam, c2, yy, m) -> tuple[np.ndarray, np.ndarray]:
    """log of integral p(z | v) p(sigma) dsigma with p(sigma) = 1/sigma; and the mode of log v.

    lam, c2: (..., k) arrays (k may be 0: the model with no effect). Returns (log Z, w_mode).
    """
    lam = np.atleast_1d(np.asarray(lam, float))
    c2 = np.atleast_1d(np.asarray(c2, float))
    yy = float(yy)
    rest_min = max(yy - float(np.max(c2.sum(-1), initial=0.0)), 1e-12 * yy)
    coarse = coarse_grid(yy, m, rest_min)
    g = _spectral(lam, c2, yy, m, np.broadcast_to(coarse, lam.shape[:-1] + coarse.shape))
    w = coarse[np.argmax(g, axis=-1)]
    done = np.zeros(np.shape(w), bool)
    for _ in range(12):  # Newton, steps clipped to the coarse spacing, to NEWTON_TOL
        d1, d2 = _derivs(lam, c2, yy, m, w)
        step = np.clip(np.where(d2 < 0, -d1 / np.where(d2 < 0, d2, -1.0), np.sign(d1) * 0.3),
                       -0.3, 0.3)
        w = np.where(done, w, w + step)
        done = done | (np.abs(step) <= NEWTON_TOL)
    _, d2 = _derivs(lam, c2, yy, m, w)
    sd = 1.0 / np.sqrt(np.maximum(-d2, 1e-2))
    # a peaked, smooth integrand: the trapezoid's end points are ~e^-40 of the peak
    lead, k = np.shape(w), lam.shape[-1]
    count = int(np.prod(lead, dtype=int))
    flat = lambda a, tail=(): np.broadcast_to(a, lead + tail).reshape((count,) + tail)
    L, C, W, SD = flat(lam, (k,)), flat(c2, (k,)), flat(w), flat(sd)
    c2_sum = C.sum(-1)
    log_z = np.empty(W.size)
    for on, t, log_weight in rules(m - k, np.maximum(yy - c2_sum, 1e-12 * yy), c2_sum):
        if on.any():
            grid = W[on, None] + SD[on, None] * t
            log_z[on] = _log_integral(_spectral(L[on], C[on], yy, m, grid), log_weight)
    return log_z.reshape(lead) + np.log(sd) + np.log(0.5), w  # dsigma/sigma = dw / 2


def prior_root(prior_var) -> np.ndarray:
    """R with S = R R^T: S a vector (diagonal prior variances) or a full covariance matrix."""
    S = np.asarray(prior_var, float)
    if S.ndim == 1:
        return np.diag(np.sqrt(S))
    lam, V = np.linalg.eigh(0.5 * (S + S.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def spectrum(Xt: np.ndarray, yt: np.ndarray, prior_var) -> tuple[np.ndarray, np.ndarray]:
    """(lam, c2) of the model with projected columns Xt (n x k), projected data yt.

    ``prior_var``: the prior covariance S of theta, as its diagonal (vector) or a k x k matrix.
    """
    S = np.asarray(prior_var, float)
    B = Xt * np.sqrt(S) if S.ndim == 1 else Xt @ prior_root(S)
    A = B.T @ B
    lam, U = np.linalg.eigh(0.5 * (A + A.T))
    proj = U.T @ (B.T @ yt)
    small = lam <= 1e-12 * max(lam.max(initial=0.0), 1e-300)
    lam = np.where(small, 0.0, lam)
    c2 = np.where(small, 0.0, proj ** 2 / np.where(small, 1.0, lam))
    return lam, c2


def log_evidence(Xt: np.ndarray, yt: np.ndarray, prior_var, m: int) -> tuple[float, float]:
    """log Z and the posterior mode of log v for one model (Xt may have 0 columns)."""
    yy = float(yt @ yt)
    if Xt.shape[1] == 0:
        lz, w = log_evidence_spectral(np.zeros(0), np.zeros(0), yy, m)
    else:
        lam, c2 = spectrum(Xt, yt, prior_var)
        lz, w = log_evidence_spectral(lam, c2, yy, m)
    return float(lz), float(w)


def log_evidence_columns(Xt: np.ndarray, yt: np.ndarray, prior_var: float, m: int):
    """log Z of many one-column models at once (column j alone with prior variance prior_var)."""
    s = np.einsum("ij,ij->j", Xt, Xt) * prior_var
    b = (Xt.T @ yt) * np.sqrt(prior_var)
    small = s <= 1e-300
    c2 = np.where(small, 0.0, b ** 2 / np.where(small, 1.0, s))
    return log_evidence_spectral(s[:, None], c2[:, None], float(yt @ yt), m)


def log_evidence_mixture(Xt: np.ndarray, yt: np.ndarray, prior_std: np.ndarray, m: int,
                         shape=None):
    """log Z with theta ~ N(0, tau^2 S0), tau log-uniform on the grid ``prior_std``.

    S0 (``shape``) is the identity by default, or a k x k matrix (e.g. the design-scaled prior of
    ``candidates.prior_shape``). Scaling the prior only scales the spectrum (lam -> tau^2 lam, c2
    unchanged), so the whole grid costs one eigendecomposition. Returns (log Z, index of the best
    tau, log Z per tau).
    """
    lam1, c2 = spectrum(Xt, yt, np.ones(Xt.shape[1]) if shape is None else shape)
    tau2 = np.asarray(prior_std, float)[:, None] ** 2
    lz, _ = log_evidence_spectral(tau2 * lam1, np.broadcast_to(c2, (tau2.shape[0], c2.size)),
                                  float(yt @ yt), m)
    return float(logsumexp(lz) - np.log(lz.size)), int(np.argmax(lz)), lz


def log_evidence_presence(Xt: np.ndarray, yt: np.ndarray, prior_std: np.ndarray, m: int,
                          groups) -> float:
    """log Z of an effect made of several kinds of shape, each present or not (issue 15 item 5).

    DESIGN.md names form's content as kinds -- "plate not flat: bow, twist, warp" -- not as one
    four-part shape that comes whole: a plate may be bowed and not twisted. With nothing known
    about which kinds a plate has, each is present with probability 1/2, independently, given
    the effect (at least one present): the 2^g - 1 non-empty sets of the g kinds are equally
    likely, and the present kinds share the scale mixture of ``log_evidence_mixture``. So
    Z = mean over the non-empty sets S of Z(columns of S). ``groups``: the kind of each column
    (per-round copies of a kind share its label). Against the all-present prior this costs at
    most ln(2^g - 1) (ln 15 for form's four shapes) where every kind is there, and saves the
    Occam factor of the kinds that are absent (about 0.5 ln(1 + lam tau^2 / v) each).
    """
    from itertools import combinations

    groups = np.asarray(groups)
    labels = np.unique(groups)
    lz = [log_evidence_mixture(Xt[:, np.isin(groups, S)], yt, prior_std, m)[0]
          for r in range(1, labels.size + 1) for S in combinations(labels.tolist(), r)]
    return float(logsumexp(lz) - np.log(len(lz)))


def log_evidence_columns_mixture(Xt: np.ndarray, yt: np.ndarray, prior_std: np.ndarray, m: int):
    """``log_evidence_mixture`` for many one-column models at once: (log Z (L,), best tau (L,))."""
    s = np.einsum("ij,ij->j", Xt, Xt)
    b = Xt.T @ yt
    small = s <= 1e-300
    c2 = np.where(small, 0.0, b ** 2 / np.where(small, 1.0, s))
    tau2 = np.asarray(prior_std, float) ** 2
    lam = s[:, None] * tau2[None, :]  # (L, T): one column per model
    lz, _ = log_evidence_spectral1(lam, np.broadcast_to(c2[:, None], lam.shape), float(yt @ yt), m)
    return logsumexp(lz, axis=1) - np.log(tau2.size), np.argmax(lz, axis=1)


def prior_precision(prior_var) -> np.ndarray:
    """S^-1 of a prior given as its diagonal or as a (non-singular) covariance matrix."""
    S = np.asarray(prior_var, float)
    if S.ndim == 1:
        return np.diag(1.0 / S)
    L = np.linalg.cholesky(0.5 * (S + S.T))
    Li = np.linalg.solve(L, np.eye(S.shape[0]))
    return Li.T @ Li


def posterior(Xt: np.ndarray, yt: np.ndarray, prior_var, noise_var: float):
    """Mean and covariance of theta given v: (Xt^T Xt / v + S^-1)^-1 Xt^T yt / v."""
    P = Xt.T @ Xt / noise_var + prior_precision(prior_var)
    L = np.linalg.cholesky(0.5 * (P + P.T))
    cov = np.linalg.solve(L.T, np.linalg.solve(L, np.eye(P.shape[0])))
    mean = cov @ (Xt.T @ yt) / noise_var
    return mean, 0.5 * (cov + cov.T)


def loo_residuals(D: np.ndarray, y: np.ndarray, penalty: np.ndarray) -> np.ndarray:
    """Leave-one-out residuals of the penalised least squares fit y ~ D coef, penalty diag.

    Exact shortcut for a linear smoother: e_i / (1 - H_ii), H = D (D^T D + diag(penalty))^-1 D^T.
    Columns with zero penalty are the flat-prior nuisance (tilt, offset). ``penalty`` is the
    diagonal or a full (k x k) penalty matrix (noise variance x prior precision).
    """
    pen = np.asarray(penalty, float)
    A = D.T @ D + (np.diag(pen) if pen.ndim == 1 else pen)
    A = 0.5 * (A + A.T) + 1e-12 * np.trace(A) / A.shape[0] * np.eye(A.shape[0])
    L = np.linalg.cholesky(A)
    W = np.linalg.solve(L, D.T)  # k x n
    h = np.einsum("ij,ij->j", W, W)
    coef = np.linalg.solve(L.T, W @ y)
    e = y - D @ coef
    return e / np.maximum(1.0 - h, 1e-12)
