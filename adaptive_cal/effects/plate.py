"""Effects of the plate itself (part of the true surface): tilt, form, local_defect.

======================  =====================================================================
tilt                    a x + b y + c  (a, b in mm/mm, c in mm)
form                    pv_mm x normalised shape (bow_x u^2, bow_y v^2, twist u v, warp u^2 v^2),
                        centred on the plate, peak-to-valley pv_mm over the workplane
local_defect            height_mm cosine bell of radius_mm at (x_mm, y_mm)
======================  =====================================================================
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from adaptive_cal.effects.base import Effect, Features, Geometry, Param

FORM_SHAPES = ("bow_x", "bow_y", "twist", "warp")
DEFECT_RADII_MM = (15.0, 30.0, 60.0)


def _tilt(f, p, g):
    return p["a"] * f.x_mm + p["b"] * f.y_mm + p["c"]


tilt = Effect(
    "tilt", "plane not level", "a x + b y + c",
    (Param("a", "mm/mm", "slope along x", 0.0), Param("b", "mm/mm", "slope along y", 0.0),
     Param("c", "mm", "offset", 0.0)),
    _tilt, axis="position", surface=True)


# -- form -----------------------------------------------------------------------------------------

def form_basis(x_mm, y_mm, geometry: Geometry) -> np.ndarray:
    """Shape functions (bow_x, bow_y, twist, warp) in normalised coordinates u, v in [-1, 1]."""
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    u = (np.asarray(x_mm, float) - 0.5 * (x0 + x1)) / (0.5 * (x1 - x0))
    v = (np.asarray(y_mm, float) - 0.5 * (y0 + y1)) / (0.5 * (y1 - y0))
    return np.stack([u * u, v * v, u * v, u * u * v * v], axis=-1)


def _form_reference(geometry: Geometry) -> np.ndarray:
    """The 101 x 101 reference grid of the four form shapes over the workplane (rows x 4)."""
    g = np.linspace(0.0, 1.0, 101)
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    gx, gy = np.meshgrid(x0 + g * (x1 - x0), y0 + g * (y1 - y0), indexing="ij")
    return form_basis(gx, gy, geometry).reshape(-1, 4)


def form_height(x_mm, y_mm, params: Mapping[str, float], geometry: Geometry) -> np.ndarray:
    """Form height in mm: weighted shape, centred (zero mean over the plate), scaled to pv_mm."""
    w = np.array([params.get(k, form.defaults[k]) for k in FORM_SHAPES])
    pv = float(params.get("pv_mm", 0.0))
    if pv == 0.0 or not np.any(w):
        return np.zeros(np.broadcast(np.asarray(x_mm), np.asarray(y_mm)).shape)
    g = np.linspace(0.0, 1.0, 101)
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    gx, gy = np.meshgrid(x0 + g * (x1 - x0), y0 + g * (y1 - y0), indexing="ij")
    ref = form_basis(gx, gy, geometry) @ w
    scale = pv / (ref.max() - ref.min())
    return (form_basis(x_mm, y_mm, geometry) @ w - ref.mean()) * scale


def _form(f, p, g):
    return form_height(f.x_mm, f.y_mm, p, g)


def _form_columns(features: Features, geometry: Geometry) -> np.ndarray:
    """Regressor of the shape coefficients (mm): each shape centred, at its own pv (scale 1)."""
    ref = _form_reference(geometry)
    cols = []
    for j, k in enumerate(FORM_SHAPES):
        w = {n: (1.0 if n == k else 0.0) for n in FORM_SHAPES}
        pv = float(ref[:, j].max() - ref[:, j].min())
        cols.append(form.reading_change(features, {**w, "pv_mm": pv}, geometry))
    return np.stack(cols, axis=-1)


def form_params(coefficients, geometry: Geometry) -> dict[str, float]:
    """Form parameters whose ``form_height`` equals ``form.regressor(...) @ coefficients``.

    The coefficients (mm) become the shape weights and pv_mm = max - min of the weighted shape
    over the workplane, so the forward model's rescaling is the identity.
    """
    c = np.asarray(coefficients, float)
    ref = _form_reference(geometry) @ c
    out = {"pv_mm": float(ref.max() - ref.min())}
    out.update({k: float(v) for k, v in zip(FORM_SHAPES, c)})
    return out


def form_pv_gradient(coefficients, geometry: Geometry) -> np.ndarray:
    """d pv_mm / d coefficients (for the delta-method standard deviation of pv_mm)."""
    ref = _form_reference(geometry)
    h = ref @ np.asarray(coefficients, float)
    return ref[int(np.argmax(h))] - ref[int(np.argmin(h))]


def _form_derive(coefficients, geometry: Geometry) -> tuple[dict, dict]:
    return (form_params(coefficients, geometry),
            {"pv_mm": form_pv_gradient(coefficients, geometry)})


form = Effect(
    "form", "plate not flat: bow, twist, warp",
    "pv_mm x centred shape (bow_x u^2 + bow_y v^2 + twist u v + warp u^2 v^2)",
    (Param("pv_mm", "mm", "peak-to-valley over the workplane", 0.0, linear=False),
     Param("bow_x", "mm", "weight of u^2 (fitted: coefficient in mm)", 0.0, prior=(1e-3, 1.0)),
     Param("bow_y", "mm", "weight of v^2", 1.0, prior=(1e-3, 1.0)),
     Param("twist", "mm", "weight of u v", 0.0, prior=(1e-3, 1.0)),
     Param("warp", "mm", "weight of u^2 v^2", 0.0, prior=(1e-3, 1.0))),
    _form, axis="position", main="pv_mm", surface=True,
    columns=_form_columns, derived=("pv_mm",), derive=_form_derive)


# -- local defect ---------------------------------------------------------------------------------

def _defect(f, p, g):
    d = np.hypot(f.x_mm - p["x_mm"], f.y_mm - p["y_mm"]) / p["radius_mm"]
    return p["height_mm"] * np.where(d < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, 1.0))), 0.0)


def _centre_axes(geometry: Geometry, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    step = radius_mm / 4.0
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / step)) + 1))
    ys = np.linspace(y0, y1, max(2, int(np.ceil((y1 - y0) / step)) + 1))
    return xs, ys


def defect_centres(geometry: Geometry, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres searched for a defect of this radius: spacing radius / 4 over the workplane (fine
    enough that a bump centred between two touches, both inside its half-height contour, is
    on the grid)."""
    gx, gy = np.meshgrid(*_centre_axes(geometry, radius_mm), indexing="ij")
    return gx.ravel(), gy.ravel()


# Profiles a bump may have, unit height at d = 0 and zero from d = 1 (d: distance / radius_mm).
# The library's forward model is the cosine bell (smooth at its rim); a burr, chip or speck of
# dirt is not bound to it: a shallow spherical cap (a dome, h << r) is the paraboloid 1 - d^2,
# flat-topped beside the bell, and a cone 1 - d is peaked. Touches on a bump's flanks fix its
# half-height width, and the peak height extrapolated from them depends on the profile: for
# the same flank touches a dome's peak is lower than the bell's and a cone's higher, so a height
# reported under one profile is biased on the others by about as much as the flanks allow.
# explain's intervals average over these (``analysis.explain.averaging``); the value it reports
# stays the bell's, the model the simulator and the cell file use.
DEFECT_PROFILES = ("cosine_bell", "dome", "cone")


def defect_profile(d, profile: str = "cosine_bell") -> np.ndarray:
    """Unit-height profile at d = distance / radius (d >= 0), 0 from d = 1 (``DEFECT_PROFILES``)."""
    d = np.minimum(np.asarray(d, float), 1.0)
    if profile == "cosine_bell":
        return 0.5 * (1.0 + np.cos(np.pi * d))
    if profile == "dome":
        return 1.0 - d * d
    if profile == "cone":
        return 1.0 - d
    raise ValueError(f"unknown bump profile {profile!r}; known: {', '.join(DEFECT_PROFILES)}")


def defect_regressor_grid(features: Features, x_mm, y_mm, radius_mm: float,
                          profile: str = "cosine_bell") -> np.ndarray:
    """local_defect regressor (unit height) for many centres at once: touches x centres.

    The forward model (``local_defect.reading_change``) with the centres broadcast against the
    touches; the cosine is taken only inside the bell, where it is not zero (a search grid of
    thousands of centres over thousands of touches is mostly outside it). ``profile``: another
    of ``DEFECT_PROFILES`` in the bell's place.
    """
    dx = np.asarray(features.x_mm, float)[:, None] - np.asarray(x_mm, float)[None, :]
    dy = np.asarray(features.y_mm, float)[:, None] - np.asarray(y_mm, float)[None, :]
    d2 = dx * dx + dy * dy
    r = float(radius_mm)
    inside = d2 < r * r
    out = np.zeros(d2.shape)
    if profile == "cosine_bell":
        out[inside] = 0.5 * (1.0 + np.cos(np.pi * np.sqrt(d2[inside]) / r))
    else:
        out[inside] = defect_profile(np.sqrt(d2[inside]) / r, profile)
    return out


def defect_regressor_sparse(features: Features, geometry: Geometry, radius_mm: float,
                            chunk: int = 4096):
    """``defect_regressor_grid`` at every centre of ``defect_centres(geometry, radius_mm)``, as a
    sparse (scipy COO) touches x centres matrix with only the touches inside each bell stored:
    the same values, computed the same way, for the few centres near each touch (a window of
    the centre grid), so 100,000 touches cost the bells' few million entries."""
    from scipy import sparse

    xs, ys = _centre_axes(geometry, radius_mm)
    fx, fy = np.asarray(features.x_mm, float), np.asarray(features.y_mm, float)
    r = float(radius_mm)
    rows, cols, vals = [], [], []

    def window(f, axis):  # per touch: the centre indices that can lie within r, and f - centre
        step = (axis[-1] - axis[0]) / (axis.size - 1)
        lo = np.floor((f - r - axis[0]) / step).astype(int) - 1
        idx = lo[:, None] + np.arange(int(np.ceil(2.0 * r / step)) + 4)[None, :]
        ok = (idx >= 0) & (idx < axis.size)
        diff = f[:, None] - axis[np.clip(idx, 0, axis.size - 1)]
        return idx, np.where(ok, diff * diff, np.inf)

    for s in range(0, fx.size, chunk):
        ix, dx2 = window(fx[s:s + chunk], xs)
        iy, dy2 = window(fy[s:s + chunk], ys)
        d2 = dx2[:, :, None] + dy2[:, None, :]  # as the dense form computes it: the same values
        t, a, b = np.nonzero(d2 < r * r)
        v = 0.5 * (1.0 + np.cos(np.pi * np.sqrt(d2[t, a, b]) / r))
        nz = v != 0.0
        rows.append(s + t[nz]), cols.append(ix[t, a][nz] * ys.size + iy[t, b][nz])
        vals.append(v[nz])
    cat = lambda parts, dtype: np.concatenate(parts) if parts else np.zeros(0, dtype)
    return sparse.coo_matrix((cat(vals, float), (cat(rows, int), cat(cols, int))),
                             shape=(fx.size, xs.size * ys.size))


def _defect_grid(features: Features, geometry: Geometry) -> dict[str, np.ndarray]:
    """radius_mm on DEFECT_RADII_MM; the centres follow from the radius (``defect_centres``)."""
    return {"radius_mm": np.asarray(DEFECT_RADII_MM)}


local_defect = Effect(
    "local_defect", "burr, chip, dirt: a bump confined to a small area",
    "height_mm x cosine bell of radius_mm at (x_mm, y_mm)",
    (Param("x_mm", "mm", "centre x", 0.0, linear=False),
     Param("y_mm", "mm", "centre y", 0.0, linear=False),
     Param("height_mm", "mm", "height of the bump (positive: surface higher)", 0.0,
           prior=(1e-3, 1.0)),
     Param("radius_mm", "mm", "radius where the bump ends", 5.0, linear=False)),
    _defect, axis="position", main="height_mm", grid=_defect_grid,
    searched=("height_mm",), surface=True,
    grid_text="radius_mm uniform on {15, 30, 60}; centre uniform on a grid of spacing radius / 4, "
    "conditioned on the bump reaching at least two touches with >= 1/4 of its height, none carrying > 3/4 of its sum of squares")
