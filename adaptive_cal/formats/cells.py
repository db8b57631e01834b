"""The cells of one recording row: CSV as RFC 4180 has it (``split_cells``) and strict numbers
(``number``), with RecordingError naming where a value is wrong (``formats.recording``)."""
from __future__ import annotations

import csv
import math

# a quoted field may be as long as a file this tool reads (64 MiB), not csv's 128 KiB (an
# unknown column holding a long note is ignored, quoted or not)
csv.field_size_limit(max(csv.field_size_limit(), 64 * 2**20))

from adaptive_cal.formats.table import strict_float
from adaptive_cal.formats.text import separated_hint

MAGIC = "# adaptive-cal recording v1"
REQUIRED = ("seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm")
#: the optional columns DESIGN.md names: each, like a required one, may be named only once
OPTIONAL = ("temp_c",) + tuple(f"j{i}_deg" for i in range(1, 7)) + ("round", "flags")


class RecordingError(ValueError):
    """A recording that cannot be read: the message names the file, line and column."""


def _number(text: str, *, where: str, blank_ok: bool = False) -> float:
    text = text.strip()
    if text == "":
        if blank_ok:
            return math.nan
        raise RecordingError(f"{where}: empty value")
    value = strict_float(text)
    if value is None:
        raise RecordingError(f"{where}: {text!r} is not a number")
    if not math.isfinite(value):
        raise RecordingError(f"{where}: {text!r} is not a finite number")
    return value


class _OpenQuote(Exception):
    """A line ends inside a quoted field: the field (and the row) goes on on the next line."""


def split_cells(line: str, where: str) -> list[str]:
    """The fields of one CSV row (RFC 4180: ``"a, b"`` is one field, ``""`` inside quotes is
    ``"``), each stripped of white space. Lines without a quote are split on ``,`` (the fast
    path: a 10^5-row recording reads in under a second); others go through ``csv`` (strict:
    text after a closing quote is refused naming ``where``). Raises _OpenQuote when the line
    ends inside a quoted field."""
    if '"' not in line:
        return [c.strip() for c in line.split(",")]
    try:
        cells = next(csv.reader((line,), skipinitialspace=True, strict=True), [])
    except csv.Error as e:
        if "unexpected end of data" in str(e):
            raise _OpenQuote from None
        raise RecordingError(f"{where}: not a CSV row ({e}): {line[:80]!r}") from None
    return [c.strip() for c in cells]


def _header(cells: list[str], where: str) -> list[str]:
    """The header's column names: every required one, none of those DESIGN.md names twice
    (which would be read?). Another name given twice is allowed: unknown columns are ignored."""
    missing = [c for c in REQUIRED if c not in cells]
    if missing:
        hint = separated_hint(",".join(cells))  # a spreadsheet's ';' or tabs: one cell
        if not hint and all(c in [n.lower() for n in cells] for c in missing):
            hint = f" (column names are lower case, as DESIGN.md has them: {', '.join(missing)})"
        raise RecordingError(f"{where}: header lacks column(s) {', '.join(missing)}{hint}")
    twice = sorted({c for c in cells if cells.count(c) > 1 and c in REQUIRED + OPTIONAL})
    if twice:
        raise RecordingError(f"{where}: header names column(s) {', '.join(twice)} more than once")
    return cells


def field_count_error(where: str, fields: int, header: list[str], header_line: int,
                      rows_read: int) -> RecordingError:
    """A row whose field count is not the header's. On the first row the header may be the one
    edited (a column added or removed by hand): the message says so and names the header's
    line instead of blaming the row alone."""
    said = f"{where}: {fields} fields, the header (line {header_line}) has {len(header)}"
    if rows_read == 0:
        said += (f" ({','.join(header)}): the first row already disagrees, so the header or "
                 "the rows were edited -- a column added to or removed from one of them")
    return RecordingError(said)
