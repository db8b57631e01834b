"""The effect library: forward models of the physics a probe reading sees.

Names and parameters are a stable interface (DESIGN.md, "Names of physics effects"); the same
forward code drives the simulator and is the regressor that ``explain`` fits. Each effect maps
per-touch features to a change of the reading in mm (larger reading = surface higher):

======================  =====================================================================
tilt                    a x + b y + c  (a, b in mm/mm, c in mm)
form                    pv_mm x normalised shape (bow_x u^2, bow_y v^2, twist u v, warp u^2 v^2),
                        centred on the plate, peak-to-valley pv_mm over the workplane
thermal_drift           rate_mm_per_s t
reversal                span_mm / 2 x direction of arrival along x (+1 / -1)
arm_sag                 sag_mm_at_1m (r / 1 m)^p, r = horizontal distance from the robot base
probe_gain              gain x true displacement (reading = (1 + gain) displacement)
local_defect            height_mm cosine bell of radius_mm at (x_mm, y_mm)
======================  =====================================================================
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

EFFECT_NAMES = ("tilt", "form", "thermal_drift", "reversal", "arm_sag", "probe_gain",
                "local_defect")
PARAMS: dict[str, tuple[str, ...]] = {
    "tilt": ("a", "b", "c"),
    "form": ("pv_mm", "bow_x", "bow_y", "twist", "warp"),
    "thermal_drift": ("rate_mm_per_s",),
    "reversal": ("span_mm",),
    "arm_sag": ("sag_mm_at_1m", "p"),
    "probe_gain": ("gain",),
    "local_defect": ("x_mm", "y_mm", "height_mm", "radius_mm"),
}
DEFAULTS: dict[str, dict[str, float]] = {
    "tilt": {"a": 0.0, "b": 0.0, "c": 0.0},
    "form": {"pv_mm": 0.0, "bow_x": 0.0, "bow_y": 1.0, "twist": 0.0, "warp": 0.0},
    "thermal_drift": {"rate_mm_per_s": 0.0},
    "reversal": {"span_mm": 0.0},
    "arm_sag": {"sag_mm_at_1m": 0.0, "p": 2.0},
    "probe_gain": {"gain": 0.0},
    "local_defect": {"x_mm": 0.0, "y_mm": 0.0, "height_mm": 0.0, "radius_mm": 5.0},
}
SURFACE_EFFECTS = frozenset({"tilt", "form", "local_defect"})  # part of the plate itself


@dataclass(frozen=True)
class Geometry:
    """What the effects need to know about the cell (mm, workplane frame)."""

    x_range_mm: tuple[float, float]
    y_range_mm: tuple[float, float]
    base_xy_mm: tuple[float, float] | None = None  # robot base; needed by arm_sag


@dataclass(frozen=True)
class Features:
    """Per-touch inputs of the forward models; arrays of one length, NaN where unknown."""

    x_mm: np.ndarray
    y_mm: np.ndarray
    t_s: np.ndarray
    direction: np.ndarray  # +1 arriving moving +x, -1 moving -x, 0 unknown
    displacement_mm: np.ndarray  # the ideal indication (surface - z + probe zero)

    def reach_mm(self, geometry: Geometry) -> np.ndarray:
        if geometry.base_xy_mm is None:
            raise ValueError("arm_sag needs robot.base_xy_mm (the robot base position in the "
                             "workplane frame) in the cell file")
        bx, by = geometry.base_xy_mm
        return np.hypot(self.x_mm - bx, self.y_mm - by)


def form_basis(x_mm, y_mm, geometry: Geometry) -> np.ndarray:
    """Shape functions (bow_x, bow_y, twist, warp) in normalised coordinates u, v in [-1, 1]."""
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    u = (np.asarray(x_mm, float) - 0.5 * (x0 + x1)) / (0.5 * (x1 - x0))
    v = (np.asarray(y_mm, float) - 0.5 * (y0 + y1)) / (0.5 * (y1 - y0))
    return np.stack([u * u, v * v, u * v, u * u * v * v], axis=-1)


def form_height(x_mm, y_mm, params: Mapping[str, float], geometry: Geometry) -> np.ndarray:
    """Form height in mm: weighted shape, centred (zero mean over the plate), scaled to pv_mm."""
    w = np.array([params.get(k, DEFAULTS["form"][k]) for k in ("bow_x", "bow_y", "twist", "warp")])
    pv = float(params.get("pv_mm", 0.0))
    if pv == 0.0 or not np.any(w):
        return np.zeros(np.broadcast(np.asarray(x_mm), np.asarray(y_mm)).shape)
    g = np.linspace(0.0, 1.0, 101)
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    gx, gy = np.meshgrid(x0 + g * (x1 - x0), y0 + g * (y1 - y0), indexing="ij")
    ref = form_basis(gx, gy, geometry) @ w
    scale = pv / (ref.max() - ref.min())
    return (form_basis(x_mm, y_mm, geometry) @ w - ref.mean()) * scale


def _tilt(f, p, g):
    return p["a"] * f.x_mm + p["b"] * f.y_mm + p["c"]


def _form(f, p, g):
    return form_height(f.x_mm, f.y_mm, p, g)


def _drift(f, p, g):
    return p["rate_mm_per_s"] * np.nan_to_num(f.t_s, nan=0.0)


def _reversal(f, p, g):
    return 0.5 * p["span_mm"] * f.direction


def _sag(f, p, g):
    return p["sag_mm_at_1m"] * (f.reach_mm(g) / 1000.0) ** p["p"]


def _gain(f, p, g):
    return p["gain"] * f.displacement_mm


def _defect(f, p, g):
    d = np.hypot(f.x_mm - p["x_mm"], f.y_mm - p["y_mm"]) / p["radius_mm"]
    return p["height_mm"] * np.where(d < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, 1.0))), 0.0)


FORWARD: dict[str, Callable[[Features, Mapping[str, float], Geometry], np.ndarray]] = {
    "tilt": _tilt, "form": _form, "thermal_drift": _drift, "reversal": _reversal,
    "arm_sag": _sag, "probe_gain": _gain, "local_defect": _defect,
}


def complete_params(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """Defaults filled in; unknown effect or parameter names raise with the name."""
    if name not in FORWARD:
        raise KeyError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
    unknown = set(params) - set(PARAMS[name])
    if unknown:
        raise KeyError(f"effect {name!r} has no parameter(s) {sorted(unknown)}; "
                       f"it takes {', '.join(PARAMS[name])}")
    return {**DEFAULTS[name], **{k: float(v) for k, v in params.items()}}


def reading_change(name: str, params: Mapping[str, float], features: Features,
                   geometry: Geometry) -> np.ndarray:
    """Change of the reading in mm caused by one effect at each touch."""
    return np.asarray(FORWARD[name](features, complete_params(name, params), geometry), float)


def total_change(effects: Mapping[str, Mapping[str, float]], features: Features,
                 geometry: Geometry, *, only: frozenset[str] | None = None) -> np.ndarray:
    """Sum of the reading changes of several effects (``only`` restricts to a subset)."""
    out = np.zeros(np.shape(features.x_mm))
    for name, params in effects.items():
        if only is None or name in only:
            out = out + reading_change(name, params, features, geometry)
    return out


# -- regressors and Jacobians (used by ``explain`` and by beliefs that estimate effects) ----------
# Every effect is linear in some of its parameters once the others are fixed. The regressor R is
# built by calling the forward model itself at unit values of those parameters, so explain fits
# exactly the code the simulator runs: reading_change(name, params) = R(fixed) @ theta.

LINEAR_PARAMS: dict[str, tuple[str, ...]] = {
    "tilt": ("a", "b", "c"),
    "form": ("bow_x", "bow_y", "twist", "warp"),  # coefficients in mm, see form_params
    "thermal_drift": ("rate_mm_per_s",),
    "reversal": ("span_mm",),
    "arm_sag": ("sag_mm_at_1m",),
    "probe_gain": ("gain",),
    "local_defect": ("height_mm",),
}
NONLINEAR_PARAMS: dict[str, tuple[str, ...]] = {
    name: tuple(p for p in PARAMS[name] if p not in LINEAR_PARAMS[name] and p != "pv_mm")
    for name in EFFECT_NAMES
}


def _form_reference(geometry: Geometry) -> np.ndarray:
    """The 101 x 101 reference grid of the four form shapes, as ``form_height`` uses it."""
    g = np.linspace(0.0, 1.0, 101)
    (x0, x1), (y0, y1) = geometry.x_range_mm, geometry.y_range_mm
    gx, gy = np.meshgrid(x0 + g * (x1 - x0), y0 + g * (y1 - y0), indexing="ij")
    return form_basis(gx, gy, geometry).reshape(-1, 4)


def form_params(coefficients, geometry: Geometry) -> dict[str, float]:
    """Form parameters whose ``form_height`` equals ``effect_regressor('form') @ coefficients``.

    The coefficients (mm) become the shape weights and pv_mm = max - min of the weighted shape
    over the workplane, so the forward model's rescaling is the identity.
    """
    c = np.asarray(coefficients, float)
    ref = _form_reference(geometry) @ c
    out = {"pv_mm": float(ref.max() - ref.min())}
    out.update({k: float(v) for k, v in zip(LINEAR_PARAMS["form"], c)})
    return out


def form_pv_gradient(coefficients, geometry: Geometry) -> np.ndarray:
    """d pv_mm / d coefficients (for the delta-method standard deviation of pv_mm)."""
    ref = _form_reference(geometry)
    h = ref @ np.asarray(coefficients, float)
    return ref[int(np.argmax(h))] - ref[int(np.argmin(h))]


def effect_regressor(name: str, features: Features, geometry: Geometry,
                     fixed: Mapping[str, float] | None = None) -> np.ndarray:
    """Regressor R (touches x linear parameters): reading_change = R @ theta.

    theta are ``LINEAR_PARAMS[name]`` (form: the shape coefficients in mm); the nonlinear
    parameters (arm_sag p, local_defect x_mm, y_mm, radius_mm) are taken from ``fixed`` or the
    defaults. Columns are the forward model evaluated at unit parameter values.
    """
    fixed = dict(fixed or {})
    names = LINEAR_PARAMS[name]
    base = {k: v for k, v in complete_params(name, fixed).items() if k not in names}
    cols = []
    if name == "form":
        ref = _form_reference(geometry)
        for j, k in enumerate(names):
            w = {n: (1.0 if n == k else 0.0) for n in names}
            pv = float(ref[:, j].max() - ref[:, j].min())
            cols.append(reading_change(name, {**w, "pv_mm": pv}, features, geometry))
    else:
        for k in names:
            p = {**base, **{n: (1.0 if n == k else 0.0) for n in names}}
            cols.append(reading_change(name, p, features, geometry))
    return np.stack(cols, axis=-1)


def effect_jacobian(name: str, params: Mapping[str, float], features: Features,
                    geometry: Geometry, rel_step: float = 1e-6) -> np.ndarray:
    """d reading_change / d parameter (touches x PARAMS[name]) by central differences.

    Linearises an effect around ``params`` so its parameters can become states of a belief.
    """
    p0 = complete_params(name, params)
    cols = []
    for k in PARAMS[name]:
        h = rel_step * max(1.0, abs(p0[k]))
        up = reading_change(name, {**p0, k: p0[k] + h}, features, geometry)
        dn = reading_change(name, {**p0, k: p0[k] - h}, features, geometry)
        cols.append((up - dn) / (2.0 * h))
    return np.stack(cols, axis=-1)


def defect_regressor_grid(features: Features, x_mm, y_mm, radius_mm: float) -> np.ndarray:
    """local_defect regressor (unit height) for many centres at once: touches x centres.

    Calls the forward model with the centres broadcast against the touches (same code as
    ``reading_change('local_defect', ...)``, vectorised over a search grid).
    """
    f = Features(np.asarray(features.x_mm, float)[:, None], np.asarray(features.y_mm, float)[:, None],
                 features.t_s, features.direction, features.displacement_mm)
    p = {"x_mm": np.asarray(x_mm, float)[None, :], "y_mm": np.asarray(y_mm, float)[None, :],
         "height_mm": 1.0, "radius_mm": float(radius_mm)}
    return np.asarray(FORWARD["local_defect"](f, p, None), float)
