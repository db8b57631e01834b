"""Readings from another tool: a plain CSV table of x, y and a reading or height per touch (like
the paper's tables), read as a recording.

The first line names the columns: ``x_mm`` (or ``x``), ``y_mm`` (or ``y``) and one of
``reading_mm``, ``reading``, ``height_mm``, ``height``, ``z_mm`` or ``z`` (mm; larger is a higher
surface either way); other columns are ignored. With a reading column, a ``z_mm`` (or ``z``)
column is the approach height, as in a recording (reading = surface - z + zero); without one the
approach height is 0. Each row is a touch in order (seq 0, 1, ...), with no time: heights are
relative, which is all tilt and flatness need.
A ``flags`` column is honoured exactly as a recording's (``parse_flags``): a row flagged
``gated``, ``rejected`` or ``invalid`` is not used.
Blank lines and lines starting with ``#`` are skipped.
"""
from __future__ import annotations

import csv
import difflib
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


#: flag words a recording's ``flags`` column carries (docs/recording.md); ``outlier=P`` besides.
#: A row with one of NOT_FUSED is never used (``invalid`` is written with ``rejected``, and is
#: not used alone either).
NOT_FUSED = frozenset({"gated", "rejected", "invalid"})
KNOWN_FLAGS = NOT_FUSED | {"retake", "surprise", "closure", "spread", "stroke_end", "frozen",
                           "nonfinite", "cut"}  # cut: a row completed after a crash cut its flags
OUTLIER_FLAG = "outlier="


def not_read(reading: str, flags: str) -> bool:
    """Whether a row's ``reading`` is no number at all (blank, NaN, infinite) on a row its
    ``flags`` say is not fused (``NOT_FUSED``): another tool's way to write a failed reading,
    read as this tool writes one, 0 flagged ``nonfinite`` (an outside audit: one such row
    refused the whole file)."""
    value = strict_float(reading) if reading.strip() else math.nan  # float reads nan, inf
    return value is not None and not math.isfinite(value) and \
        bool({w.strip().lower() for w in flags.split(";")} & NOT_FUSED)


def strict_float(text: str) -> float | None:
    """``text`` (stripped) as a float, or None when it is not a number as a CSV writer writes
    one: Python's ``float`` also takes ``5_1.0`` (51.0) and non-ASCII digits (``\u0665.\u0661``,
    5.1), which no CSV writer means as numbers -- refused here. NaN and infinities are returned
    (the caller says whether they are allowed)."""
    try:
        value = float(text)
    except ValueError:
        return None
    if "_" in text or not text.isascii():
        return None
    return value


def parse_flags(text: str, where: str, error=ValueError) -> tuple[frozenset[str], list[str]]:
    """The flag words of a ``flags`` cell (``;``-separated) and those this tool does not know.
    Words are stripped of white space and lower-cased (``REJECTED``, `` rejected `` are
    ``rejected``); an unknown word is kept (it changes nothing: it is not one of NOT_FUSED).
    ``outlier=P`` must carry a probability 0 <= P <= 1 (the reading's weight is 1 - P; the run
    writes two decimals, so 1.00 for p >= 0.995): else
    ``error`` is raised naming ``where`` and the word."""
    words, unknown = set(), []
    for word in text.split(";"):
        word = word.strip().lower()
        if not word:
            continue
        if word.startswith(OUTLIER_FLAG):
            value = word[len(OUTLIER_FLAG):].strip()
            p = strict_float(value)
            if p is None or not 0 <= p <= 1:
                raise error(f"{where}: flag {word!r}: the outlier probability must be a number "
                            "from 0 to 1 (the reading's weight is 1 - p)")
            word = OUTLIER_FLAG + value
        elif word not in KNOWN_FLAGS:
            unknown.append(word)
        words.add(word)
    return frozenset(words), unknown


def unknown_flag_note(path, first: dict[str, tuple[int, int]]) -> str:
    """The one message for a file's unknown flag words: ``first`` maps each word to (the line
    where it first appears, the number of rows with it)."""
    parts = []
    for word, (line, n) in first.items():
        near = difflib.get_close_matches(word, sorted(KNOWN_FLAGS), n=1)
        parts.append(f"{word!r} on line {line}" + (f" and {n - 1} more row(s)" if n > 1 else "")
                     + (f" (did you mean {near[0]!r}?)" if near else ""))
    return (f"{path}: column flags: unknown flag word{'s' * (len(parts) > 1)} {'; '.join(parts)}. "
            "Kept, and the row is used as if the word were not there; a row is left out only "
            f"when flagged {', '.join(sorted(NOT_FUSED))} (docs/recording.md)")


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
    names = [c.strip().lower() for c in next(csv.reader([first_line]), [])]
    iflags = names.index("flags") if "flags" in names else None
    x, y, v, z, flags = [], [], [], [], []
    unknown: dict[str, tuple[int, int]] = {}
    columns = [(ix, names[ix], x), (iy, names[iy], y), (iv, value_name, v)]  # as the header
    columns += [(iz, names[iz], z)] if iz is not None else []
    with open(path, encoding="utf-8-sig", newline="") as f:
        rows = csv.reader(f, skipinitialspace=True)
        next(rows, None)
        end = rows.line_num
        for cells in rows:  # a quoted field may span lines: a row is named by its first line
            lineno, end = end + 1, rows.line_num
            if not cells or not "".join(cells).strip() or cells[0].lstrip().startswith("#"):
                continue
            if len(x) >= MAX_ROWS:
                raise TableError(f"{path}:{lineno}: more than {MAX_ROWS} rows; split the table")
            if iflags is not None:
                words, odd = parse_flags(cells[iflags] if iflags < len(cells) else "",
                                         f"{path}:{lineno}: column flags", TableError)
                flags.append(words)
                for word in odd:
                    line, n = unknown.get(word, (lineno, 0))
                    unknown[word] = (line, n + 1)
            for i, name, out in columns:
                text = cells[i].strip() if i < len(cells) else ""
                value = strict_float(text)
                if value is None:
                    raise TableError(f"{path}:{lineno}: column {name}: {text!r} is not a number "
                                     "(mm)") from None
                if not math.isfinite(value) or abs(value) > LIMIT_MM:
                    raise TableError(f"{path}:{lineno}: column {name}: {text} mm is not a "
                                     f"finite value within +-{LIMIT_MM:g} mm")
                out.append(value)
    if not x:
        raise TableError(f"{path}: a table header ({first_line.strip()!r}) but no rows")
    n = len(x)
    notes = []
    if iflags is not None:
        left_out = sum(bool(f & NOT_FUSED) for f in flags)
        notes.append(f"{path}: read as a plain table (its first line is not '# adaptive-cal "
                     f"recording v1'); its flags column is honoured: {left_out} of {n} rows "
                     f"flagged {'/'.join(sorted(NOT_FUSED))} are not used")
    if unknown:
        notes.append(unknown_flag_note(path, unknown))
    used = np.array([not (f & NOT_FUSED) for f in flags], bool) if flags else np.ones(n, bool)
    heights = np.array(v) + (np.array(z) if z else 0.0)
    steep = steep_plane_note(path, np.array(x)[used], np.array(y)[used], heights[used],
                             value_name)
    notes += [steep] if steep else []
    return {"seq": np.arange(n, dtype=float), "t_s": np.full(n, np.nan),
            "x_mm": np.array(x), "y_mm": np.array(y), "z_mm": np.array(z) if z else np.zeros(n),
            "reading_mm": np.array(v), "flags": tuple(flags),
            "meta": {"source": f"table {Path(path).name}", "column": value_name},
            "path": str(path),
            "notes": tuple(notes)}


STEEP_DEG = 5.0  # a workplane tilted more than this would leave any probe's stroke across it
WARPED = 0.01  # heights straying from their plane by this share of the plate's size: no workplane


def steep_plane_note(path, x, y, heights, name: str) -> str | None:
    """A note where the used rows' heights look like um in a mm column: their least-squares
    plane tilts more than ``STEEP_DEG``, or they stray from it by more than ``WARPED`` of the
    plate's size (an outside audit: a table in um read as a 62 deg tilt, no word; a second: a
    levelled plate's 30 um bow in um read as 31 mm of flatness, no word)."""
    a = np.column_stack([x, y, np.ones_like(x)])
    if len(x) < 3 or np.linalg.matrix_rank(a) < 3:
        return None
    coef = np.linalg.lstsq(a, heights, rcond=None)[0]
    deg = math.degrees(math.atan(math.hypot(*coef[:2])))
    extent = float(math.hypot(np.ptp(x), np.ptp(y)))
    stray = float(np.ptp(heights - a @ coef))
    if deg > STEEP_DEG:
        what = (f"the heights' least-squares plane tilts {deg:.1f} deg "
                f"({float(np.ptp(heights)):.4g} mm over {extent:.4g} mm of plate)")
    elif stray > WARPED * extent:
        what = (f"the heights stray {stray:.4g} mm from their least-squares plane over "
                f"{extent:.4g} mm of plate")
    else:
        return None
    return (f"{path}: column {name}: {what}: heights in um in a mm column? (this tool reads mm: "
            "15.3 um is 0.0153)")
