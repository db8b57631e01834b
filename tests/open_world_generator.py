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
# added for the calibration benchmark (benchmarks/bench_explain_calib.py); the kinds above keep
# their output: the new branches draw from the generator only when they are asked for
CALIBRATION_KINDS = ("bow", "local_defect", "thermal_drift", "warmup")

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
    if kind == "bow":  # a bow along x or y (or both), no twist: the reference cell's shape
        w = rng.normal(size=2)
        return w[0] * u * u + w[1] * v * v, {"weights": [float(w[0]), float(w[1]), 0.0]}
    if kind == "local_defect":  # cosine bell, radius 25-60 mm
        for _ in range(1000):  # a bump two touches see well: at least two carry a quarter of
            # its height and none more than half of its sum of squares (one touch: a spike)
            radius = float(rng.uniform(25.0, 60.0))
            cx = float(rng.uniform(x.min() + 0.5 * radius, x.max() - 0.5 * radius))
            cy = float(rng.uniform(y.min() + 0.5 * radius, y.max() - 0.5 * radius))
            d = np.hypot(x - cx, y - cy) / radius
            bell = np.where(d < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, 1.0))), 0.0)
            w2 = bell * bell
            if np.count_nonzero(bell >= 0.25) >= 2 and w2.max() <= 0.5 * w2.sum():
                break
        return bell, {"x_mm": cx, "y_mm": cy, "radius_mm": radius}
    if kind == "thermal_drift":  # a linear drift: reading change rate x t
        return TOUCH_S * np.arange(x.size), {}
    if kind == "warmup":  # an exponential approach, time constant a tenth to a half of the run
        run = TOUCH_S * max(x.size - 1, 1)
        tau = float(rng.uniform(0.1, 0.5)) * run
        return -np.expm1(-TOUCH_S * np.arange(x.size) / tau), {"tau_s": tau}
    return np.zeros_like(x), {}


def pattern_truth(kind: str, case: dict) -> dict:
    """The parameters of a case in DESIGN.md's effect table (names, units and signs), from the
    drawn shape and its scale: form pv_mm over the workplane, arm_sag sag_mm_at_1m and p,
    reversal span_mm, local_defect height_mm (and centre, radius), thermal_drift rate_mm_per_s
    or amplitude_mm and tau_s."""
    s, t = case["scale_mm"], case["truth"]
    if kind in ("form", "bow"):
        g = np.linspace(-1.0, 1.0, 201)
        u, v = np.meshgrid(g, g, indexing="ij")
        w = t["weights"]
        h = s * (w[0] * u * u + w[1] * v * v + w[2] * u * v)
        return {"pv_mm": float(h.max() - h.min())}
    if kind == "arm_sag":
        return {"sag_mm_at_1m": s, "p": t["p"]}
    if kind == "reversal":
        return {"span_mm": s}
    if kind == "local_defect":
        return {"height_mm": s, **t}
    if kind == "thermal_drift":
        return {"rate_mm_per_s": s}
    if kind == "warmup":
        return {"amplitude_mm": s, "tau_s": t["tau_s"]}
    return {}


def random_path(rng: np.random.Generator, n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """n touches uniform over the workplane (10 mm in from its edge), taken in a greedy
    nearest-neighbour order from the first."""
    x = rng.uniform(X_RANGE[0] + 10, X_RANGE[1] - 10, n)
    y = rng.uniform(Y_RANGE[0] + 10, Y_RANGE[1] - 10, n)
    order, left = [0], list(range(1, n))
    while left:
        j = min(left, key=lambda i: (x[i] - x[order[-1]]) ** 2 + (y[i] - y[order[-1]]) ** 2)
        order.append(j), left.remove(j)
    return x[order], y[order]


def recording(kind: str, rng: np.random.Generator, sigma: float = 10.0,
              columns: bool | None = None, shape_rng: np.random.Generator | None = None,
              xy: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """One recording: readings, design and truth. ``columns``: the column-wise serpentine
    (default: only for backlash_y); ``xy``: the touches in the order taken, instead of a grid."""
    columns = (kind == "backlash_y") if columns is None else columns
    x, y = grid_path(columns) if xy is None else (np.asarray(xy[0], float),
                                                   np.asarray(xy[1], float))
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
