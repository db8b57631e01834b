"""An independent generator of recordings and cell files for ``explain`` (issue 15, item 7).

Written from ../shared/DESIGN.md only (the effect table, the ``tau_s`` warm-up, the recording
format v1) and numpy; it imports nothing from ``adaptive_cal`` and shares no code with its
simulator, effect library or explain (tests/test_explain_indep.py checks the imports). It writes
a cell YAML and v1 recordings as text; the benchmark reads them back with the ordinary readers.

Cell. Workplane x [-225, 225] mm, y [-185, 185] mm (the reference cell's), robot base at
(-700, -50) mm, one touch every ``TOUCH_S`` = 4 s (t_s = seq x 4 s, per round from 0), constant
approach height z = 0, probe zero 5 mm, ``simulation.unknown: [tilt]``. The readings carry
Gaussian noise of sd ``noise_mm`` (3-15 um, drawn per case) and the cell states it as
``probe.noise_std_mm``; every third case also states ``noise_range_mm`` [0.7, 1.4] x sd.
Off-centre plates: workplane x [150, 600] mm, y [-350, 20] mm; small plates 150 x 100 mm.
Every round has its own tilt a x + b y + c (a, b ~ N(0, 2e-3), c ~ N(0, 0.2 mm)), unknown to
explain.

Designs (touches in the order taken, ``design``): ``s_path`` a 12 x 6 grid, rows along x, every
other row reversed; ``raster`` the same grid, every row taken moving +x (the first touch of a
row arrives moving -x, from the previous row's end); ``columns`` a column-wise serpentine
(columns along y, every other column reversed: x never reverses); ``random`` 72 touches uniform
over the plate inside a 10 mm margin, in the order drawn; ``edge`` 72 touches, 54 on two
rectangular rings (10 mm and 50 mm inside the edge) taken around each ring, 18 uniform inside.

Physics (DESIGN.md's table, in reading units: a reading is larger when the surface is higher):
``form`` bow (u^2 or v^2), twist (u v) or a random mix of the three, u, v in [-1, 1] over the
workplane, truth ``pv_mm`` = max - min of that shape over the workplane (a 201 x 201 grid,
corners included); ``arm_sag`` s (r / 1 m)^p, r the horizontal distance from the base, p drawn
from {1.5, 2, 2.5}; ``reversal`` span / 2 x the direction of arrival along x (the sign of the
last non-zero x move; the first touch arrives moving +x); ``thermal_drift`` linear rate x t, or
the warm-up A (1 - exp(-t / tau_s)), tau_s a third of the run; ``local_defect`` a parabolic cap
h (1 - (d / R)^2) for d < R (its own profile, not the library's cosine bell; explain's height
interval averages over a dome, the bell and a cone since 2026-11-23), centred between a touch and one
of its 4 nearest neighbours (drawn at random: along a row or across rows) so that it reaches
both. Out of the library: ``backlash_y`` +-b/2 by the direction of arrival along y; ``ripple``
A sin(2 pi x / 50 mm + phase).
Bad readings (nulls): Student-t (3 dof) noise scaled to sd ``noise_mm``; 1-3 gross outliers of
+-(15-50) sd; one spike of +-(6-10) sd.

"k sigma" (``scale``): the pattern g at the touches (all rounds stacked) is scaled so that
||g - P g|| = k x noise_mm, where P g is the least-squares tilt a x + b y + c of g fitted to
each round separately over that round's touches (explain's nuisance). Two effects at once:
each at k sigma on its own.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

TOUCH_S = 4.0
BASE = (-700.0, -50.0)
PLATES = {"standard": ((-225.0, 225.0), (-185.0, 185.0)),
          "off_centre": ((150.0, 600.0), (-350.0, 20.0)),
          "small": ((-75.0, 75.0), (-50.0, 50.0))}
DESIGNS = ("s_path", "raster", "columns", "random", "edge")
NX, NY = 12, 6
MARGIN = 10.0
DEFECT_NEIGHBOURS = 4  # a bump lies between a touch and one of its 4 nearest (both axes on a grid)


@dataclass
class Case:
    """One generated case: its recordings (one per round) and what was put in."""

    family: str
    truth: dict
    design: str
    plate: str
    noise_mm: float
    noise_range: bool
    rounds: list[dict] = field(default_factory=list)  # x, y, t, reading arrays per round
    suspects: list[tuple[int, int]] = field(default_factory=list)  # (round, seq) of bad readings


# -- designs --------------------------------------------------------------------------------------

def _grid(xr, yr, nx=NX, ny=NY):
    return (np.linspace(xr[0] + MARGIN, xr[1] - MARGIN, nx),
            np.linspace(yr[0] + MARGIN, yr[1] - MARGIN, ny))


def touches(design: str, plate: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Touch positions (mm) in the order taken."""
    xr, yr = PLATES[plate]
    nx, ny = (8, 4) if plate == "small" else (NX, NY)
    xs, ys = _grid(xr, yr, nx, ny)
    if design in ("s_path", "raster"):
        rows = [xs if (design == "raster" or r % 2 == 0) else xs[::-1] for r in range(ny)]
        return np.concatenate(rows), np.repeat(ys, nx)
    if design == "columns":
        cols = [ys if c % 2 == 0 else ys[::-1] for c in range(nx)]
        return np.repeat(xs, ny), np.concatenate(cols)
    n = nx * ny
    lo = np.array([xr[0] + MARGIN, yr[0] + MARGIN])
    hi = np.array([xr[1] - MARGIN, yr[1] - MARGIN])
    if design == "random":
        p = rng.uniform(lo, hi, size=(n, 2))
        return p[:, 0], p[:, 1]
    if design == "edge":
        pts = []
        inset2 = min(50.0, 0.3 * min(xr[1] - xr[0], yr[1] - yr[0]))
        for inset, k in ((0.0, n * 5 // 12), (inset2 - MARGIN, n * 4 // 12)):
            a, b = lo + inset, hi - inset
            per = 2 * ((b - a).sum())
            s = np.arange(k) * per / k  # arc length around the ring
            w, h = b - a
            for si in s:
                if si < w:
                    pts.append((a[0] + si, a[1]))
                elif si < w + h:
                    pts.append((b[0], a[1] + si - w))
                elif si < 2 * w + h:
                    pts.append((b[0] - (si - w - h), b[1]))
                else:
                    pts.append((a[0], b[1] - (si - 2 * w - h)))
        inner_lo, inner_hi = lo + inset2, hi - inset2
        pts += list(rng.uniform(inner_lo, inner_hi, size=(n - len(pts), 2)))
        p = np.asarray(pts)
        return p[:, 0], p[:, 1]
    raise ValueError(f"unknown design {design!r}; known: {', '.join(DESIGNS)}")


def arrival(v: np.ndarray, first: float = 1.0) -> np.ndarray:
    """+1 / -1: direction of arrival along this axis (sign of the last non-zero move)."""
    out = np.empty(v.size)
    last = first
    for i in range(v.size):
        if i > 0 and v[i] != v[i - 1]:
            last = 1.0 if v[i] > v[i - 1] else -1.0
        out[i] = last
    return out


# -- physics (unit-free patterns; the size follows from k sigma) ---------------------------------

def _uv(x, y, plate):
    (x0, x1), (y0, y1) = PLATES[plate]
    return (2 * x - (x0 + x1)) / (x1 - x0), (2 * y - (y0 + y1)) / (y1 - y0)


def form_weights(kind: str, rng: np.random.Generator) -> np.ndarray:
    """Weights of (u^2, v^2, u v) for a bow, a twist or a mix."""
    if kind == "bow":
        return np.array([1.0, 0.0, 0.0]) if rng.random() < 0.5 else np.array([0.0, 1.0, 0.0])
    if kind == "twist":
        return np.array([0.0, 0.0, 1.0])
    return rng.normal(size=3)


def form_shape(w, x, y, plate):
    u, v = _uv(x, y, plate)
    return w[0] * u * u + w[1] * v * v + w[2] * u * v


def form_pv(w, plate) -> float:
    """Peak-to-valley of the shape over the whole workplane (unit weights scale)."""
    (x0, x1), (y0, y1) = PLATES[plate]
    gx, gy = np.meshgrid(np.linspace(x0, x1, 201), np.linspace(y0, y1, 201))
    s = form_shape(w, gx, gy, plate)
    return float(s.max() - s.min())


def defect_place(x, y, rng) -> tuple[float, float, float]:
    """Centre and radius of a bump reaching a touch and one of its ``DEFECT_NEIGHBOURS`` nearest
    neighbours (drawn at random). A burr sits anywhere: on a grid design the nearest neighbour
    alone is always along the row, which put every bump's centre on a touch row."""
    i = int(rng.integers(x.size))
    d = np.hypot(x - x[i], y - y[i])
    d[i] = np.inf
    j = int(rng.choice(np.argsort(d, kind="stable")[:DEFECT_NEIGHBOURS]))
    f = rng.uniform(0.3, 0.7)
    cx, cy = x[i] + f * (x[j] - x[i]), y[i] + f * (y[j] - y[i])
    radius = float(np.clip(rng.uniform(1.3, 2.0) * d[j] * max(f, 1 - f), 15.0, 90.0))
    return float(cx), float(cy), radius


def pattern(effect: str, rng, rounds: list[dict], plate: str, shared: dict | None = None):
    """Unit-size pattern per round (list of arrays) and the truth's shape parameters."""
    shared = {} if shared is None else shared
    out, truth = [], {}
    if effect.startswith("form"):
        w = shared.setdefault("w", form_weights(effect.split(":")[1], rng))
        truth = {"form_kind": effect.split(":")[1], "weights": [float(v) for v in w],
                 "unit_pv_mm": form_pv(w, plate)}
        out = [form_shape(w, r["x"], r["y"], plate) for r in rounds]
    elif effect == "arm_sag":
        p = shared.setdefault("p", float(rng.choice([1.5, 2.0, 2.5])))
        truth = {"p": p}
        out = [(np.hypot(r["x"] - BASE[0], r["y"] - BASE[1]) / 1000.0) ** p for r in rounds]
    elif effect == "reversal":
        out = [0.5 * arrival(r["x"]) for r in rounds]
    elif effect == "backlash_y":
        out = [0.5 * arrival(r["y"]) for r in rounds]
    elif effect == "thermal_drift":
        out = [r["t"].copy() for r in rounds]
    elif effect == "warmup":
        tau = shared.setdefault("tau", (rounds[0]["t"][-1] + TOUCH_S) / 3.0)
        truth = {"tau_s": float(tau)}
        out = [-np.expm1(-r["t"] / tau) for r in rounds]
    elif effect == "local_defect":
        cx, cy, rad = shared.setdefault("defect", defect_place(rounds[0]["x"], rounds[0]["y"], rng))
        truth = {"x_mm": cx, "y_mm": cy, "radius_mm": rad}
        out = [np.clip(1.0 - (np.hypot(r["x"] - cx, r["y"] - cy) / rad) ** 2, 0.0, None)
               for r in rounds]
    elif effect == "ripple":
        ph = shared.setdefault("phase", float(rng.uniform(0, 2 * np.pi)))
        truth = {"wavelength_mm": 50.0, "phase_rad": ph}
        out = [np.sin(2 * np.pi * r["x"] / 50.0 + ph) for r in rounds]
    else:
        raise ValueError(f"unknown effect {effect!r}")
    return out, truth


def detilted_norm(pats: list[np.ndarray], rounds: list[dict]) -> float:
    """||g - P g||: the pattern less its least-squares tilt, fitted per round over the touches."""
    ss = 0.0
    for g, r in zip(pats, rounds):
        A = np.stack([r["x"], r["y"], np.ones_like(r["x"])], 1)
        coef, *_ = np.linalg.lstsq(A, g, rcond=None)
        ss += float(np.sum((g - A @ coef) ** 2))
    return float(np.sqrt(ss))


# the truth's size parameter in DESIGN.md's names, per unit scale of the pattern
SIZE_NAME = {"form": "pv_mm", "arm_sag": "sag_mm_at_1m", "reversal": "span_mm",
             "thermal_drift": "rate_mm_per_s", "warmup": "amplitude_mm",
             "local_defect": "height_mm", "backlash_y": "span_y_mm", "ripple": "amplitude_mm"}
LIBRARY_NAME = {"warmup": "thermal_drift"}


def generate(family: str, effects: tuple[str, ...], sigma: float, design: str, rng,
             plate: str = "standard", n_rounds: int = 1, noise: str = "gauss") -> Case:
    """One case. ``effects``: pattern names (``form:bow``/``form:twist``/``form:mixed``,
    ``arm_sag``, ``reversal``, ``thermal_drift``, ``warmup``, ``local_defect``, ``backlash_y``,
    ``ripple``), each at ``sigma`` k sigma; ``noise``: gauss, student_t, outliers or spike."""
    noise_mm = float(rng.uniform(0.003, 0.015))
    x, y = touches(design, plate, rng)
    t = TOUCH_S * np.arange(x.size)
    rounds = []
    for _ in range(n_rounds):
        a, b, c = rng.normal(0, 2e-3), rng.normal(0, 2e-3), rng.normal(0, 0.2)
        rounds.append({"x": x, "y": y, "t": t, "reading": 5.0 + a * x + b * y + c})
    truth: dict = {"effects": []}
    for eff in effects:
        pats, shape = pattern(eff, rng, rounds, plate)
        sign = float(rng.choice([-1.0, 1.0]))
        visible = detilted_norm(pats, rounds)
        if visible < 1e-9 * np.sqrt(sum(float(g @ g) for g in pats)):
            raise ValueError(f"{eff} on the {design} design is a plane in x, y: the tilt "
                             "absorbs it (no k sigma can be defined)")
        scale = sign * sigma * noise_mm / visible
        for r, g in zip(rounds, pats):
            r["reading"] = r["reading"] + scale * g
        base = eff.split(":")[0]
        entry = {"effect": LIBRARY_NAME.get(base, base), "pattern": eff, "k_sigma": sigma,
                 **{k: v for k, v in shape.items() if k not in ("unit_pv_mm", "weights")}}
        if base == "form":
            entry["weights_mm"] = [scale * w for w in shape["weights"]]
            entry["pv_mm"] = abs(scale) * shape["unit_pv_mm"]
        elif base == "reversal":
            entry["span_mm"] = scale  # +x arrival minus -x arrival = scale (pattern +-1/2)
        elif base == "backlash_y":
            entry["span_y_mm"] = scale
        else:
            entry[SIZE_NAME[base]] = scale
        truth["effects"].append(entry)
    case = Case(family, truth, design, plate, noise_mm, bool(rng.integers(3) == 0), rounds)
    for k, r in enumerate(rounds):
        n = r["x"].size
        if noise == "student_t":
            e = rng.standard_t(3, n) / np.sqrt(3.0)
        else:
            e = rng.standard_normal(n)
        if noise == "outliers":
            for i in rng.choice(n, int(rng.integers(1, 4)), replace=False):
                e[i] += rng.choice([-1, 1]) * rng.uniform(15, 50)
                case.suspects.append((k, int(i)))
        if noise == "spike" and k == 0:
            i = int(rng.integers(n))
            e[i] = rng.choice([-1, 1]) * rng.uniform(6, 10)
            case.suspects.append((k, i))
        r["reading"] = r["reading"] + noise_mm * e
    truth["noise_mm"] = noise_mm
    return case


def cell_yaml(case: Case) -> str:
    """The cell file (text) that reaches explain with this case's recordings."""
    (x0, x1), (y0, y1) = PLATES[case.plate]
    noise = f"  noise_std_mm: {case.noise_mm:.6f}\n"
    if case.noise_range:
        noise += f"  noise_range_mm: [{0.7 * case.noise_mm:.6f}, {1.4 * case.noise_mm:.6f}]\n"
    return (f"name: independent explain benchmark ({case.family})\n"
            f"workplane:\n  x_mm: [{x0:g}, {x1:g}]\n  y_mm: [{y0:g}, {y1:g}]\n"
            f"  edge_margin_mm: 0\n"
            f"robot:\n  adapter: sim\n  base_xy_mm: [{BASE[0]:g}, {BASE[1]:g}]\n"
            f"  touch_time_s: {TOUCH_S:g}\n"
            f"probe:\n  adapter: sim\n  zero_mm: 5.0\n{noise}"
            f"simulation:\n  effects: {{}}\n  unknown: [tilt]\n")


def recording_text(r: dict) -> str:
    """Recording v1 (DESIGN.md): metadata, header, one row per touch in touch order."""
    lines = ["# adaptive-cal recording v1", "# source: benchmarks/explain_indep (independent)",
             "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    lines += [f"{i},{t:.1f},{x:.4f},{y:.4f},0,{v:.7f}"
              for i, (t, x, y, v) in enumerate(zip(r["t"], r["x"], r["y"], r["reading"]))]
    return "\n".join(lines) + "\n"


def write(case: Case, directory: Path) -> tuple[Path, list[Path]]:
    """Cell file and recordings (one per round) under ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    cell = directory / "cell.yaml"
    cell.write_text(cell_yaml(case), encoding="utf-8")
    recs = []
    for k, r in enumerate(case.rounds):
        p = directory / f"round{k}.csv"
        p.write_text(recording_text(r), encoding="utf-8")
        recs.append(p)
    return cell, recs
