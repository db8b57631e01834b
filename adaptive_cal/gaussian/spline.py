"""Stochastic cubic splines parameterised by their values at control points (Brunn & Hanebeck).

1-D: S(t) = m(t)^T a on [t_1, t_n], with (Brunn eq. 19)

    m(t)^T = delta_i^T + M1[i] s + M2[i] s^2 + M3[i] s^3,   s = t - t_i,  t in [t_i, t_{i+1}],

where b = M1 a, c = M2 a, d = M3 a are the power-form coefficients (eq. 11). They follow from the
second derivatives sigma = Sigma a, found from C2 continuity plus the end conditions:

* ``natural``     sigma_1 = sigma_n = 0 (Brunn eqs. 3-6): reproduces any straight line;
* ``not_a_knot``  third derivative continuous at t_2 and t_{n-1}: reproduces any cubic, so a
                  bowed plate is not forced flat at its edge;
* ``cyclic``      S, S', S'' equal at both ends (eqs. 7-10); then a_n = a_1 and the spline has
                  n - 1 free values (rotary axes).

2-D (bicubic tensor product): S(x, y) = (m_x(x) kron m_y(y))^T vec(A), vec(A) row-major in x.
Integrated variance J(C) = trace(Q C), Q = Q_x kron Q_y, Q_x = integral m_x m_x^T dx, computed
exactly with 4-point Gauss-Legendre per knot interval (the integrand has degree 6).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Ends = Literal["natural", "not_a_knot", "cyclic"]


def _cyclic_second_derivative_map(knots: np.ndarray) -> np.ndarray:
    """Sigma (n x (n-1)) for a cyclic spline: parameters a_1..a_{n-1}, a_n = a_1, sigma_n = sigma_1.

    Knot i joins the interval before it (knot 1: the last interval, length h_{n-1}) to the one
    after it, so every knot gets the C2 equation of an interior knot."""
    n = len(knots)
    h = np.diff(knots)
    m = n - 1
    lhs = np.zeros((m, m))
    rhs = np.zeros((m, m))
    for i in range(m):
        prev, nxt = (i - 1) % m, (i + 1) % m
        hp, hn = h[i - 1] if i > 0 else h[-1], h[i]
        lhs[i, prev] += hp
        lhs[i, i] += 2 * (hp + hn)
        lhs[i, nxt] += hn
        rhs[i, nxt] += 6 / hn
        rhs[i, i] += -6 / hn - 6 / hp
        rhs[i, prev] += 6 / hp
    sigma = np.linalg.solve(lhs, rhs)
    return np.vstack([sigma, sigma[:1]])


def _second_derivative_map(knots: np.ndarray, ends: Ends) -> np.ndarray:
    """Sigma (n x n): second derivatives at the knots as a linear map of the knot values."""
    if ends == "cyclic":
        return _cyclic_second_derivative_map(knots)
    n = len(knots)
    h = np.diff(knots)
    lhs = np.zeros((n, n))
    rhs = np.zeros((n, n))
    for i in range(1, n - 1):  # C2 continuity at interior knots
        lhs[i, i - 1], lhs[i, i], lhs[i, i + 1] = h[i - 1], 2 * (h[i - 1] + h[i]), h[i]
        rhs[i, i - 1], rhs[i, i], rhs[i, i + 1] = 6 / h[i - 1], -6 / h[i - 1] - 6 / h[i], 6 / h[i]
    if ends == "natural" or n == 2:
        lhs[0, 0] = lhs[-1, -1] = 1.0
    elif ends == "not_a_knot":
        if n == 3:  # one parabola: constant second derivative
            lhs[0, :2] = (1.0, -1.0)
            lhs[-1, 1:] = (1.0, -1.0)
        else:
            lhs[0, :3] = (h[1], -(h[0] + h[1]), h[0])
            lhs[-1, -3:] = (h[-1], -(h[-2] + h[-1]), h[-2])
    else:
        raise ValueError(f"ends must be 'natural', 'not_a_knot' or 'cyclic', got {ends!r}")
    return np.linalg.solve(lhs, rhs)


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality and hash
class Spline1D:
    """A cubic spline basis on fixed knots (mm). ``size`` values parameterise it."""

    knots: np.ndarray
    ends: Ends
    M1: np.ndarray  # (n-1, size) slope coefficients b_i (Brunn eq. 11)
    M2: np.ndarray  # (n-1, size) c_i = sigma_i / 2
    M3: np.ndarray  # (n-1, size) d_i = (sigma_{i+1} - sigma_i) / (6 h_i)
    expand: np.ndarray  # (n, size): knot values from the parameters (identity unless cyclic)

    @classmethod
    def create(cls, knots, ends: Ends = "not_a_knot") -> "Spline1D":
        knots = np.asarray(knots, float)
        if knots.ndim != 1 or len(knots) < 2 or np.any(np.diff(knots) <= 0):
            raise ValueError(f"knots must be at least 2 increasing values, got {knots}")
        if ends == "cyclic" and len(knots) < 3:
            raise ValueError("a cyclic spline needs at least 3 knots")
        n = len(knots)
        h = np.diff(knots)[:, None]
        sigma = _second_derivative_map(knots, ends)  # (n, size)
        expand = np.eye(n)
        if ends == "cyclic":
            expand = np.eye(n)[:, : n - 1]
            expand[n - 1, 0] = 1.0
        a = expand
        M1 = (a[1:] - a[:-1]) / h - h * (2 * sigma[:-1] + sigma[1:]) / 6.0
        M2 = sigma[:-1] / 2.0
        M3 = (sigma[1:] - sigma[:-1]) / (6.0 * h)
        return cls(knots, ends, M1, M2, M3, expand)

    @property
    def size(self) -> int:
        return self.expand.shape[1]

    @property
    def period(self) -> float:
        return float(self.knots[-1] - self.knots[0])

    def basis(self, t, xp=np):
        """Rows m(t)^T for points t (any shape): shape t.shape + (size,). ``xp``: numpy or
        jax.numpy (differentiable in t within a knot interval). Outside the knots the end
        cubics are extended (cyclic splines wrap around)."""
        t = xp.asarray(t)
        knots = xp.asarray(self.knots)
        if self.ends == "cyclic":
            t = knots[0] + xp.mod(t - knots[0], self.period)
        i = xp.clip(xp.searchsorted(knots, t, side="right") - 1, 0, len(self.knots) - 2)
        s = (t - knots[i])[..., None]
        delta = xp.asarray(self.expand)[i]
        return (delta + xp.asarray(self.M1)[i] * s + xp.asarray(self.M2)[i] * s**2
                + xp.asarray(self.M3)[i] * s**3)

    def gram(self) -> np.ndarray:
        """Q = integral over [t_1, t_n] of m(t) m(t)^T dt, exact (4-point Gauss-Legendre per
        interval integrates the degree-6 integrand exactly). Computed once per spline (its
        knots never change) and returned read-only."""
        q = self.__dict__.get("_gram")
        if q is None:
            nodes, weights = np.polynomial.legendre.leggauss(4)
            lo, hi = self.knots[:-1, None], self.knots[1:, None]
            t = 0.5 * (hi - lo) * nodes + 0.5 * (hi + lo)  # (n-1, 4)
            w = 0.5 * (hi - lo) * weights
            m = self.basis(t.ravel()).reshape(-1, self.size)
            q = (m * w.ravel()[:, None]).T @ m
            q.setflags(write=False)
            self.__dict__["_gram"] = q  # frozen dataclass: set past __setattr__
        return q


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality and hash
class Surface:
    """Bicubic tensor-product spline over a rectangle: S(x, y) = (m_x kron m_y)^T vec(A)."""

    sx: Spline1D
    sy: Spline1D

    @classmethod
    def create(cls, knots_x, knots_y, ends: Ends = "not_a_knot") -> "Surface":
        return cls(Spline1D.create(knots_x, ends), Spline1D.create(knots_y, ends))

    @property
    def size(self) -> int:
        return self.sx.size * self.sy.size

    @property
    def shape(self) -> tuple[int, int]:
        return self.sx.size, self.sy.size

    def basis(self, x, y, xp=np):
        """Rows h(x, y)^T = m_x(x) kron m_y(y): shape (..., size)."""
        mx = self.sx.basis(x, xp)
        my = self.sy.basis(y, xp)
        out = mx[..., :, None] * my[..., None, :]
        return out.reshape(out.shape[:-2] + (self.size,))

    def gram(self) -> np.ndarray:
        """Q = Q_x kron Q_y, so that J(C) = trace(Q C) is the integrated variance (mm^2 mm^2)."""
        return np.kron(self.sx.gram(), self.sy.gram())

    @property
    def area_mm2(self) -> float:
        return self.sx.period * self.sy.period

    @property
    def knot_interval_mm(self) -> float:
        """The largest knot interval along x or y (mm): the finest scale the spline resolves
        everywhere."""
        return float(max(np.diff(self.sx.knots).max(), np.diff(self.sy.knots).max()))

    def knot_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates (x, y) of each coefficient, in vec(A) order."""
        gx, gy = np.meshgrid(self.sx.knots[: self.sx.size], self.sy.knots[: self.sy.size],
                             indexing="ij")
        return gx.ravel(), gy.ravel()


def default_knots(lo_mm: float, hi_mm: float, tolerance_mm: float, max_curvature_per_mm: float,
                  *, minimum: int = 4, maximum: int = 16) -> np.ndarray:
    """Evenly spaced knots no further apart than Brunn eq. 15, x_d <= sqrt(6 (S_u - S_l) / k_max),
    in ``minimum`` .. ``maximum`` knots: where eq. 15 asks for more than ``maximum`` the spacing
    is wider than it (a tolerance of 1 um at a curvature of 1e-4 / mm asks 7.7 mm; 450 mm then
    gets 30 mm) -- the self-checks (``planning.adequacy``) judge what the knots miss."""
    spacing = np.sqrt(6.0 * tolerance_mm / max_curvature_per_mm)
    n = int(np.clip(np.ceil((hi_mm - lo_mm) / spacing) + 1, minimum, maximum))
    return np.linspace(lo_mm, hi_mm, n)


def refined(knots: np.ndarray) -> np.ndarray:
    """The knots with the midpoint of every interval inserted (nested: a cubic spline on the
    old knots is one on the new knots)."""
    knots = np.asarray(knots, float)
    mid = 0.5 * (knots[:-1] + knots[1:])
    return np.sort(np.concatenate([knots, mid]))


def embedding(coarse: Surface, fine: Surface) -> np.ndarray:
    """E (K_fine x K_coarse): the fine spline's knot values of every coarse spline, exact when
    the fine knots contain the coarse ones (a spline is parameterised by its knot values), so
    basis_fine(x, y) E = basis_coarse(x, y)."""
    gx, gy = fine.knot_grid()
    return coarse.basis(gx, gy)
