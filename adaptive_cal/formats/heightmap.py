"""Height maps (DESIGN.md "Height maps", a stable format): a plate's true height on a regular
grid, for the simulated cell (``simulation.surface_file``) and studies (``plate.surface_files``).
UTF-8 CSV, first line ``x_mm,y_mm,height_mm``, then one row per node of a regular grid (every x
of the grid with every y, in any order). Heights between nodes are bilinear. A file that is not
that is refused with a HeightMapError naming the file, the line and the value. As CSV, the header
may have spaces after its commas (``x_mm, y_mm, height_mm``) and any field may be quoted
(``"-225"``, R's ``write.csv``); node coordinates may carry a writer's round-off (``_axis``)."""
from __future__ import annotations

import io
import math
import os
import stat
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from adaptive_cal.formats.cells import RecordingError, _OpenQuote, split_cells
from adaptive_cal.formats.table import strict_float
from adaptive_cal.formats.text import not_utf8, separated_hint

HEADER = "x_mm,y_mm,height_mm"
MAX_NODES = 4_000_000  # 2000 x 2000 nodes: far finer than any plate needs
# a recording's limits (formats.recording): positions +-10 m, a height (a reading) +-1 m
LIMIT_MM = {"x_mm": 10_000.0, "y_mm": 10_000.0, "height_mm": 1_000.0}
_REL = 1e-6  # grid positions equal to this share of the node spacing are the same node
#: a node may lie this share of the grid's spacing from its place on the regular grid (``_axis``)
ROUND_OFF = 1 / 20


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

    def _short(self, x_mm, y_mm) -> list[tuple[str, int, float, float]]:
        """The workplane edges the grid falls short of: (axis, 0 low / 1 high, grid's end,
        workplane's edge); an end within _REL of the grid's span of the edge covers it."""
        out = []
        for name, nodes, edges in (("x_mm", self.x_mm, x_mm), ("y_mm", self.y_mm, y_mm)):
            tol = _REL * (nodes[-1] - nodes[0])
            if nodes[0] > edges[0] + tol:
                out.append((name, 0, float(nodes[0]), float(edges[0])))
            if nodes[-1] < edges[1] - tol:
                out.append((name, 1, float(nodes[-1]), float(edges[1])))
        return out

    def covers(self, x_mm: tuple[float, float], y_mm: tuple[float, float]) -> bool:
        return not self._short(x_mm, y_mm)

    def check_covers(self, x_mm, y_mm) -> "HeightMap":
        """This map, or HeightMapError when it does not cover the rectangle (the workplane)."""
        short = self._short(x_mm, y_mm)
        if short:
            # an end that falls short is written with the digits that tell it from the edge
            # (a grid 0.5 um short printed as -185 beside the workplane's -185.0)
            ends = {"x_mm": [f"{v:g}" for v in self.x_mm[[0, -1]]],
                    "y_mm": [f"{v:g}" for v in self.y_mm[[0, -1]]]}
            gaps = []
            for name, side, end, edge in short:
                ends[name][side] = _apart(end, edge)[0]
                gaps.append(f"{abs(end - edge):.3g} mm short of {name}={edge!r}")
            raise HeightMapError(
                f"{self.source}: the grid spans x_mm=[{', '.join(ends['x_mm'])}], "
                f"y_mm=[{', '.join(ends['y_mm'])}] and does not cover the workplane "
                f"x_mm={list(x_mm)}, y_mm={list(y_mm)} (it ends {', '.join(gaps)})")
        return self


def _cell(nodes: np.ndarray, v: np.ndarray):
    v = np.clip(v, nodes[0], nodes[-1])
    i = np.clip(np.searchsorted(nodes, v, side="right") - 1, 0, len(nodes) - 2)
    t = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
    return i, t


def _axis(values: np.ndarray, name: str, source: str, lines=None) -> np.ndarray:
    """The distinct grid positions of one axis, equally spaced, or HeightMapError. Positions
    closer than _REL of the axis' span are one node (a writer's round-off, e.g. -224.99999999999997
    beside -225.0); the node is their first value in sorted order. ``lines``: each value's file
    line, for the message (the first line holding the node off the grid).

    "Equally spaced" allows the round-off of a writer that gives its coordinates few decimals: a
    step of 370/14 = 26.4286 mm written to 0.1 mm (-185.0, -158.6, -132.1, ...) puts a node up
    to 0.05 mm from its place. A node may lie up to ROUND_OFF (1/20) of the spacing from its place
    on the regular grid from the first node to the last; the nodes are used where the file puts
    them. That is safe for bilinear interpolation: the nodes stay strictly increasing (each step
    within 1/10 of the spacing), every cell keeps at least 9/10 of its width, and a height is
    read at most 1/20 of a cell from where the writer meant it -- the surface's slope times that,
    well below what the node spacing itself resolves. A grid with a node or a grid line missing
    is at least half a step off, and refused."""
    u, inverse = np.unique(values, return_inverse=True)
    keep = np.ones(len(u), bool)
    if len(u) > 1:
        keep[1:] = np.diff(u) > _REL * (u[-1] - u[0])
    node = (np.cumsum(keep) - 1)[inverse.ravel()]  # each value's node
    u = u[keep]
    if len(u) < 2:
        raise HeightMapError(f"{source}: {name} takes one value ({u[0]:g}): a grid needs at "
                             "least two nodes along each axis")
    h = (u[-1] - u[0]) / (len(u) - 1)
    off = np.abs(u - (u[0] + h * np.arange(len(u))))
    if off.max() > ROUND_OFF * h:
        step = np.diff(u)
        k = int(np.argmax(np.abs(step - h)))  # the two nodes farthest from the spacing
        a, b = _apart(step[k], h)
        # the node to name: one fewer rows hold than the others (a typed value), else the
        # node farthest from its place
        held = np.bincount(node, minlength=len(u))
        bad = int(np.argmin(held)) if held.min() < held.max() else int(np.argmax(off))
        first = int(np.flatnonzero(node == bad)[0])
        where = source if lines is None else f"{source}, line {lines[first]}"
        odd = (f", on {held[bad]} row(s) where each other {name} node is on "
               f"{held[np.arange(len(u)) != bad].min()} or more" if held.min() < held.max()
               else "")
        raise HeightMapError(f"{where}: not a regular grid: {name} nodes {u[k]:g} and "
                             f"{u[k + 1]:g} are {a} mm apart, the grid's spacing is {b} mm "
                             f"({len(u)} nodes from {u[0]:g} to {u[-1]:g} mm; a node may lie "
                             f"1/20 of the spacing, {ROUND_OFF * h:.3g} mm, from its place; "
                             f"{name} {float(values[first])!r} lies {off[bad]:.3g} mm from "
                             f"its place{odd})")
    return u


def _apart(a: float, b: float) -> tuple[str, str]:
    """``a`` and ``b`` written with the fewest significant digits (at least 6) that tell them
    apart."""
    for digits in range(6, 18):
        ta, tb = f"{a:.{digits}g}", f"{b:.{digits}g}"
        if ta != tb:
            return ta, tb
    return ta, tb


def _node(nodes: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Index of the node each value belongs to (values lie within round-off of a node)."""
    half = 0.5 * (nodes[1] - nodes[0])
    return np.clip(np.searchsorted(nodes, values + half) - 1, 0, len(nodes) - 1)


def _fast_numbers(text: str) -> np.ndarray | None:
    """The rows as an (n, 3) array when the file is well formed (numpy's C reader: a 541,501-node
    map, 0.5 mm over 450 x 300 mm, in 2.6 s against 7.9 s line by line), else None: the careful
    reader then finds and names the fault."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": the careful reader says
            a = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, comments=None,
                           ndmin=2, dtype=float)
    except ValueError:
        return None
    if a.shape[1] != 3 or not len(a) or len(a) > MAX_NODES or not np.isfinite(a).all():
        return None
    return a


def _place(a: np.ndarray, source: str, lines=None):
    """The grid's nodes (xs, ys) and each row's node indices (i, j), from rows ``a`` (x, y,
    height) on file ``lines``; axis faults raise HeightMapError."""
    xs = _axis(a[:, 0], "x_mm", source, lines)
    ys = _axis(a[:, 1], "y_mm", source, lines)
    return xs, ys, _node(xs, a[:, 0]), _node(ys, a[:, 1])


def _grid(a: np.ndarray, source: str) -> HeightMap | None:
    """The map from rows ``a`` (x, y, height), or None when a node is given twice or missing or
    an axis is not a regular grid (the careful reader names the lines)."""
    try:
        xs, ys, i, j = _place(a, source)
    except HeightMapError:
        return None
    flat = i * len(ys) + j
    if len(flat) != xs.size * ys.size or len(np.unique(flat)) != len(flat):
        return None
    z = np.empty(xs.size * ys.size)
    z[flat] = a[:, 2]
    return HeightMap(xs, ys, z.reshape(len(xs), len(ys)), source)


def _cells(line: str, n: int, source: str) -> list[str]:
    """The fields of line ``n`` of a map, as a recording's row is read (``formats.cells``:
    split on ``,``, or as CSV, RFC 4180, when the line holds a quote); HeightMapError naming
    the line where it is not a CSV row."""
    where = f"{source}, line {n}"
    try:
        return split_cells(line, where)
    except RecordingError as e:
        raise HeightMapError(str(e)) from None
    except _OpenQuote:
        raise HeightMapError(f"{where}: not a CSV row (a quoted field is not closed on its "
                             f"line): {line[:80]!r}") from None


def parse_heightmap(text: str, source: str = "height map") -> HeightMap:
    """Parse a height map's text; HeightMapError names the line and the value."""
    first = io.StringIO(text, newline=None).readline().strip().lstrip("\ufeff")
    names = _cells(first, 1, source)
    if names != HEADER.split(","):
        hint = separated_hint(first, "height maps")
        if names[:3] == HEADER.split(",") and any(names[3:]):  # compensate --grid's std_mm
            hint = ("; a height map has exactly these three columns (DESIGN.md): drop the others, "
                    "or write the map with 'adaptive-cal compensate --grid OUT.csv --heights-only'")
        elif names[:3] == HEADER.split(","):  # 'x_mm,y_mm,height_mm,'
            hint = "; the comma at its end makes an empty fourth column: drop it"
        elif [n.lower().replace("_um", "_mm") for n in names] == HEADER.split(","):
            hint = "; the names are lower case and the heights mm (height_mm), as DESIGN.md has them"
        raise HeightMapError(f"{source}, line 1: expected the header {HEADER!r}, got "
                             f"{first[:80]!r}{hint}")
    a = _fast_numbers(text)
    if a is not None and (np.abs(a) <= [LIMIT_MM["x_mm"], LIMIT_MM["y_mm"],
                                        LIMIT_MM["height_mm"]]).all():  # else: said by line
        fast = _grid(a, source)
        if fast is not None:
            return fast
    lines = text.splitlines()
    rows, numbers = [], []
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = _cells(line, n, source)
        if len(cells) != 3:
            raise HeightMapError(f"{source}, line {n}: expected 3 values x_mm,y_mm,height_mm, "
                                 f"got {len(cells)}: {line[:80]!r}")
        row = []
        for name, cell in zip(("x_mm", "y_mm", "height_mm"), cells):
            value = strict_float(cell)
            if value is None or not math.isfinite(value):
                raise HeightMapError(f"{source}, line {n}: {name} must be a finite number, "
                                     f"got {cell[:40]!r}")
            if abs(value) > LIMIT_MM[name]:  # as a recording's: a typo or a unit error
                raise HeightMapError(f"{source}, line {n}: {name} {cell.strip()!r} is beyond "
                                     f"+-{LIMIT_MM[name]:g} mm (a typo or a unit error?)")
            row.append(value)
        numbers.append(row)
        rows.append(n)
        if len(numbers) > MAX_NODES:
            raise HeightMapError(f"{source}: more than {MAX_NODES} nodes")
    if not numbers:
        raise HeightMapError(f"{source}: no rows after the header")
    a = np.array(numbers)
    xs, ys, i, j = _place(a, source, rows)
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
    except UnicodeDecodeError:
        raise HeightMapError(not_utf8(path)) from None
    except OSError as e:  # a folder, a file without read permission
        raise HeightMapError(f"{path}: cannot read the height map ({e.strerror})") from None
    return parse_heightmap(text, path)


def load_heightmap(path: str | Path) -> HeightMap:
    """Read and check a height map file (cached while the file is unchanged)."""
    path = str(path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise HeightMapError(f"{path}: cannot read the height map ({e.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise HeightMapError(f"{path}: a folder, not a height map file (a height map is one CSV file)")
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
