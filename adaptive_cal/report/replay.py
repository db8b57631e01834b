"""A bare recording replayed with a cell file (``flatness REC --robot CELL``, ``report REC
--robot CELL``) is judged as the live run would have judged it before it is fused:

- a reading outside the probe's usable stroke (``probe.usable_mm``) is not used, as ``run``
  rejects it (``rejected;stroke_end``): counted and said, never fused;
- a touch the cell's workplane does not hold is refused, naming its line and value (the
  recording is not of this cell, or a value is a typo).

Rows already flagged as not fused are left as they are (``run`` writes off-workplane touches
flagged ``invalid;rejected``). The file itself is never changed. ``closure_of`` judges a
recording's closure touch (rows flagged ``closure``) again, for the report's drift row.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.recording import Recording, RecordingError, say

STROKE_END = frozenset({"rejected", "stroke_end"})
HEIGHT_COLUMNS = ("height_mm", "height", "z_mm", "z")  # a table's heights are no indications
#: a cell whose usable stroke leaves out more than this share of a recording's readings does not
#: describe that recording's gauge (signed relative readings, a zero set elsewhere): its readings
#: are used, and the mismatch said, rather than nearly all of them set aside
STROKE_MISMATCH_SHARE = 0.2


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
    (said on stderr) -- unless they are more than ``STROKE_MISMATCH_SHARE`` of its readings:
    then the cell does not describe the recording's gauge, and they are used (said);
    RecordingError naming the line and the value for a touch to be fused outside the
    workplane; a warning naming the first touch inside a keep-out (used: a real reading, but
    a run of this cell never touches there)."""
    where = rec.path or "the recording"
    _another_cell(rec, cell, cell_file, where)
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
    inside = [(i, k) for i in np.flatnonzero(used) for k, ko in enumerate(cell.workplane.keep_outs)
              if ko.contains(float(rec.x_mm[i]), float(rec.y_mm[i]))]
    if inside:  # a real reading, used; but a run of this cell never touches there
        i, k = inside[0]
        line = line_of(rec.path, int(i))
        say([f"{where}{f':{line}' if line else ''}: touch seq {int(rec.seq[i])} at "
             f"({rec.x_mm[i]:g}, {rec.y_mm[i]:g}) mm lies inside keep_outs[{k}] of {cell_file} "
             f"({len(inside)} such touch{'es' * (len(inside) != 1)}, used): a run of this cell "
             "never touches there -- is the recording of this cell?"])
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
    if idx.size > STROKE_MISMATCH_SHARE * np.count_nonzero(used):
        spread = float(np.ptp(rec.reading_mm[used]))
        why = (f"their spread, {spread:g} mm, is more than the probe's whole stroke "
               f"({cell.probe.stroke_mm:g} mm): readings in um? (reading_mm is mm, DESIGN.md)"
               if spread > cell.probe.stroke_mm else "signed readings? a zero set elsewhere?")
        say([f"{where}: {idx.size} of its {np.count_nonzero(used)} readings lie outside the "
             f"probe's usable stroke {[lo, hi]} mm of {cell_file} ({shown}{more}): the cell's "
             f"probe block does not describe this recording's gauge ({why}), so they are used, "
             "not set aside as a run's stroke-end touches; give the cell probe.rest_mm and "
             "probe.usable_mm that hold them (docs/config.md)"])
        return rec
    say([f"{where}: {idx.size} reading{'s' * (idx.size != 1)} outside the probe's usable stroke "
         f"{[lo, hi]} mm (probe.usable_mm of {cell_file}) not used, as the run does not use "
         f"them (rejected;stroke_end): {shown}{more}"])
    flags = list(rec.flags) if rec.flags else [frozenset()] * len(rec)
    for i in idx:
        flags[i] = flags[i] | STROKE_END
    return replace(rec, flags=tuple(flags))


def _another_cell(rec: Recording, cell: Cell, cell_file, where: str) -> None:
    """Say where a recording was taken with another probe zero than ``cell``'s: its heights
    are then computed with this cell's zero and judged against its stroke (an outside audit:
    a run's recording read with the Cheng cell gave 282.5 um for 275.8, exit 0; beside its run
    folder the folder's cell.yaml is compared in full, ``cli.common``; a name is a label: a
    renamed cell that maps the same says nothing)."""
    try:
        zero = float(rec.meta.get("probe_zero_mm", "nan"))
    except ValueError:
        return
    if math.isfinite(zero) and abs(zero - cell.probe.zero_mm) > 1e-9:
        say([f"{where}: recorded with probe_zero_mm {zero:g}, read with {cell_file}'s "
             f"probe.zero_mm {cell.probe.zero_mm:g}: the heights follow the cell file's"])


def last_closure(flags) -> list[int]:
    """The rows of a recording's last closure (its repeat, retakes and confirmation: one run
    of consecutive rows flagged closure; a run its first closure moved off the bound closes
    again later), by index; [] where none was made."""
    from adaptive_cal.planning.closure import FLAG

    at = [j for j, f in enumerate(flags or ()) if FLAG in f]
    k = len(at) - 1
    while k > 0 and at[k - 1] == at[k] - 1:
        k -= 1
    return at[max(k, 0):]


def closure_of(plan, rec: Recording):
    """The (last) closure touch of a recording judged again (``planning.closure``) as the run
    judged it: the map with the repeat fused, the noise relearned without the drift it reads
    (``planning.closure_noise``). None when the recording has no closure touch."""
    from types import SimpleNamespace

    from adaptive_cal.formats.recording import surface_height_mm
    from adaptive_cal.planning import closure as cl
    from adaptive_cal.planning import closure_noise
    from adaptive_cal.planning import survey as sv

    flags = list(rec.flags) if rec.flags else []
    at = last_closure(flags)
    if not at:
        return None
    before = sv.replay(plan, sv.start(plan), rec.select(np.arange(len(rec)) < at[0]))
    i = cl.first_place(before.fused_weights)
    if i is None:
        return cl.Closure(False, why="every one of the first readings was flagged an outlier")
    rows_at = np.flatnonzero(rec.fused & (np.arange(len(rec)) < at[0]))  # fused, in order
    xy = np.column_stack([rec.x_mm[rows_at], rec.y_mm[rows_at]])
    start = cl.start_cluster(before.fused_weights, xy, i)
    where = dict(x_mm=float(xy[i, 0]), y_mm=float(xy[i, 1]), first_touch=int(rec.seq[rows_at[i]]))
    used: list[int] = []
    verdict = None
    parts, rest = [], list(at)  # the repeat, then a confirmation: each with its retake where
    while rest and len(parts) < 2:  # the gate held it back (a gated reading is never fused)
        n = 2 if "gated" in flags[rest[0]] else 1
        parts.append(rest[:n])
        rest = rest[n:]
    for part in parts:
        told = [SimpleNamespace(fused=bool(rec.fused[j]), flags=flags[j]) for j in part
                if "gated" in flags[j] or not ({"rejected", "invalid"} & flags[j])]
        keep, why = cl.repeats_to_judge(told)
        if why and not used:
            return cl.Closure(False, repeat_touches=tuple(int(rec.seq[j]) for j in part),
                              why=why, **where)
        if why or (verdict is not None and (verdict.passed or len(used) != 1)):
            break
        used += [part[k] for k in keep]
        u = np.array(used)
        heights = surface_height_mm(rec.reading_mm[u], rec.z_mm[u], plan.zero_mm)
        upto = np.arange(len(rec)) <= part[-1]  # the run judged with the repeat fused
        now = sv.replay(plan, sv.start(plan), rec.select(upto))
        elapsed = float(rec.t_s[u[-1]] - rec.t_s[rows_at[i]])
        verdict = closure_noise.judged(
            plan, now, rec.t_s[rec.fused & upto], start, before.rows[start],
            before.heights_mm[start], plan.model.surface.basis(rec.x_mm[u], rec.y_mm[u]),
            heights, rec.t_s[u], repeat_touches=tuple(int(rec.seq[j]) for j in used),
            elapsed_s=elapsed if np.isfinite(elapsed) else None, **where)
    return verdict

