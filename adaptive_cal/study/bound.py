"""Lower bound on touches: the continuous relaxation of the optimal (I-optimal, Bayesian) design,
and the best integer design by exhaustive search where that is feasible.

A design puts n touches on the candidate rows h_i with weights w (w_i >= 0, sum w = 1):

    M(w) = C0^-1 + (n / r) sum_i w_i h_i h_i^T,   J(n, w) = trace(Q M(w)^-1).

J is convex in w with gradient dJ/dw_i = -(n / r) h_i^T W h_i, W = C Q C, C = M^-1 -- the
numerator of the planner's dJ. Any integer design of n touches is a feasible w (counts / n), so
J*(n) = min_w J(n, w) <= J(any n-touch design). Frank-Wolfe gives w and the certified bound

    J*(n) >= J(n, w) - (n / r) (max_i h_i^T W h_i - sum_i w_i h_i^T W h_i)   (duality gap),

so the smallest n whose certified bound meets the target is a lower bound on the touches of every
design on the candidates -- the adaptive planner's included (for the same hyper-parameters).
Touches come whole, so the bound rounds up: a design needs at least the smallest integer n not
excluded by its certificate (``integer_touches``). The planner also refines points off the
candidate grid; on five seed-99 study plates the bound came out the same with 1,000 and 4,000
candidates, so the grid does not make it optimistic.

The planner does not know the hyper-parameters: it learns them and stops on the integrated
variance of its belief marginalised over their posterior (sigma points theta_k with weights a_k,
``prior.hyper_posterior``), whose covariance is sum_k a_k C_k plus the spread of the component
means. So a design meeting the planner's own stop with that hyper-parameter posterior has

    J_marg(n, w) = sum_k a_k trace(Q M_k(w)^-1) <= target,
    M_k = C0_k^-1 + (n / r_k) sum_i w_i h_i h_i^T,

the pseudo-Bayesian I-criterion (Chaloner & Verdinelli 1995): convex in w, gradient
-n sum_k (a_k / r_k) h_i^T W_k h_i, and the same certificate with the weighted scores
(``MarginalProblem``). Its bound answers "how few touches could meet this stop, knowing the
posterior over the hyper-parameters the planner held when it stopped" (at a refit the mixture's
variance is at least J_marg; after it, new readings are fused under the MAP's noise); the
single-hyper bound answers "how few touches could an oracle that knows the hyper-parameters
need". Both go into the summary.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from adaptive_cal.cell.schema import Cell
from adaptive_cal.gaussian.belief import Belief, fuse_step, information_cov, integrated_variance
from adaptive_cal.gaussian.belief import precision
from adaptive_cal.planning.scoring import candidate_grid
from adaptive_cal.gaussian.prior import Hyper, PriorModel


@dataclass(frozen=True)
class DesignProblem:
    """Prior precision, Gram matrix, candidate rows and noise variance of one design question."""

    prior_cov: np.ndarray  # C0 (K, K)
    gram: np.ndarray  # Q (K, K)
    rows: np.ndarray  # (N, K)
    noise_var: float  # r (mm^2)
    area_mm2: float

    @cached_property
    def prior_precision(self) -> np.ndarray:
        return precision(self.prior_cov)

    @cached_property
    def prior_integrated_variance(self) -> float:
        """J with no touches: trace(Q C0)."""
        return float(integrated_variance(self.prior_cov, self.gram))

    def integrated_variance(self, counts: np.ndarray) -> float:
        """J of an integer design given as touch counts per candidate."""
        return _objective(self, np.asarray(counts, float), 1.0)[0]


@dataclass(frozen=True)
class MarginalProblem:
    """The design question under a posterior over the hyper-parameters: one ``DesignProblem``
    per weighted hyper-parameter point (same candidates and Gram matrix), J the weighted sum."""

    parts: tuple[DesignProblem, ...]
    weights: tuple[float, ...]

    def __post_init__(self):
        if not self.parts or len(self.parts) != len(self.weights):
            raise ValueError("a marginal design problem needs one weight per hyper-parameter point")
        if abs(sum(self.weights) - 1.0) > 1e-9 or min(self.weights) < 0:
            raise ValueError(f"hyper-parameter weights must be >= 0 and sum to 1, not "
                             f"{list(self.weights)}")

    @property
    def rows(self) -> np.ndarray:
        return self.parts[0].rows

    @property
    def gram(self) -> np.ndarray:
        return self.parts[0].gram

    @property
    def area_mm2(self) -> float:
        return self.parts[0].area_mm2

    @cached_property
    def prior_integrated_variance(self) -> float:
        return float(sum(a * p.prior_integrated_variance for p, a in zip(self.parts, self.weights)))

    def integrated_variance(self, counts: np.ndarray) -> float:
        return _objective(self, np.asarray(counts, float), 1.0)[0]


Problem = DesignProblem | MarginalProblem


def _candidate_rows(cell: Cell, model: PriorModel, candidates: int) -> np.ndarray:
    wp, m = cell.workplane, cell.workplane.edge_margin_mm
    return candidate_grid(model.surface, wp.allows, (wp.x_mm[0] + m, wp.x_mm[1] - m),
                          (wp.y_mm[0] + m, wp.y_mm[1] - m), candidates).rows


def design_problem(cell: Cell, model: PriorModel, hyper: Hyper, *, candidates: int,
                   rows: np.ndarray | None = None) -> DesignProblem:
    rows = _candidate_rows(cell, model, candidates) if rows is None else rows
    return DesignProblem(model.belief(hyper).cov, model.surface.gram(), rows,
                         hyper.noise_std_mm**2, model.surface.area_mm2)


def marginal_problem(cell: Cell, model: PriorModel, points, *, candidates: int) -> MarginalProblem:
    """``points``: (hyper-parameters, weight) pairs, as ``prior.hyper_posterior`` returns."""
    rows = _candidate_rows(cell, model, candidates)
    return MarginalProblem(
        tuple(design_problem(cell, model, Hyper(*h), candidates=candidates, rows=rows)
              for h, _ in points), tuple(float(w) for _, w in points))


def _objective(prob: Problem, weights: np.ndarray, n: float, scores: bool = True):
    """J(n, w) and the scaled scores s_i = h_i^T W h_i / r (so that dJ/dw_i = -n s_i), summed
    with the hyper-parameter weights for a ``MarginalProblem`` (Cholesky solves, never inv)."""
    if isinstance(prob, MarginalProblem):
        total, summed = 0.0, 0.0
        for part, a in zip(prob.parts, prob.weights):
            j, s = _objective(part, weights, n, scores)
            total += a * j
            if scores:
                summed = summed + a * s
        return total, (summed if scores else None)
    active = weights > 0
    rows = prob.rows[active]
    info = (rows * (weights[active] * n / prob.noise_var)[:, None]).T @ rows
    cov = information_cov(prob.prior_precision, info)
    if not scores:
        return float(integrated_variance(cov, prob.gram)), None
    w = cov @ prob.gram @ cov
    scores = np.einsum("nk,nk->n", prob.rows @ w, prob.rows) / prob.noise_var
    return float(integrated_variance(cov, prob.gram)), scores


def relaxed_design(prob: Problem, n: float, *, iterations: int = 300, tol: float = 2e-3,
                   start: np.ndarray | None = None, decide: float | None = None):
    """Weights minimising J(n, w) on the simplex: the multiplicative algorithm
    w_i <- w_i (s_i / w^T s)^(1/2) (a fixed point is exactly the optimality condition
    s_i <= w^T s with equality on the support), each step followed by a Frank-Wolfe step
    with exact line search. Returns (weights, J, certified lower bound on J*(n)).

    ``decide``: stop as soon as the question "can n touches reach J = decide?" is settled
    (certified lower bound above it: no; a design at or below it: yes). Both answers are final
    -- the bound only rises and J only falls -- so the bisections below get the same answers
    as from a fully converged run, in far fewer iterations away from the threshold."""
    size = len(prob.rows)
    w = np.full(size, 1.0 / size) if start is None else np.maximum(start, 1e-12 / size)
    w /= w.sum()
    best_lower = -np.inf
    j, s = _objective(prob, w, n)
    for _ in range(iterations):
        gap = n * (s.max() - w @ s)
        best_lower = max(best_lower, j - gap)
        if j - best_lower <= tol * j or (decide is not None
                                         and (best_lower > decide or j <= decide)):
            break
        w = w * np.sqrt(s / (w @ s))
        w /= w.sum()
        w[w < 1e-10 * w.max()] = 0.0
        w /= w.sum()
        j, s = _objective(prob, w, n)
        # Frank-Wolfe step towards the best vertex (golden-section line search, J convex)
        direction = -w.copy()
        direction[int(np.argmax(s))] += 1.0
        lo, hi, g = 0.0, 1.0, (math.sqrt(5) - 1) / 2
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        fa = _objective(prob, w + a * direction, n, False)[0]
        fb = _objective(prob, w + b * direction, n, False)[0]
        for _ in range(12):
            if fa < fb:
                hi, b, fb = b, a, fa
                a = hi - g * (hi - lo)
                fa = _objective(prob, w + a * direction, n, False)[0]
            else:
                lo, a, fa = a, b, fb
                b = lo + g * (hi - lo)
                fb = _objective(prob, w + b * direction, n, False)[0]
        cand = np.maximum(w + 0.5 * (lo + hi) * direction, 0.0)
        jc, sc = _objective(prob, cand / cand.sum(), n)
        if jc < j:
            w, j, s = cand / cand.sum(), jc, sc
    gap = n * (s.max() - w @ s)
    return w, j, max(best_lower, j - gap)


def relaxed_integrated_variance(prob: Problem, n: float, iterations: int = 200) -> float:
    """A certified lower bound on J*(n): no n-touch design has a smaller integrated variance."""
    return relaxed_design(prob, n, iterations=iterations)[2]


def relaxed_touches(prob: Problem, target_j: float, max_touches: int,
                    *, iterations: int = 300) -> float:
    """Smallest real n whose certified J*(n) lower bound reaches ``target_j`` (bisection): no
    design on the candidates meets the target with fewer touches. inf if max_touches fails."""
    w = None
    lo, hi = 0.0, float(max_touches)
    if relaxed_design(prob, hi, iterations=iterations, decide=target_j)[2] > target_j:
        return math.inf
    if prob.prior_integrated_variance <= target_j:
        return 0.0
    while hi - lo > 0.02 * max(hi, 1.0):
        mid = 0.5 * (lo + hi)
        w, j, lower = relaxed_design(prob, mid, iterations=iterations, start=w, decide=target_j)
        if lower > target_j:
            lo = mid  # certified: fewer than mid touches cannot reach the target
        elif j <= target_j:
            hi = mid
        else:  # not resolved within the iterations: stay on the safe side for a lower bound
            hi = mid
    return lo


def integer_touches(prob: Problem, target_j: float, max_touches: int,
                    *, relaxed: float | None = None, iterations: int = 300) -> float:
    """The relaxed bound in whole touches: the smallest integer n whose certified J*(n) lower
    bound does not exclude ``target_j``. Every n-touch design is a feasible relaxed design
    (w = counts / n) and J*(n) falls with n, so a design needs more than ``relaxed`` touches,
    i.e. at least floor(relaxed) + 1; each whole n above that is then tried and skipped only
    while its certificate still excludes the target (an unresolved certificate stops the
    search: the safe side for a lower bound). inf if max_touches fail."""
    lo = relaxed_touches(prob, target_j, max_touches, iterations=iterations) \
        if relaxed is None else relaxed
    if not math.isfinite(lo):
        return math.inf
    if prob.prior_integrated_variance <= target_j:
        return 0.0  # the prior alone meets the target
    n, w = math.floor(lo) + 1, None
    while n <= max_touches:
        w, _, lower = relaxed_design(prob, n, iterations=iterations, start=w, decide=target_j)
        if lower <= target_j:
            return float(n)
        n += 1
    return math.inf


def greedy_touches(prob: DesignProblem, target_j: float, max_touches: int) -> int | None:
    """Touches of the greedy sequential design under the same hyper-parameters (each touch the
    candidate with the largest drop of J, as the planner scores it, with nothing to learn): a
    feasible integer design, so relaxed <= best integer <= greedy brackets the best integer
    design where enumeration is out of reach. None if max_touches do not reach ``target_j``."""
    belief = Belief(np.zeros(len(prob.prior_cov)), prob.prior_cov)
    for n in range(max_touches + 1):
        if float(integrated_variance(belief.cov, prob.gram)) <= target_j:
            return n
        ch = prob.rows @ belief.cov
        drop = np.einsum("nk,kl,nl->n", ch, prob.gram, ch) / (
            np.einsum("nk,nk->n", ch, prob.rows) + prob.noise_var)
        i = int(np.argmax(drop))
        belief = fuse_step(belief, prob.rows[i], 0.0, prob.noise_var)  # C' is reading-free
    return None


def best_integer_touches(prob: Problem, target_j: float, max_touches: int,
                         limit: int) -> int | None:
    """Smallest n for which some n-touch design (a multiset of candidates) reaches ``target_j``,
    by exhaustive enumeration; None when the enumeration would exceed ``limit`` designs."""
    size = len(prob.rows)
    for n in range(max_touches + 1):
        if math.comb(size + n - 1, n) > limit:
            return None
        for combo in itertools.combinations_with_replacement(range(size), n):
            counts = np.bincount(np.asarray(combo, int), minlength=size)
            if prob.integrated_variance(counts) <= target_j:
                return n
    return None
