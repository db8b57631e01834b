"""A small independent generator of open-world recordings for explain (issue 15, items 3, 5, 6).

Numpy only, written from ../shared/DESIGN.md's physics; it shares no code with
``adaptive_cal`` (not the simulator, the effect library or explain): it writes a cell file and
v1 recordings as text, and the caller reads them back with the ordinary readers, the way a real
recording reaches explain.

Cell: workplane x [-250, 250] mm, y [-200, 200] mm, robot base at (-700, -100) mm, one touch
every 4 s, probe noise stated 0.005 mm (the readings carry exactly that noise). Designs: a 16 x 8
grid taken as an S-path (rows along x, every other row reversed) or a column-wise serpentine
(columns along y, every other column reversed: the robot never reverses along x).

Effects (DESIGN.md): tilt a x + b y + c always; ``form`` a centred mix of bow (x^2, y^2) and
twist (x y); ``arm_sag`` s (r / 1 m)^p with r the distance from the base; ``reversal`` span/2 x the
direction of arrival along x; out of the library: ``ripple`` A sin(2 pi x / 50 mm + phase) and
``backlash_y`` an offset of +-b/2 by the direction of arrival along y. Size: the norm of the
pattern minus its least-squares plane over the touches, in noise sds ("k sigma").
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

NOISE_MM = 0.005
X_RANGE, Y_RANGE = (-250.0, 250.0), (-200.0, 200.0)
BASE = (-700.0, -100.0)
TOUCH_S = 4.0
NX, NY = 16, 8
KINDS = ("null", "form", "arm_sag", "reversal", "ripple", "backlash_y")

CELL_YAML = f"""name: open-world generator cell
workplane:
  x_mm: [{X_RANGE[0]:g}, {X_RANGE[1]:g}]
  y_mm: [{Y_RANGE[0]:g}, {Y_RANGE[1]:g}]
  edge_margin_mm: 0
robot:
  adapter: sim
  base_xy_mm: [{BASE[0]:g}, {BASE[1]:g}]
  touch_time_s: {TOUCH_S:g}
probe:
  adapter: sim
  zero_mm: 0.0
  noise_std_mm: {NOISE_MM:g}
simulation:
  effects: {{}}
  unknown: [tilt]
"""


def grid_path(columns: bool) -> tuple[np.ndarray, np.ndarray]:
    """Touches in the order taken: S-path along x rows, or serpentine along y columns."""
    xs = np.linspace(X_RANGE[0] + 10, X_RANGE[1] - 10, NX)
    ys = np.linspace(Y_RANGE[0] + 10, Y_RANGE[1] - 10, NY)
    if columns:
        x = np.repeat(xs, NY)
        y = np.concatenate([ys if c % 2 == 0 else ys[::-1] for c in range(NX)])
    else:
        x = np.concatenate([xs if r % 2 == 0 else xs[::-1] for r in range(NY)])
        y = np.repeat(ys, NX)
    return x, y


def arrival(v: np.ndarray) -> np.ndarray:
    """+1 / -1: moving +v / -v into the point (the first touch takes the first move's sign)."""
    step = np.sign(np.diff(v))
    out = np.zeros(v.size)
    last = 0.0
    for i, s in enumerate(step, start=1):
        last = s if s != 0 else last
        out[i] = last
    first = step[np.flatnonzero(step)[0]] if np.any(step) else 0.0
    out[0] = first
    return out


def _unplaned_norm(x, y, h) -> float:
    A = np.stack([x, y, np.ones_like(x)], 1)
    coef, *_ = np.linalg.lstsq(A, h, rcond=None)
    return float(np.linalg.norm(h - A @ coef))


def pattern(kind: str, rng: np.random.Generator, x, y) -> tuple[np.ndarray, dict]:
    """Unit-free shape of the effect at the touches and what was drawn."""
    u = (x - 0.5 * sum(X_RANGE)) / (0.5 * (X_RANGE[1] - X_RANGE[0]))
    v = (y - 0.5 * sum(Y_RANGE)) / (0.5 * (Y_RANGE[1] - Y_RANGE[0]))
    if kind == "form":
        w = rng.normal(size=3)
        return w[0] * u * u + w[1] * v * v + w[2] * u * v, {"weights": w.tolist()}
    if kind == "arm_sag":
        p = float(rng.choice([1.5, 2.0, 2.5]))
        r = np.hypot(x - BASE[0], y - BASE[1]) / 1000.0
        return r ** p, {"p": p}
    if kind == "reversal":
        return 0.5 * arrival(x), {}
    if kind == "ripple":
        phase = rng.uniform(0, 2 * np.pi)
        return np.sin(2 * np.pi * x / 50.0 + phase), {"wavelength_mm": 50.0}
    if kind == "backlash_y":
        return 0.5 * arrival(y), {}
    return np.zeros_like(x), {}


def recording(kind: str, rng: np.random.Generator, sigma: float = 10.0,
              columns: bool | None = None, shape_rng: np.random.Generator | None = None) -> dict:
    """One recording: readings, design and truth. ``columns``: the column-wise serpentine
    (default: only for backlash_y)."""
    columns = (kind == "backlash_y") if columns is None else columns
    x, y = grid_path(columns)
    n = x.size
    h = rng.normal(0, 1e-4) * x + rng.normal(0, 1e-4) * y + rng.normal(0, 0.1)
    shape, truth = pattern(kind, shape_rng or rng, x, y)  # shape_rng: rounds sharing one shape
    size = 0.0
    if kind != "null":
        norm = _unplaned_norm(x, y, shape)
        size = sigma * NOISE_MM / norm * (shape_rng or rng).choice([-1.0, 1.0])
        h = h + size * shape
    reading = h + NOISE_MM * rng.standard_normal(n)
    return {"kind": kind, "x": x, "y": y, "t": TOUCH_S * np.arange(n), "reading": reading,
            "scale_mm": float(size), "truth": truth, "columns": bool(columns)}


def write(directory: Path, case: dict, name: str = "rec.csv",
          stated_noise_mm: float = NOISE_MM) -> tuple[Path, Path]:
    """The cell file (stating ``stated_noise_mm`` as the probe noise) and the recording (v1 CSV)
    under ``directory``; returns their paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    cell = directory / "cell.yaml"
    cell.write_text(CELL_YAML.replace(f"noise_std_mm: {NOISE_MM:g}",
                                      f"noise_std_mm: {stated_noise_mm:g}"), encoding="utf-8")
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    lines += [f"{i},{t:.1f},{x:.3f},{y:.3f},0,{r:.6f}" for i, (t, x, y, r) in
              enumerate(zip(case["t"], case["x"], case["y"], case["reading"]))]
    rec = directory / name
    rec.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return cell, rec
