"""The variance of the form the spline cannot represent (``gaussian.checks.unresolved_form_var``)
against a dense reference: every 1-D integral by composite Simpson on 600 points per knot
interval instead of Gauss-Legendre on 12, and the 2-D variance composed from the kernel's and
the basis's tensor products. Simpson's error is O(h^4) with panels that do not straddle a knot:
below 1e-9 of s^2 here, so 1e-7 is round-off's and the quadrature's room, not the method's.
The Matern-5/2 kernel's third derivative jumps at d = 0, inside Gauss-Legendre's panels: its
error there is O(h^4) of the panel width (24 nodes per interval for it): measured 4e-6 of s^2
at l = 25 mm, so 1e-5 is its room. The dense reference writes the Matern from its general form
with the Bessel function (Rasmussen & Williams 2006, eq. 4.14), not from the code's closed
form."""
import numpy as np
import pytest
from scipy import special

from adaptive_cal.gaussian.checks import unresolved_form_var
from adaptive_cal.gaussian.spline import Surface


def _kernel(d, length_mm, kernel):
    if kernel == "se":
        return np.exp(-0.5 * (d / length_mm) ** 2)
    nu = 2.5  # 2^(1 - nu) / Gamma(nu) (sqrt(2 nu) r / l)^nu K_nu(sqrt(2 nu) r / l), 1 at r = 0
    z = np.sqrt(2 * nu) * np.abs(d) / length_mm
    with np.errstate(invalid="ignore"):
        k = 2 ** (1 - nu) / special.gamma(nu) * z**nu * special.kv(nu, z)
    return np.where(z > 0, k, 1.0)


def test_the_matern_correlation_equals_its_bessel_form():
    from adaptive_cal.gaussian.kernels import correlation

    d = np.r_[0.0, np.geomspace(1e-6, 400, 50), -np.geomspace(1e-3, 400, 20)]
    np.testing.assert_allclose(correlation(d, 37.0, "m52"), _kernel(d, 37.0, "m52"),
                               rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="m32"):
        correlation(d, 37.0, "m32")


def _dense_axis(spline, t, length_mm, kernel="se", per_interval=600):
    # composite Simpson, its panels inside knot intervals (the cubic pieces meet at knots)
    n = per_interval * (len(spline.knots) - 1) + 1
    u = np.linspace(spline.knots[0], spline.knots[-1], n)
    w = np.where(np.arange(n) % 2 == 1, 4.0, 2.0) * (u[1] - u[0]) / 3
    w[[0, -1]] = (u[1] - u[0]) / 3
    m = spline.basis(u)
    mw = m * w[:, None]
    gram = mw.T @ m
    b_t = mw.T @ _kernel(u[:, None] - t[None, :], length_mm, kernel)
    big_b = mw.T @ _kernel(u[:, None] - u[None, :], length_mm, kernel) @ mw
    g_inv_m = np.linalg.solve(gram, spline.basis(t).T)
    a = np.einsum("kn,kn->n", g_inv_m, b_t)
    c = np.einsum("kn,kn->n", g_inv_m, big_b @ g_inv_m)
    return a, c, np.trace(np.linalg.solve(gram, big_b)) / spline.period


@pytest.mark.parametrize("ends", ["not_a_knot", "natural", "cyclic"])
@pytest.mark.parametrize("length_mm", [25.0, 80.0])
@pytest.mark.parametrize("kernel", ["se", "m52"])
def test_unresolved_form_variance_equals_a_dense_reference(ends, length_mm, kernel):
    surface = Surface.create(np.linspace(-225, 225, 5), np.linspace(-185, 185, 4), ends=ends)
    rng = np.random.default_rng(3)
    # scattered points and a grid (whose points share coordinates along each axis)
    gx, gy = np.meshgrid(np.linspace(-225, 225, 9), np.linspace(-185, 185, 7), indexing="ij")
    x = np.r_[rng.uniform(-225, 225, 40), gx.ravel()]
    y = np.r_[rng.uniform(-185, 185, 40), gy.ravel()]
    s = 0.01  # mm
    var, mean = unresolved_form_var(surface, s, length_mm, x, y, kernel=kernel)
    ax, cx, tx = _dense_axis(surface.sx, x, length_mm, kernel)
    ay, cy, ty = _dense_axis(surface.sy, y, length_mm, kernel)
    expected = np.maximum(s**2 * (1 - 2 * ax * ay + cx * cy), 0.0)
    assert var.shape == x.shape
    tol = (1e-7 if kernel == "se" else 1e-5) * s**2
    np.testing.assert_allclose(var, expected, rtol=0, atol=tol)
    assert mean == pytest.approx(max(0.0, s**2 * (1 - tx * ty)), abs=tol)
    # a short length scale leaves much of the form unresolved; a long one little, but for
    # cyclic ends, which cannot follow a form that differs at opposite edges
    if length_mm == 25.0:
        assert mean > 0.2 * s**2
    elif ends != "cyclic":
        assert mean < 0.2 * s**2
