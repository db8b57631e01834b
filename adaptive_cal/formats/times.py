"""Checks on a recording's t_s column (the reader's notes)."""
from __future__ import annotations

import numpy as np


def time_backwards(path, t_s: np.ndarray, rounds, lines: list[int]) -> str | None:
    """A note where t_s runs backwards within a round (it is the time since the run's start,
    rows in touch order): a drift read from such times has its sign reversed. Blank times are
    skipped; each round (the ``round`` column) has its own clock."""
    r = np.zeros(t_s.size) if rounds is None else np.asarray(rounds, float)
    found = []
    for value in np.unique(r[np.isfinite(r)]) if rounds is not None else [0.0]:
        idx = np.flatnonzero((r == value) & np.isfinite(t_s))
        back = np.flatnonzero(np.diff(t_s[idx]) < 0)
        found += [(idx[k], idx[k + 1]) for k in back]
    if not found:
        return None
    i, j = min(found, key=lambda p: p[1])
    return (f"{path}:{lines[j]}: t_s {t_s[j]:g} s after {t_s[i]:g} s on line {lines[i]}: time "
            f"runs backwards ({len(found)} time{'s' * (len(found) > 1)}); t_s is the time since "
            "the start of the run, rows in touch order -- a drift read from these times has "
            "its sign turned")


def last_time_s(recording) -> float | None:
    """The recording's last known t_s (the cell's own clock since the run's start, resumes
    included): None where it has no rows or no times."""
    t = np.asarray(recording.t_s, float) if recording is not None else np.zeros(0)
    t = t[np.isfinite(t)]
    return float(t[-1]) if t.size else None
