"""An independent generator of recordings for the suspect-reading tests (issue 15).

Written from DESIGN.md's physics only -- a tilted plane, Gaussian (or Student-t) reading noise, one
gross error, a cosine-bell bump -- and shares no code with ``adaptive_cal.simulation``,
``adaptive_cal.effects`` or ``explain``: the readings are written as a v1 recording and read back
with the ordinary reader, the way a real recording reaches explain.

The reference design: the 10 x 4 S-path of Cheng, Chang & Weng (2025), x = -202.5 .. 202.5 mm in
steps of 45, y in {-165, -55, 55, 165}, rows alternating +x / -x; the probe's stated noise of that
cell is 0.01 mm, and the readings here carry exactly that noise.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from adaptive_cal.formats.recording import read_recording

NOISE_MM = 0.01  # configs/cheng2025-cell.yaml: probe.noise_std_mm
XS = -202.5 + 45.0 * np.arange(10)
YS = np.array([-165.0, -55.0, 55.0, 165.0])


def s_path() -> tuple[np.ndarray, np.ndarray]:
    """The touches in the order taken: row 0 along +x, row 1 along -x, ..."""
    x = np.concatenate([XS if r % 2 == 0 else XS[::-1] for r in range(YS.size)])
    y = np.repeat(YS, XS.size)
    return x, y


def plane_residual_norm(x, y, h) -> float:
    """|h minus its least-squares plane|: the part of a height pattern a tilt cannot absorb."""
    A = np.stack([x, y, np.ones_like(x)], 1)
    coef, *_ = np.linalg.lstsq(A, h, rcond=None)
    return float(np.linalg.norm(h - A @ coef))


def bell(x, y, cx, cy, radius):
    d = np.hypot(x - cx, y - cy) / radius
    return np.where(d < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d, 1.0))), 0.0)


def readings(rng: np.random.Generator, *, spike_sigma: float | None = None,
             defect_sigma: float | None = None, student_t: bool = False,
             defect_pair_weight: float = 0.0) -> dict:
    """Plane + noise, plus optionally one gross error (``spike_sigma`` noise sds, random sign, at
    a random touch) or a cosine bump reaching at least 3 touches whose plane-removed norm is
    ``defect_sigma`` noise sds, two of them carrying at least ``defect_pair_weight`` of its
    height. Returns x, y, reading and what was hidden."""
    x, y = s_path()
    n = x.size
    a, b, c = rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, 0.2)
    h = a * x + b * y + c
    if student_t:  # 3 dof, scaled to the stated sd
        noise = NOISE_MM * rng.standard_t(3, n) / np.sqrt(3.0)
    else:
        noise = NOISE_MM * rng.standard_normal(n)
    out = {"x": x, "y": y, "spike_seq": None, "defect": None}
    if defect_sigma is not None:
        while True:
            cx, cy = rng.uniform(-200, 200), rng.uniform(-165, 165)
            radius = rng.uniform(50.0, 70.0)
            unit = bell(x, y, cx, cy, radius)
            if np.count_nonzero(unit > 0) >= 3 and np.sort(unit)[-2] >= defect_pair_weight:
                break
        height = defect_sigma * NOISE_MM / plane_residual_norm(x, y, unit)
        h = h + height * unit
        out["defect"] = {"x_mm": cx, "y_mm": cy, "radius_mm": radius, "height_mm": height}
    if spike_sigma is not None:
        i = int(rng.integers(n))
        noise[i] = rng.choice([-1.0, 1.0]) * spike_sigma * NOISE_MM
        out["spike_seq"] = i
    out["reading"] = h + noise
    return out


def write(path: Path, case: dict):
    """As a v1 recording (t_s blank, z_mm 0: reading = surface height + probe zero 0)."""
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    lines += [f"{i},,{x:.4f},{y:.4f},0,{r:.6f}"
              for i, (x, y, r) in enumerate(zip(case["x"], case["y"], case["reading"]))]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return read_recording(path)
