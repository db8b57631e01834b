"""The point-table form of a toolpath: a CSV with the header ``x_mm,y_mm,z_mm`` (other columns
kept), one row a point, each row after the first a straight cut from the one before. Read as
the csv module reads a file opened with newline="" (CR, LF and CRLF line ends; a quoted field
may span lines), every row named by its line in the file."""
from __future__ import annotations

import csv
import io
import math

from adaptive_cal.formats.table import strict_float
from adaptive_cal.formats.toolpath_base import Move, Toolpath, ToolpathError, fmt, newline_of


def read_csv_toolpath(text: str, name: str, bom: bool = False) -> Toolpath:
    newline, final = newline_of(text)
    reader = csv.reader(io.StringIO(text, newline=""))  # CR-only line ends too
    try:
        rows = [(reader.line_num, row) for row in reader]
    except csv.Error as e:
        raise ToolpathError(f"{name} line {reader.line_num}: {e}") from None
    header = [h.strip() for h in rows[0][1]]
    names = [h.lower() for h in header]  # X_MM is x_mm, as the detection reads it
    for j, h in enumerate(header):
        if h and h.lower() in names[:j]:
            raise ToolpathError(f"{name} line 1: column {h!r} given twice (columns "
                                f"{names.index(h.lower()) + 1} and {j + 1}): give each column once")
    try:
        cols = tuple(names.index(k) for k in ("x_mm", "y_mm", "z_mm"))
    except ValueError:
        raise ToolpathError(f"{name} line 1: a point CSV needs the columns x_mm, y_mm, z_mm; "
                            f"got {', '.join(header)}") from None
    moves, prev = [], None  # the first point starts nothing: it is a point, not a move
    for i, (line, row) in enumerate(rows[1:], start=1):
        if not row or all(not f.strip() for f in row):
            continue
        where = f"{name} line {line}"  # the row's last line in the file (a quoted field spans)
        if len(row) != len(header):
            raise ToolpathError(f"{where}: {len(row)} fields, the header has {len(header)}")
        point = []
        for c, k in zip(cols, ("x_mm", "y_mm", "z_mm")):
            v = strict_float(row[c].strip())
            if v is None:
                raise ToolpathError(f"{where}: {k} {row[c]!r} is not a number")
            if not math.isfinite(v):
                raise ToolpathError(f"{where}: {k} {row[c]!r} is not finite")
            point.append(v)
        moves.append(Move(i, line, True, prev, tuple(point)))
        prev = tuple(point)
    return Toolpath("csv", [row for _, row in rows], moves, newline, final, cols, bom=bom)


def write_csv_toolpath(path: Toolpath, pieces: dict, marks: dict, note_column: str) -> str:
    """The rows with each listed move's pieces before its own row (which keeps its other
    columns); ``marks`` in ``note_column`` -- the file's own column of that name where it has
    one (a marked output compensated again would otherwise name it twice)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator=path.newline)
    header = list(path.lines[0])
    at = next((j for j, h in enumerate(header) if h.strip().lower() == note_column), None)
    if marks and at is None:
        header.append(note_column)
    w.writerow(header)
    cx, cy, cz = path.columns

    def noted(row, i):
        row = list(row)
        if marks and at is not None:
            row[at] = marks.get(i, row[at])
        return row + ([marks.get(i, "")] if marks and at is None else [])

    for i, row in enumerate(path.lines[1:], start=1):
        if i not in pieces:
            w.writerow(noted(row, i))
            continue
        *before, last = pieces[i]
        for x, y, z in before:
            new = list(row)
            new[cx], new[cy], new[cz] = fmt(x), fmt(y), fmt(z)
            w.writerow(noted(new, i))
        new = list(row)
        new[cz] = fmt(last[2])
        w.writerow(noted(new, i))
    return buf.getvalue()
