"""Spline oracles: scipy's CubicSpline, exact planes and cubics, end conditions, dense quadrature."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import trapezoid
from scipy.interpolate import CubicSpline

from adaptive_cal.gaussian.spline import Spline1D, Surface, default_knots

RNG = np.random.default_rng(7)
KNOTS = np.array([0.0, 1.3, 2.0, 3.7, 5.1, 6.0, 8.4, 10.0])


@pytest.mark.parametrize("ends,bc", [("natural", "natural"), ("not_a_knot", "not-a-knot")])
def test_basis_equals_scipy_cubic_spline(ends, bc):
    s = Spline1D.create(KNOTS, ends)
    a = RNG.normal(size=len(KNOTS))
    t = np.linspace(-0.5, 10.5, 401)
    np.testing.assert_allclose(s.basis(t) @ a, CubicSpline(KNOTS, a, bc_type=bc)(t), atol=1e-12)


def test_cyclic_equals_scipy_periodic_and_is_c2_across_the_seam():
    s = Spline1D.create(KNOTS, "cyclic")
    a = RNG.normal(size=s.size)
    ref = CubicSpline(KNOTS, np.r_[a, a[0]], bc_type="periodic")
    t = np.linspace(0, 10, 301)
    np.testing.assert_allclose(s.basis(t) @ a, ref(t), atol=1e-12)
    # value, slope and curvature agree just before and just after the seam (wrap-around)
    eps = 1e-6
    f = lambda u: s.basis(np.array([u]))[0] @ a  # noqa: E731
    left = [f(10 - eps), f(10 - 2 * eps), f(10 - 3 * eps)]
    right = [f(0 + eps), f(0 + 2 * eps), f(0 + 3 * eps)]
    # finite differences of first and second order on each side
    d1l, d1r = (left[0] - left[1]) / eps, (right[1] - right[0]) / eps
    d2l = (left[0] - 2 * left[1] + left[2]) / eps**2
    d2r = (right[2] - 2 * right[1] + right[0]) / eps**2
    assert abs(left[0] - right[0]) < 1e-5
    assert abs(d1l - d1r) < 1e-4
    assert abs(d2l - d2r) < 1e-1 * max(1.0, abs(d2l))
    # exact: the power-form second derivative 2 c at the first knot equals that at the last
    c_end = 2 * s.M2[-1] + 6 * s.M3[-1] * (KNOTS[-1] - KNOTS[-2])
    np.testing.assert_allclose(c_end @ a, 2 * s.M2[0] @ a, atol=1e-10)


@pytest.mark.parametrize("ends", ["natural", "not_a_knot"])
def test_a_line_is_reproduced_exactly(ends):
    s = Spline1D.create(KNOTS, ends)
    t = np.linspace(0, 10, 97)
    np.testing.assert_allclose(s.basis(t) @ (0.3 * KNOTS - 2.0), 0.3 * t - 2.0, atol=1e-12)


def test_not_a_knot_reproduces_a_cubic_natural_does_not():
    t = np.linspace(0, 10, 97)
    cubic = lambda u: 0.01 * u**3 - 0.2 * u**2 + u  # noqa: E731
    nak = Spline1D.create(KNOTS, "not_a_knot").basis(t) @ cubic(KNOTS)
    nat = Spline1D.create(KNOTS, "natural").basis(t) @ cubic(KNOTS)
    np.testing.assert_allclose(nak, cubic(t), atol=1e-12)
    assert np.abs(nat - cubic(t)).max() > 1e-3


def test_natural_end_conditions_zero_curvature():
    s = Spline1D.create(KNOTS, "natural")
    a = RNG.normal(size=len(KNOTS))
    h_last = KNOTS[-1] - KNOTS[-2]
    assert abs(2 * s.M2[0] @ a) < 1e-12
    assert abs((2 * s.M2[-1] + 6 * s.M3[-1] * h_last) @ a) < 1e-12


@pytest.mark.parametrize("ends", ["natural", "not_a_knot", "cyclic"])
def test_gram_equals_dense_quadrature(ends):
    s = Spline1D.create(KNOTS, ends)
    t = np.linspace(0, 10, 400001)
    m = s.basis(t)
    dense = trapezoid(m[:, :, None] * m[:, None, :], t, axis=0)
    np.testing.assert_allclose(s.gram(), dense, atol=1e-8)


def test_surface_plane_exact_and_gram_is_2d_integral():
    surf = Surface.create(np.linspace(-200, 200, 6), np.linspace(-150, 150, 5))
    gx, gy = surf.knot_grid()
    coef = 0.014 * gx - 0.002 * gy + 0.3
    x, y = RNG.uniform(-200, 200, 500), RNG.uniform(-150, 150, 500)
    np.testing.assert_allclose(surf.basis(x, y) @ coef, 0.014 * x - 0.002 * y + 0.3, atol=1e-12)
    # trace(Q C) with C = v v^T is the integral of S(x, y)^2 over the rectangle. S is a cubic
    # in each variable on every knot cell, S^2 of degree 6: 4-point Gauss-Legendre per knot
    # interval and axis (exact to degree 7) integrates it exactly, so the tolerance is round-off.
    # (It was the trapezoid rule on an 801 x 601 grid with rtol 1e-5 and v drawn from the module's
    # shared generator: its O(h^2) error reached 2.5e-5 for some v, depending on which tests ran
    # before in the same worker -- a test that failed once in a while under pytest -n.)
    v = np.random.default_rng(7).normal(size=surf.size)
    g, w = np.polynomial.legendre.leggauss(4)

    def nodes(knots):
        a, b = knots[:-1, None], knots[1:, None]
        return ((a + b) / 2 + (b - a) / 2 * g).ravel(), ((b - a) / 2 * w).ravel()

    (xs, wx), (ys, wy) = nodes(np.linspace(-200, 200, 6)), nodes(np.linspace(-150, 150, 5))
    xx, yy = np.meshgrid(xs, ys, indexing="ij")
    f = (surf.basis(xx.ravel(), yy.ravel()) @ v).reshape(xx.shape) ** 2
    integral = wx @ f @ wy
    np.testing.assert_allclose(v @ surf.gram() @ v, integral, rtol=1e-10)


def test_jax_basis_equals_numpy_and_jit():
    surf = Surface.create(np.linspace(0, 100, 7), np.linspace(0, 80, 5))
    x, y = RNG.uniform(0, 100, 50), RNG.uniform(0, 80, 50)
    ref = surf.basis(x, y)
    eager = np.asarray(surf.basis(jnp.asarray(x), jnp.asarray(y), jnp))
    jitted = np.asarray(jax.jit(lambda a, b: surf.basis(a, b, jnp))(x, y))
    np.testing.assert_allclose(eager, ref, atol=1e-13)
    np.testing.assert_allclose(jitted, ref, atol=1e-13)


def test_default_knots_follow_brunn_eq15():
    k = default_knots(0, 450, tolerance_mm=0.1, max_curvature_per_mm=5e-5)
    assert np.diff(k).max() <= np.sqrt(6 * 0.1 / 5e-5) + 1e-9
    assert len(k) >= 4 and k[0] == 0 and k[-1] == 450


def test_bad_knots_are_refused():
    with pytest.raises(ValueError, match="increasing"):
        Spline1D.create([0, 1, 1, 2])


@pytest.mark.parametrize("n,natural_um", [(4, 18.07), (8, 2.82), (12, 1.12)])
def test_default_ends_reproduce_a_bow_natural_ends_bias_the_edge(n, natural_um):
    """DESIGN.md: a least-squares fit of the reference cell's bow (0.35 mm over 370 mm) leaves
    18 / 2.8 / 1.1 um at the edge with 4 / 8 / 12 natural knots, and 0 with not-a-knot ends."""
    y = np.linspace(-185, 185, 2001)
    bow = 0.35 * (1 - (y / 185) ** 2)
    edge = {}
    for ends in ("natural", "not_a_knot"):
        b = Spline1D.create(np.linspace(-185, 185, n), ends).basis(y)
        coef, *_ = np.linalg.lstsq(b, bow, rcond=None)
        edge[ends] = abs(b[0] @ coef - bow[0]) * 1e3
    assert edge["natural"] == pytest.approx(natural_um, abs=0.05)
    assert edge["not_a_knot"] < 1e-6
