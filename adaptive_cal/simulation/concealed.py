"""Recordings where one effect hides: the proof set for ``explain`` (pure; randomness passed in).

Each recording is a tilted plate (random tilt, offset and noise) on a design where the effect is
hard to see -- drift on an S-path, reversal on a serpentine at noise level, a warm-up (``warm_up``), gain with varied
approach heights, a burr between grid lines, sag with reach, plate form -- or a null with no
effect. The readings come from the effect library's forward models (the simulator's code):

    reading = zero - z + tilt + [form, defect] + [drift, reversal, sag, gain] + noise.

The magnitude is set by the *non-absorbed norm*: the effect's change of the readings after the
least-squares tilt (a x + b y + c) is projected out, sqrt(sum of squares) / sigma.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from adaptive_cal import effects
from adaptive_cal.cell.schema import Cell, parse_cell
from adaptive_cal.formats.recording import Recording

EFFECTS = ("form", "thermal_drift", "reversal", "arm_sag", "probe_gain", "local_defect")
WORKPLANE = {"x_mm": (-225.0, 225.0), "y_mm": (-185.0, 185.0)}
BASE_XY_MM = (0.0, -650.0)
ZERO_MM = 5.0
DEFECT_RADII = (30.0, 60.0)


@dataclass(frozen=True)
class Concealed:
    """A generated recording, its cell, and the truth."""

    recording: Recording
    cell: Cell
    effect: str  # "none" for a null
    params: dict
    nonabsorbed_sigma: float
    noise_std_mm: float


def generator_cell(base_xy_mm=BASE_XY_MM) -> Cell:
    """The cell the generated recordings belong to: nominal = rigid tilted plane, tilt unknown."""
    return parse_cell({
        "name": "concealed-effect generator",
        "workplane": {**{k: list(v) for k, v in WORKPLANE.items()}, "edge_margin_mm": 0},
        "robot": {"adapter": "sim", "base_xy_mm": list(base_xy_mm) if base_xy_mm else None,
                  "touch_time_s": 4},
        "probe": {"adapter": "sim", "zero_mm": ZERO_MM},
        "simulation": {"effects": {}, "unknown": ["tilt"]},
    }, "generator cell")


def serpentine(nx: int, ny: int, *, raster: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Grid touches in S-path order (rows along x, every other row reversed) or raster order."""
    (x0, x1), (y0, y1) = WORKPLANE["x_mm"], WORKPLANE["y_mm"]
    xs = np.linspace(x0, x1, nx + 1)[:-1] + 0.5 * (x1 - x0) / nx
    ys = np.linspace(y0, y1, ny + 1)[:-1] + 0.5 * (y1 - y0) / ny
    x = np.concatenate([xs[::-1] if (j % 2 and not raster) else xs for j in range(ny)])
    return x, np.repeat(ys, nx)


def _direction(x: np.ndarray) -> np.ndarray:
    d = np.zeros(x.size)
    last = 0.0
    for i in range(1, x.size):
        step = x[i] - x[i - 1]
        last = 1.0 if step > 1e-9 else (-1.0 if step < -1e-9 else last)
        d[i] = last
    return d


def _tilt_projector(x, y):
    A = np.stack([x, y, np.ones_like(x)], 1)
    q, _ = np.linalg.qr(A)
    return lambda v: v - q @ (q.T @ v)


def _shape(effect: str, rng, feats: effects.Features, geom: effects.Geometry, grid_xy,
           warm_up: float | None = None):
    """Unit-amplitude parameters of the effect (the amplitude parameter is scaled later)."""
    if effect == "thermal_drift" and warm_up is not None:
        return {"amplitude_mm": 1.0, "tau_s": float(warm_up * feats.t_s.max())}, "amplitude_mm"
    if effect == "form":
        w = rng.standard_normal(4)
        return {"pv_mm": 1.0, **dict(zip(("bow_x", "bow_y", "twist", "warp"), w))}, "pv_mm"
    if effect == "thermal_drift":
        return {"rate_mm_per_s": 1.0}, "rate_mm_per_s"
    if effect == "reversal":
        return {"span_mm": 1.0}, "span_mm"
    if effect == "arm_sag":
        return {"sag_mm_at_1m": 1.0, "p": float(rng.uniform(1.2, 2.8))}, "sag_mm_at_1m"
    if effect == "probe_gain":
        return {"gain": 1.0}, "gain"
    if effect == "local_defect":
        gx, gy = grid_xy
        for _ in range(200):  # a centre between grid lines, within 0.6 radius of 2+ touches
            radius = float(rng.choice(DEFECT_RADII))
            i = rng.integers(len(gx) - 1)
            cx = 0.5 * (gx[i] + gx[i + 1]) + rng.uniform(-5, 5)
            cy = float(rng.uniform(*WORKPLANE["y_mm"]))
            if np.sum(np.hypot(feats.x_mm - cx, feats.y_mm - cy) < 0.6 * radius) >= 2:
                break
        return {"x_mm": float(cx), "y_mm": cy, "height_mm": 1.0, "radius_mm": radius}, "height_mm"
    raise KeyError(effect)


def concealed_recording(effect: str, rng: np.random.Generator, *, nonabsorbed_sigma: float = 4.0,
                        nx: int = 10, ny: int | None = None, noise_std_mm: float | None = None,
                        raster: bool = False, varied_z: bool | None = None,
                        seconds_per_touch: float = 4.0, warm_up: float | None = None) -> Concealed:
    """One recording with ``effect`` ('none' for a null) hidden at the given non-absorbed norm.

    ``warm_up``: for thermal_drift, an exponential warm-up amplitude_mm (1 - exp(-t / tau_s))
    with tau_s this share of the run's duration, instead of a linear rate.
    """
    ny = ny if ny is not None else (6 if effect == "local_defect" else 4)
    varied_z = (effect == "probe_gain") if varied_z is None else varied_z
    sigma = float(rng.uniform(0.002, 0.008)) if noise_std_mm is None else float(noise_std_mm)
    cell = generator_cell()
    geom = cell.geometry
    x, y = serpentine(nx, ny, raster=raster)
    n = x.size
    t = seconds_per_touch * np.arange(n) + rng.uniform(0, 0.5, n).cumsum()
    z = rng.uniform(-2.0, 2.0, n) if varied_z else np.zeros(n)
    tilt = {"a": float(rng.normal(0, 0.01)), "b": float(rng.normal(0, 0.01)),
            "c": float(rng.normal(0, 0.2))}
    d = _direction(x)
    f0 = effects.Features(x, y, t, d, np.zeros(n))
    surface = {"tilt": tilt}
    others: dict = {}
    params: dict = {}
    achieved = 0.0
    if effect != "none":
        shape, amp = _shape(effect, rng, f0, geom, (np.unique(x), np.unique(y)), warm_up)
        if effects.get(effect).surface:
            unit = effects.reading_change(effect, shape, f0, geom)
        else:
            ideal = ZERO_MM - z + effects.total_change(surface, f0, geom)
            f1 = effects.Features(x, y, t, d, ideal)
            unit = effects.reading_change(effect, shape, f1, geom)
        norm = float(np.linalg.norm(_tilt_projector(x, y)(unit)))
        scale = nonabsorbed_sigma * sigma / norm if norm > 0 else 0.0
        if effect != "form":
            scale *= float(rng.choice([-1.0, 1.0]))
        params = {**shape, amp: shape[amp] * scale}
        (surface if effects.get(effect).surface else others)[effect] = params
        achieved = abs(scale) * norm / sigma
    ideal = ZERO_MM - z + effects.total_change(surface, f0, geom)
    f = effects.Features(x, y, t, d, ideal)
    reading = ideal + effects.total_change(others, f, geom) + sigma * rng.standard_normal(n)
    reading = np.round(reading / 1e-4) * 1e-4
    rec = Recording(np.arange(n), t, x, y, z, reading, path=f"concealed-{effect}")
    return Concealed(rec, cell, effect, params, achieved, sigma)
