"""Height maps (DESIGN.md "Height maps", a stable format): a plate's true height on a regular
grid, for the simulated cell (``simulation.surface_file``) and studies (``plate.surface_files``).

UTF-8 CSV, first line exactly ``x_mm,y_mm,height_mm``, then one row per node of a regular grid
(every x of the grid with every y, in any order). Heights between nodes are bilinear. A file that
is not that is refused with a HeightMapError naming the file, the line and the value.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

HEADER = "x_mm,y_mm,height_mm"
MAX_NODES = 4_000_000  # 2000 x 2000 nodes: far finer than any plate needs
_REL = 1e-6  # grid positions equal to this share of the node spacing are the same node


class HeightMapError(ValueError):
    """A height map that cannot be used; the message names the file, the line and the value."""


@dataclass(frozen=True)
class HeightMap:
    """Heights ``z_mm[i, j]`` at ``(x_mm[i], y_mm[j])``; x_mm and y_mm strictly increasing."""

    x_mm: np.ndarray
    y_mm: np.ndarray
    z_mm: np.ndarray
    source: str = "height map"

    def __call__(self, x_mm, y_mm) -> np.ndarray:
        """Bilinear height (mm) at (x_mm, y_mm); points outside the grid take the edge value."""
        x = np.asarray(x_mm, float)
        y = np.broadcast_to(np.asarray(y_mm, float), x.shape)
        i, tx = _cell(self.x_mm, x)
        j, ty = _cell(self.y_mm, y)
        z = self.z_mm
        return ((1 - tx) * (1 - ty) * z[i, j] + tx * (1 - ty) * z[i + 1, j]
                + (1 - tx) * ty * z[i, j + 1] + tx * ty * z[i + 1, j + 1])

    def covers(self, x_mm: tuple[float, float], y_mm: tuple[float, float]) -> bool:
        tol_x = _REL * (self.x_mm[-1] - self.x_mm[0])
        tol_y = _REL * (self.y_mm[-1] - self.y_mm[0])
        return (self.x_mm[0] <= x_mm[0] + tol_x and self.x_mm[-1] >= x_mm[1] - tol_x
                and self.y_mm[0] <= y_mm[0] + tol_y and self.y_mm[-1] >= y_mm[1] - tol_y)

    def check_covers(self, x_mm, y_mm) -> "HeightMap":
        """This map, or HeightMapError when it does not cover the rectangle (the workplane)."""
        if not self.covers(x_mm, y_mm):
            raise HeightMapError(
                f"{self.source}: the grid spans x_mm=[{self.x_mm[0]:g}, {self.x_mm[-1]:g}], "
                f"y_mm=[{self.y_mm[0]:g}, {self.y_mm[-1]:g}] and does not cover the workplane "
                f"x_mm={list(x_mm)}, y_mm={list(y_mm)}")
        return self


def _cell(nodes: np.ndarray, v: np.ndarray):
    v = np.clip(v, nodes[0], nodes[-1])
    i = np.clip(np.searchsorted(nodes, v, side="right") - 1, 0, len(nodes) - 2)
    t = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
    return i, t


def _axis(values: np.ndarray, name: str, source: str) -> np.ndarray:
    """The distinct grid positions of one axis, equally spaced, or HeightMapError."""
    u = np.unique(values)
    if len(u) < 2:
        raise HeightMapError(f"{source}: {name} takes one value ({u[0]:g}): a grid needs at "
                             "least two nodes along each axis")
    step = np.diff(u)
    h = (u[-1] - u[0]) / (len(u) - 1)
    bad = np.flatnonzero(np.abs(step - h) > 1e-3 * h)
    if len(bad):
        k = bad[0]
        raise HeightMapError(f"{source}: not a regular grid: {name} nodes {u[k]:g} and "
                             f"{u[k + 1]:g} are {step[k]:g} mm apart, the grid's spacing is "
                             f"{h:g} mm")
    return u


def parse_heightmap(text: str, source: str = "height map") -> HeightMap:
    """Parse a height map's text; HeightMapError names the line and the value."""
    lines = text.splitlines()
    first = lines[0].strip().lstrip("\ufeff") if lines else ""
    if first != HEADER:
        raise HeightMapError(f"{source}, line 1: expected the header {HEADER!r}, got "
                             f"{first[:80]!r}")
    rows, numbers = [], []
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != 3:
            raise HeightMapError(f"{source}, line {n}: expected 3 values x_mm,y_mm,height_mm, "
                                 f"got {len(cells)}: {line[:80]!r}")
        row = []
        for name, cell in zip(("x_mm", "y_mm", "height_mm"), cells):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not cell.strip() or not math.isfinite(value):
                raise HeightMapError(f"{source}, line {n}: {name} must be a finite number, "
                                     f"got {cell.strip()[:40]!r}")
            row.append(value)
        numbers.append(row)
        rows.append(n)
        if len(numbers) > MAX_NODES:
            raise HeightMapError(f"{source}: more than {MAX_NODES} nodes")
    if not numbers:
        raise HeightMapError(f"{source}: no rows after the header")
    a = np.array(numbers)
    xs = _axis(a[:, 0], "x_mm", source)
    ys = _axis(a[:, 1], "y_mm", source)
    i = np.searchsorted(xs, a[:, 0])
    j = np.searchsorted(ys, a[:, 1])
    z = np.full((len(xs), len(ys)), np.nan)
    seen = np.full((len(xs), len(ys)), 0)
    for k, (ii, jj) in enumerate(zip(i, j)):
        if seen[ii, jj]:
            raise HeightMapError(f"{source}, line {rows[k]}: node x_mm={xs[ii]:g}, "
                                 f"y_mm={ys[jj]:g} is given twice (first on line {seen[ii, jj]})")
        seen[ii, jj] = rows[k]
        z[ii, jj] = a[k, 2]
    missing = np.argwhere(seen == 0)
    if len(missing):
        ii, jj = missing[0]
        raise HeightMapError(f"{source}: not a regular grid: node x_mm={xs[ii]:g}, "
                             f"y_mm={ys[jj]:g} is missing ({len(missing)} node(s) missing of "
                             f"{z.size})")
    return HeightMap(xs, ys, z, source)


@lru_cache(maxsize=64)
def _load(path: str, mtime_ns: int, size: int) -> HeightMap:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise HeightMapError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    return parse_heightmap(text, path)


def load_heightmap(path: str | Path) -> HeightMap:
    """Read and check a height map file (cached while the file is unchanged)."""
    path = str(path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise HeightMapError(f"{path}: cannot read the height map ({e.strerror})") from None
    return _load(path, st.st_mtime_ns, st.st_size)


def write_heightmap(path: str | Path, x_mm, y_mm, z_mm) -> Path:
    """Write heights ``z_mm[i, j]`` at ``(x_mm[i], y_mm[j])`` in the format above."""
    x, y = np.meshgrid(np.asarray(x_mm, float), np.asarray(y_mm, float), indexing="ij")
    a = np.column_stack([x.ravel(), y.ravel(), np.asarray(z_mm, float).ravel()])
    path = Path(path)
    with path.open("w", encoding="utf-8") as f:
        f.write(HEADER + "\n")
        np.savetxt(f, a, fmt="%.9g", delimiter=",")
    return path


def beside(name: str, file: str | Path) -> str:
    """``name`` (a path or glob) taken relative to the folder of ``file``, unless absolute."""
    p = Path(name)
    return str(p if p.is_absolute() else Path(file).resolve().parent / p)


def check_map(path: str | Path, workplane, key: str) -> HeightMap:
    """The map at ``path`` if it loads and covers ``workplane`` (x_mm, y_mm); else
    HeightMapError whose message starts with the config ``key``."""
    try:
        return load_heightmap(path).check_covers(workplane.x_mm, workplane.y_mm)
    except HeightMapError as e:
        raise HeightMapError(f"{key}: {e}") from None
