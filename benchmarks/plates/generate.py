"""Realistic plates written independently of adaptive-cal's prior, simulator and effect library.

This module imports numpy, scipy and yaml only -- nothing from ``adaptive_cal`` (a test checks) --
so the plates it writes share no code with the model they test. Each family is written from
physics or a published description (docs/plates.md lists the sources):

  smooth    a squared-exponential Gaussian field (Rasmussen & Williams 2006, eq. 4.9), drawn with
            random Fourier features (Rahimi & Recht 2007): Gaussian spectral density
  rough     a Matern-3/2 field, 20 um std, length scale 60 mm (Rasmussen & Williams eq. 4.14):
            Student-t (3 dof) spectral density, again by random Fourier features
  dent      a local dent 30 um deep, radius 20 mm: a raised-cosine (Hann) bowl, the profile of a
            smoothed indentation, at a random place on the plate
  edge      edge roll-off, 20 um over the last 25 mm to every edge: quadratic in the distance
            into the band (the pressure peak at a lapped/polished edge, Preston's law)
  ripple    milling ripple, 6 um amplitude at a 30 mm period, along a random feed direction
            (the scallops of a face mill's step-over)
  seam      a ground seam: a 15 um step along a random straight line across the plate (two passes
            of a surface grinder that do not meet at the same height)
  noisy     the smooth family with heavy-tailed reading noise: Student-t (3 dof) and 1-2 %
            gross errors. The noise lives in the plate's ``noise`` entry of manifest.json
            (``reading_noise_mm`` draws it); the map is the plate alone.

Every plate also has a mild smooth form (std 3 um, length scale 200 mm) under its feature, a
random tilt uniform in +-1 deg about each axis and an offset uniform in +-0.2 mm. Heights are in
mm on a regular grid covering the workplane of the cell file (read with yaml.safe_load), written
as ``x_mm,y_mm,height_mm`` (DESIGN.md "Height maps"). Seeded and deterministic: plate i of a
family is drawn from ``default_rng([seed, family number, i])``.

    python benchmarks/plates/generate.py --out benchmarks/plates/out --plates 20
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import yaml

FAMILIES = ("smooth", "rough", "dent", "edge", "ripple", "seam", "noisy")
ROOT = Path(__file__).resolve().parents[2]
CELL = ROOT / "configs" / "sim-cell.yaml"
UM = 1e-3  # mm per micrometre


def workplane(cell_path: Path = CELL) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x_mm, y_mm) extents of the cell file's workplane, read as plain YAML."""
    data = yaml.safe_load(Path(cell_path).read_text())
    wp = data["workplane"]
    return tuple(map(float, wp["x_mm"])), tuple(map(float, wp["y_mm"]))


def grid(x_mm, y_mm, spacing_mm: float = 5.0):
    """Nodes covering [x0, x1] x [y0, y1] with about spacing_mm between them (ends included)."""
    nx = int(math.ceil((x_mm[1] - x_mm[0]) / spacing_mm)) + 1
    ny = int(math.ceil((y_mm[1] - y_mm[0]) / spacing_mm)) + 1
    return np.linspace(*x_mm, nx), np.linspace(*y_mm, ny)


def fourier_field(rng, X, Y, std_mm: float, length_mm: float, dof: float | None,
                  features: int = 3000) -> np.ndarray:
    """A stationary Gaussian-like field by random Fourier features (Rahimi & Recht 2007):
    f = std sqrt(2/M) sum cos(w.x + b), w from the kernel's spectral density -- Gaussian with
    covariance I / length^2 for the squared exponential; multivariate Student-t with 2 nu dof
    and the same scale for the Matern-nu kernel (``dof`` = 2 nu; 3 for Matern-3/2)."""
    z = rng.standard_normal((features, 2))
    if dof is not None:
        z *= np.sqrt(dof / rng.chisquare(dof, (features, 1)))
    w = z / length_mm
    b = rng.uniform(0, 2 * np.pi, features)
    phase = X.ravel()[:, None] * w[:, 0] + Y.ravel()[:, None] * w[:, 1] + b
    f = np.sqrt(2.0 / features) * np.cos(phase).sum(axis=1)
    return std_mm * f.reshape(X.shape)


def _inner_point(rng, x_mm, y_mm, margin_mm: float):
    return (rng.uniform(x_mm[0] + margin_mm, x_mm[1] - margin_mm),
            rng.uniform(y_mm[0] + margin_mm, y_mm[1] - margin_mm))


def feature(family: str, rng, X, Y, x_mm, y_mm) -> tuple[np.ndarray, dict]:
    """The family's own height (mm) on the grid and what was drawn."""
    if family in ("smooth", "noisy"):
        std, ell = rng.uniform(10, 30) * UM, rng.uniform(100, 200)
        return fourier_field(rng, X, Y, std, ell, None), {"std_mm": std, "length_mm": ell}
    if family == "rough":
        return fourier_field(rng, X, Y, 20 * UM, 60.0, 3.0), {"std_mm": 20 * UM, "length_mm": 60.0}
    if family == "dent":
        cx, cy = _inner_point(rng, x_mm, y_mm, 40.0)
        k = np.argmin(np.hypot(X - cx, Y - cy))  # on a node: the map holds the full depth
        cx, cy = float(X.flat[k]), float(Y.flat[k])
        r = np.hypot(X - cx, Y - cy)
        depth, radius = 30 * UM, 20.0
        h = -depth * 0.5 * (1 + np.cos(np.pi * np.minimum(r / radius, 1.0)))
        return h, {"centre_mm": [cx, cy], "depth_mm": depth, "radius_mm": radius}
    if family == "edge":
        d = np.minimum.reduce([X - x_mm[0], x_mm[1] - X, Y - y_mm[0], y_mm[1] - Y])
        band, drop = 25.0, 20 * UM
        h = -drop * np.clip((band - d) / band, 0.0, 1.0) ** 2
        return h, {"band_mm": band, "drop_mm": drop}
    if family == "ripple":
        theta, phase = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
        u = X * np.cos(theta) + Y * np.sin(theta)
        amp, period = 6 * UM, 30.0
        return amp * np.sin(2 * np.pi * u / period + phase), {
            "amplitude_mm": amp, "period_mm": period, "feed_deg": math.degrees(theta)}
    if family == "seam":
        cx, cy = _inner_point(rng, x_mm, y_mm, 60.0)
        theta = rng.uniform(0, np.pi)
        side = (X - cx) * -np.sin(theta) + (Y - cy) * np.cos(theta)
        step = 15 * UM * rng.choice([-1.0, 1.0])
        return np.where(side > 0, step, 0.0), {"through_mm": [cx, cy], "angle_deg":
                                               math.degrees(theta), "step_mm": step}
    raise ValueError(f"unknown family {family!r}; known: {', '.join(FAMILIES)}")


def noise_spec(family: str, rng) -> dict:
    """How readings of this plate are disturbed: Student-t (3 dof) with 1-2 % gross errors for
    ``noisy``; Gaussian otherwise (the study's own noise)."""
    if family != "noisy":
        return {"kind": "gaussian"}
    return {"kind": "student_t", "dof": 3.0, "scale_mm": 5 * UM / math.sqrt(3.0),
            "outlier_rate": float(rng.uniform(0.01, 0.02)), "outlier_mm": 0.05}


def reading_noise_mm(spec: dict, rng, n: int) -> np.ndarray:
    """n reading errors (mm) drawn from a plate's noise entry (Student-t and gross errors)."""
    if spec["kind"] != "student_t":
        raise ValueError("only the student_t entry is drawn here; gaussian is the study's own")
    e = spec["scale_mm"] * rng.standard_t(spec["dof"], n)
    hit = rng.random(n) < spec["outlier_rate"]
    return e + hit * spec["outlier_mm"] * rng.standard_normal(n)


def backdrop(rng, X, Y) -> tuple[np.ndarray, float, float, float]:
    """What every plate has under its feature (module docstring), drawn in this order: the tilt
    (slopes in x and y, within +-1 deg), the offset (+-0.2 mm) and the mild smooth form (3 um,
    200 mm). Returns (heights mm, slope_x, slope_y, offset_mm)."""
    ax, ay = np.tan(np.radians(rng.uniform(-1.0, 1.0, 2)))  # about y (slope in x), about x
    offset = rng.uniform(-0.2, 0.2)
    base = fourier_field(rng, X, Y, 3 * UM, 200.0, None)
    return offset + ax * X + ay * Y + base, float(ax), float(ay), float(offset)


def plate(family: str, index: int, seed: int, x_mm, y_mm, spacing_mm: float = 5.0):
    """(xs, ys, heights[i, j] mm, description) of plate ``index`` of ``family``."""
    rng = np.random.default_rng([seed, FAMILIES.index(family), index])
    xs, ys = grid(x_mm, y_mm, spacing_mm)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    under, ax, ay, offset = backdrop(rng, X, Y)
    h, drawn = feature(family, rng, X, Y, x_mm, y_mm)
    z = under + h
    desc = {"family": family, "index": index, "slope_x": ax, "slope_y": ay, "offset_mm": offset,
            "feature": drawn, "noise": noise_spec(family, rng)}
    return xs, ys, z, desc


def write_csv(path: Path, xs, ys, z) -> None:
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    rows = np.column_stack([X.ravel(), Y.ravel(), z.ravel()])
    with open(path, "w", encoding="utf-8") as f:
        f.write("x_mm,y_mm,height_mm\n")
        np.savetxt(f, rows, fmt="%.9g", delimiter=",")


def generate(out: Path, plates: int, families=FAMILIES, seed: int = 14,
             cell_path: Path = CELL, spacing_mm: float = 5.0) -> dict:
    """Write ``out/<family>/plate-NNN.csv`` and ``out/manifest.json``; return the manifest."""
    x_mm, y_mm = workplane(cell_path)
    manifest = {"seed": seed, "cell": str(cell_path), "x_mm": x_mm, "y_mm": y_mm,
                "spacing_mm": spacing_mm, "plates": {}}
    for family in families:
        folder = Path(out) / family
        folder.mkdir(parents=True, exist_ok=True)
        for i in range(plates):
            xs, ys, z, desc = plate(family, i, seed, x_mm, y_mm, spacing_mm)
            name = f"{family}/plate-{i:03d}.csv"
            write_csv(Path(out) / name, xs, ys, z)
            manifest["plates"][name] = desc
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return manifest


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "out"))
    p.add_argument("--plates", type=int, default=20, help="plates per family")
    p.add_argument("--families", default=",".join(FAMILIES))
    p.add_argument("--seed", type=int, default=14)
    p.add_argument("--cell", default=str(CELL), help="cell file whose workplane the maps cover")
    args = p.parse_args(argv)
    fams = [f for f in args.families.split(",") if f]
    generate(Path(args.out), args.plates, fams, args.seed, Path(args.cell))
    print(f"{args.plates} plates x {len(fams)} families written under {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
