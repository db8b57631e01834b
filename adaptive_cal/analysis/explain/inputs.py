"""What ``explain`` takes in memory, checked as the recording reader checks a file: a Recording
built by hand (or a threshold) that the reader would refuse is refused here with the column, the
row and the value -- not an IndexError deep in the analysis, nor NaN in the findings.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from adaptive_cal.formats.recording import (MAX_ABS_POSITION_MM, MAX_ABS_READING_MM, MAX_T_S,
                                           Recording, RecordingError)

COLUMNS = ("seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm")
# the reader's limits (formats.recording): beyond them a value is a typo or a unit error
LIMITS = {"x_mm": MAX_ABS_POSITION_MM, "y_mm": MAX_ABS_POSITION_MM, "z_mm": MAX_ABS_POSITION_MM,
          "reading_mm": MAX_ABS_READING_MM, "t_s": MAX_T_S}


def _array(value, name: str, label: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise RecordingError(f"{label}: column {name} is not an array of numbers") from None
    if v.ndim != 1:
        raise RecordingError(f"{label}: column {name} has shape {v.shape}; one value per touch "
                             "(a 1-D array) is needed")
    return v


def checked_recording(rec: Recording, label: str) -> Recording:
    """``rec`` with its columns as 1-D float arrays (seq as integers); RecordingError (a
    ValueError) naming the column, the row and the value where the reader would refuse it:
    columns of different lengths, flags not one set per row, a value beyond the reader's limits
    (an infinity included; NaN is a blank, as in a file), t_s negative, seq not a non-negative
    integer or not increasing within a round."""
    cols = {name: _array(getattr(rec, name), name, label) for name in COLUMNS}
    extra = dict(rec.extra or {})
    if "round" in extra:
        extra["round"] = _array(extra["round"], "round", label)
    n = cols["seq"].size
    sizes = {**{k: v.size for k, v in cols.items()}, **{k: len(v) for k, v in extra.items()}}
    for name, size in sizes.items():
        if size != n:
            raise RecordingError(f"{label}: column {name} has {size} values and seq has {n}: "
                                 "every column needs one value per touch")
    flags = tuple(rec.flags or ())
    if flags and len(flags) != n:
        raise RecordingError(f"{label}: flags has {len(flags)} entries for {n} touches: one set "
                             "of flag words per touch, or none")
    for i, f in enumerate(flags):
        if not isinstance(f, (set, frozenset)) or not all(isinstance(w, str) for w in f):
            raise RecordingError(f"{label}: flags[{i}] = {f!r}: a set of flag words is needed")
    seq = cols["seq"]
    row = lambda i: f"row {i} (seq {seq[i]:g})"
    for name, limit in LIMITS.items():
        v = cols[name]
        bad = np.flatnonzero(np.abs(v) > limit)
        if bad.size:
            raise RecordingError(f"{label}: {row(int(bad[0]))}: column {name} = {v[bad[0]]:g} is "
                                 f"beyond +-{limit:g} (a typo or a unit error?); {bad.size} "
                                 "such row(s)")
    t = cols["t_s"]
    bad = np.flatnonzero(t < 0)
    if bad.size:
        raise RecordingError(f"{label}: {row(int(bad[0]))}: column t_s = {t[bad[0]]:g} is "
                             "negative (seconds since the start of the run)")
    bad = np.flatnonzero(~np.isfinite(seq) | (seq < 0) | (seq != np.round(seq)))
    if bad.size:
        raise RecordingError(f"{label}: row {int(bad[0])}: column seq = {seq[bad[0]]:g} is not "
                             "a non-negative integer")
    # touch order within each round (rows of one round in file order; a blank round is one)
    key = extra["round"] if "round" in extra else np.zeros(n)
    key = np.where(np.isfinite(key), key, np.inf)
    order = np.argsort(key, kind="stable")
    back = np.flatnonzero((key[order][1:] == key[order][:-1]) & (np.diff(seq[order]) <= 0))
    if back.size:
        i, j = int(order[back[0]]), int(order[back[0] + 1])
        where = f" (both of round {key[i]:g})" if len(np.unique(key)) > 1 else ""
        raise RecordingError(f"{label}: row {j}: column seq = {seq[j]:g} does not increase "
                             f"after row {i}'s {seq[i]:g}{where}")
    cols["seq"] = seq.astype(np.int64)
    return replace(rec, **cols, flags=tuple(frozenset(f) for f in flags), extra=extra)


def checked_threshold(threshold) -> float:
    """``threshold`` as a float; ValueError unless it is a finite real number."""
    number = isinstance(threshold, (int, float, np.integer, np.floating)) and not isinstance(
        threshold, (bool, np.bool_))
    if not number or not np.isfinite(threshold):
        raise ValueError(f"threshold = {threshold!r}: a finite number (a log Bayes factor) is "
                         "needed")
    return float(threshold)


#: the steepest plate a probe on a robot maps (the cell's model.tilt_std_deg stops at 30 deg)
MAX_TILT_DEG = 30.0


def plausible_tilt(design, nuisance: np.ndarray) -> None:
    """RecordingError naming the round's file where a plane fitted to its readings (on
    ``nuisance``, ``design.nuisance()``'s columns, by least squares) is steeper than
    ``MAX_TILT_DEG``: positions in m (not mm), or the recording of another cell -- a recording
    with x and y in m had been explained as ``none`` with an 86 deg tilt, its suggested touches
    3,500 mm off the workspace (an outside audit, 2026-11-29). Checked before the analysis, so
    the refusal comes at once."""
    coef = np.linalg.lstsq(nuisance, design.target, rcond=None)[0]
    for r, path in enumerate(design.paths):
        a, b = coef[3 * r:3 * r + 2]
        steep = float(np.degrees(np.arctan(max(abs(a), abs(b)))))
        if steep > MAX_TILT_DEG:
            raise RecordingError(
                f"{path}: the readings rise {steep:.1f} deg across the plate (a {a:.4g}, "
                f"b {b:.4g} mm/mm): no plate a probe maps tilts beyond {MAX_TILT_DEG:.0f} "
                "deg -- are columns x_mm and y_mm in mm (not m), and is this the cell's "
                "recording?")
