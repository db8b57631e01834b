"""The variance of the form the spline cannot represent (``gaussian.checks.unresolved_form_var``)
against a dense reference: every 1-D integral by composite Simpson on 600 points per knot
interval instead of Gauss-Legendre on 12, and the 2-D variance composed from the kernel's and
the basis's tensor products. Simpson's error is O(h^4) with panels that do not straddle a knot:
below 1e-9 of s^2 here, so 1e-7 is round-off's and the quadrature's room, not the method's."""
import numpy as np
import pytest

from adaptive_cal.gaussian.checks import unresolved_form_var
from adaptive_cal.gaussian.spline import Surface


def _dense_axis(spline, t, length_mm, per_interval=600):
    # composite Simpson, its panels inside knot intervals (the cubic pieces meet at knots)
    n = per_interval * (len(spline.knots) - 1) + 1
    u = np.linspace(spline.knots[0], spline.knots[-1], n)
    w = np.where(np.arange(n) % 2 == 1, 4.0, 2.0) * (u[1] - u[0]) / 3
    w[[0, -1]] = (u[1] - u[0]) / 3
    m = spline.basis(u)
    mw = m * w[:, None]
    gram = mw.T @ m
    b_t = mw.T @ np.exp(-0.5 * ((u[:, None] - t[None, :]) / length_mm) ** 2)
    big_b = mw.T @ np.exp(-0.5 * ((u[:, None] - u[None, :]) / length_mm) ** 2) @ mw
    g_inv_m = np.linalg.solve(gram, spline.basis(t).T)
    a = np.einsum("kn,kn->n", g_inv_m, b_t)
    c = np.einsum("kn,kn->n", g_inv_m, big_b @ g_inv_m)
    return a, c, np.trace(np.linalg.solve(gram, big_b)) / spline.period


@pytest.mark.parametrize("ends", ["not_a_knot", "natural", "cyclic"])
@pytest.mark.parametrize("length_mm", [25.0, 80.0])
def test_unresolved_form_variance_equals_a_dense_reference(ends, length_mm):
    surface = Surface.create(np.linspace(-225, 225, 5), np.linspace(-185, 185, 4), ends=ends)
    rng = np.random.default_rng(3)
    # scattered points and a grid (whose points share coordinates along each axis)
    gx, gy = np.meshgrid(np.linspace(-225, 225, 9), np.linspace(-185, 185, 7), indexing="ij")
    x = np.r_[rng.uniform(-225, 225, 40), gx.ravel()]
    y = np.r_[rng.uniform(-185, 185, 40), gy.ravel()]
    s = 0.01  # mm
    var, mean = unresolved_form_var(surface, s, length_mm, x, y)
    ax, cx, tx = _dense_axis(surface.sx, x, length_mm)
    ay, cy, ty = _dense_axis(surface.sy, y, length_mm)
    expected = np.maximum(s**2 * (1 - 2 * ax * ay + cx * cy), 0.0)
    assert var.shape == x.shape
    np.testing.assert_allclose(var, expected, rtol=0, atol=1e-7 * s**2)
    assert mean == pytest.approx(max(0.0, s**2 * (1 - tx * ty)), abs=1e-7 * s**2)
    # a short length scale leaves much of the form unresolved; a long one little, but for
    # cyclic ends, which cannot follow a form that differs at opposite edges
    if length_mm == 25.0:
        assert mean > 0.2 * s**2
    elif ends != "cyclic":
        assert mean < 0.2 * s**2
