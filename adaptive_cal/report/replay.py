"""A bare recording replayed with a cell file (``flatness REC --robot CELL``, ``report REC
--robot CELL``) is judged as the live run would have judged it before it is fused:

- a reading outside the probe's usable stroke (``probe.usable_mm``) is not used, as ``run``
  rejects it (``rejected;stroke_end``): counted and said, never fused;
- a touch the cell's workplane does not hold is refused, naming its line and value (the
  recording is not of this cell, or a value is a typo).

Rows already flagged as not fused are left as they are (``run`` writes off-workplane touches
flagged ``invalid;rejected``). The file itself is never changed.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.recording import Recording, RecordingError, say

STROKE_END = frozenset({"rejected", "stroke_end"})
HEIGHT_COLUMNS = ("height_mm", "height", "z_mm", "z")  # a table's heights are no indications


def line_of(path: str | None, index: int) -> int | None:
    """The line of the ``index``-th data row (0-based) of the file at ``path``: after the
    header, skipping blank and ``#`` lines (as the readers do); None when it cannot be read."""
    if path is None:
        return None
    try:
        with open(path, encoding="utf-8-sig", errors="replace", newline=None) as f:
            header, k = False, -1
            for lineno, line in enumerate(f, start=1):
                if not line.strip() or line.startswith("#"):
                    continue
                if not header:
                    header = True
                    continue
                k += 1
                if k == index:
                    return lineno
    except OSError:
        return None
    return None


def for_replay(rec: Recording, cell: Cell, cell_file: str | Path) -> Recording:
    """``rec`` with the readings outside ``probe.usable_mm`` flagged ``rejected;stroke_end``
    (said on stderr); RecordingError naming the line and the value for a touch to be fused
    outside the workplane."""
    where = rec.path or "the recording"
    used = rec.fused
    off = cell.workplane.first_outside(rec.x_mm[used], rec.y_mm[used])
    if off is not None:
        c, j, count = off
        i = int(np.flatnonzero(used)[j])
        lo, hi = getattr(cell.workplane, c)
        line = line_of(rec.path, i)
        raise RecordingError(
            f"{where}{f':{line}' if line else ''}: touch seq {int(rec.seq[i])}: column {c} = "
            f"{getattr(rec, c)[i]:g} lies outside the workplane {c} [{lo:g}, {hi:g}] of "
            f"{cell_file} ({count} such touch{'es' * (count != 1)}): is the recording of this "
            "cell?")
    if rec.meta.get("column") in HEIGHT_COLUMNS:
        return rec
    lo, hi = cell.probe.usable_mm
    with np.errstate(invalid="ignore"):
        out = used & ~((rec.reading_mm >= lo) & (rec.reading_mm <= hi))
    if not out.any():
        return rec
    idx = np.flatnonzero(out)
    shown = ", ".join(f"line {line_of(rec.path, int(i)) or '?'} (seq {int(rec.seq[i])}: "
                      f"{rec.reading_mm[i]:g} mm)" for i in idx[:5])
    more = f" and {idx.size - 5} more" if idx.size > 5 else ""
    say([f"{where}: {idx.size} reading{'s' * (idx.size != 1)} outside the probe's usable stroke "
         f"{[lo, hi]} mm (probe.usable_mm of {cell_file}) not used, as the run does not use "
         f"them (rejected;stroke_end): {shown}{more}"])
    flags = list(rec.flags) if rec.flags else [frozenset()] * len(rec)
    for i in idx:
        flags[i] = flags[i] | STROKE_END
    return replace(rec, flags=tuple(flags))
