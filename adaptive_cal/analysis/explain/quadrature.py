"""The rules of explain's integral over the noise variance (``evidence``): Newton's start grid
and stop, and the quadrature about the mode (the module docstring of ``evidence`` says which rule
is used where and how accurate it is; tests/test_explain_quadrature.py checks it against scipy's
adaptive quadrature)."""
from __future__ import annotations

import numpy as np

LOG2PI = float(np.log(2.0 * np.pi))
TIGHT = 0.1  # bounds on the mode this close in w: Newton starts between them (``evidence1``)
# Newton stops after a step of at most this (in w = log v): it converges quadratically (steps
# of 0.1, 7e-3, 2e-5, 3e-10 on 4,000 rows), so the mode is then off by ~1e-8 of v, 1e-6 of its
# posterior sd at 100,000 rows: nothing the rules below can see
NEWTON_TOL = 1e-4
_RULES = {n: (np.linspace(-9.0, 9.0, n), np.full(n, np.log(18.0 / (n - 1)))) for n in (25, 49, 73)}


def quadrature(dof: int) -> tuple[np.ndarray, np.ndarray]:
    """(nodes t, log weights): integral f(w) dw ~ sd sum exp(log weight) f(w_mode + sd t), for
    an integrand with ``dof`` = m - k residual degrees of freedom (module docstring)."""
    return _RULES[73 if dof < 20 else 49 if dof < 100 else 25]


GAUSS_HERMITE_DOF = 1000
_GH_NODES, _GH_WEIGHTS = np.polynomial.hermite_e.hermegauss(9)  # weight exp(-t^2 / 2)
GAUSS_HERMITE = (_GH_NODES, np.log(_GH_WEIGHTS) + 0.5 * _GH_NODES ** 2)


def near_gaussian(dof: int, rest: np.ndarray, c2_sum: np.ndarray) -> np.ndarray:
    """Models whose integrand in w is a Gaussian to within what Gauss-Hermite's 9 points
    integrate exactly (``GAUSS_HERMITE``, used for them instead of the trapezoid): many residual
    degrees of freedom (``GAUSS_HERMITE_DOF``) and an effect that explains little of the data,
    sum c2 below ~0.1 of the rest (log(1 + sum c2 / rest) < ``TIGHT``: most bump centres), so
    the integrand is the no-effect one's log-gamma, slightly moved. Against scipy's quad on
    such models: <= 1e-10 nats from 1,000 to 100,000 rows. Where the effect holds most of the
    data with a prior spectrum near the noise, the integrand is lopsided and 9 points were
    6.5e-4 nats off at 1,500 rows (an outside audit): those keep the trapezoid."""
    if dof < GAUSS_HERMITE_DOF:
        return np.zeros(np.shape(rest), bool)
    return np.log1p(c2_sum / rest) < TIGHT


def rules(dof: int, rest: np.ndarray, c2_sum: np.ndarray):
    """Which rule integrates which model: ((models, nodes, log weights), ...) -- the trapezoid of
    ``quadrature(dof)`` for the models not ``near_gaussian``, ``GAUSS_HERMITE`` for those that
    are (``rest``, ``c2_sum`` per model, as there)."""
    gauss = near_gaussian(dof, rest, c2_sum)
    return (~gauss, *quadrature(dof)), (gauss, *GAUSS_HERMITE)


def coarse_grid(yy: float, m: int, rest_min: float) -> np.ndarray:
    """Newton's start grid in w, 0.3 apart: from 14 below log(yy / m) to 4 above -- and further
    down to 1 below log(rest / m) where a model leaves almost nothing (rest, its smallest
    residual sum of squares: an effect of 1e4 noise sds), whose mode would otherwise lie below
    the grid, beyond the 12 Newton steps of 0.3."""
    low = min(-14.0, float(np.log(max(rest_min, 1e-300) / max(yy, 1e-300))) - 1.0)
    n = int(np.ceil((4.0 - low) / 0.3 - 1e-9)) + 1  # 61: the grid of old, exactly
    return np.log(max(yy / m, 1e-300)) + np.linspace(4.0 - 0.3 * (n - 1), 4.0, n)


def _log_integral(g: np.ndarray, log_weight: np.ndarray) -> np.ndarray:
    """log sum_j exp(g[..., j] + log_weight[j]): shifted by the largest g (g -inf everywhere
    gives -inf), in place on one copy of g."""
    top = g.max(axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    x = np.subtract(g, top)
    x += log_weight
    with np.errstate(divide="ignore"):  # log 0 = -inf is the answer there
        return np.log(np.exp(x, out=x).sum(axis=-1)) + top[..., 0]
