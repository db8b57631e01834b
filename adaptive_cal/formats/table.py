"""Readings from another tool: a plain CSV table of x, y and a reading or height per touch (like
the paper's tables), read as a recording.

The first line names the columns: ``x_mm`` (or ``x``), ``y_mm`` (or ``y``) and one of
``reading_mm``, ``reading``, ``height_mm``, ``height``, ``z_mm`` or ``z`` (mm; larger is a higher
surface either way); other columns are ignored. With a reading column, a ``z_mm`` (or ``z``)
column is the approach height, as in a recording (reading = surface - z + zero); without one the
approach height is 0. Each row is a touch in order (seq 0, 1, ...), with no time: heights are
relative, which is all tilt and flatness need.
Blank lines and lines starting with ``#`` are skipped.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

X_NAMES = ("x_mm", "x")
Y_NAMES = ("y_mm", "y")
VALUE_NAMES = ("reading_mm", "reading", "height_mm", "height", "z_mm", "z")
Z_NAMES = ("z_mm", "z")
MAX_ROWS = 200_000  # rows of a table or a recording (formats.recording uses this one)
LIMIT_MM = 1e4  # no coordinate or reading of a plate this tool reads lies beyond 10 m


class TableError(ValueError):
    """A table that names its columns but has a bad value: the message names line and column."""


def table_columns(first_line: str) -> tuple[int, int, int, str, int | None] | None:
    """(x, y, value column indices, value column name, approach-height column index or None)
    when ``first_line`` is a header naming x, y and a reading or height column, else None."""
    names = [c.strip().lower() for c in next(csv.reader([first_line]), [])]

    def find(options):
        return next((names.index(n) for n in options if n in names), None)

    ix, iy, iv = find(X_NAMES), find(Y_NAMES), find(VALUE_NAMES)
    if ix is None or iy is None or iv is None:
        return None
    iz = find(Z_NAMES) if names[iv] in ("reading_mm", "reading") else None
    return ix, iy, iv, names[iv], iz


def read_table(path: str | Path, first_line: str) -> dict | None:
    """The fields of a ``Recording`` read from a plain table (see the module doc), or None when
    ``first_line`` is not such a header. Raises TableError naming the line and column."""
    cols = table_columns(first_line)
    if cols is None:
        return None
    ix, iy, iv, value_name, iz = cols
    x, y, v, z = [], [], [], []
    columns = [(ix, "x", x), (iy, "y", y), (iv, value_name, v)]
    columns += [(iz, "z", z)] if iz is not None else []
    with open(path, encoding="utf-8-sig", newline="") as f:
        rows = csv.reader(f)
        next(rows, None)
        for lineno, cells in enumerate(rows, start=2):
            if not cells or not "".join(cells).strip() or cells[0].lstrip().startswith("#"):
                continue
            if len(x) >= MAX_ROWS:
                raise TableError(f"{path}:{lineno}: more than {MAX_ROWS} rows; split the table")
            for i, name, out in columns:
                text = cells[i].strip() if i < len(cells) else ""
                try:
                    value = float(text)
                except ValueError:
                    raise TableError(f"{path}:{lineno}: column {name}: {text!r} is not a number "
                                     "(mm)") from None
                if not math.isfinite(value) or abs(value) > LIMIT_MM:
                    raise TableError(f"{path}:{lineno}: column {name}: {text} mm is not a "
                                     f"finite value within +-{LIMIT_MM:g} mm")
                out.append(value)
    if not x:
        raise TableError(f"{path}: a table header ({first_line.strip()!r}) but no rows")
    n = len(x)
    return {"seq": np.arange(n, dtype=float), "t_s": np.full(n, np.nan),
            "x_mm": np.array(x), "y_mm": np.array(y), "z_mm": np.array(z) if z else np.zeros(n),
            "reading_mm": np.array(v), "meta": {"source": f"table {Path(path).name}"},
            "path": str(path)}
