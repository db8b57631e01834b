"""A recording's line as a spreadsheet writes it back (standard library only): Excel and
LibreOffice save a CSV they opened with every row as wide as the widest, so a ``#`` line gains
trailing empty cells (``# adaptive-cal recording v1,,,,,,,``), a blank line becomes a row of
commas, and "quote all text cells" quotes the ``#`` lines (``"# flags: ..."``). ``unspread``
gives the line as written. Until 2026-11-29 such a round trip was refused as "a recording
version this adaptive-cal does not read" (an outside audit); docs/recording.md says a
spreadsheet's export is read."""
from __future__ import annotations

import csv


def unspread(line: str) -> str:
    """``line`` (no line end) as the writer wrote it: BOMs a second save put before it dropped,
    a ``#`` line's trailing empty cells and quotes removed, a row of separators alone -> ''.
    A data row or header is returned as it is (their quotes are CSV's, read as such)."""
    text = line.lstrip("\ufeff")
    bare = text.strip()
    if bare and not bare.strip(",;\t "):
        return ""  # a blank line, widened to the table by the spreadsheet
    if bare.startswith('"#'):
        try:
            cells = next(csv.reader([bare]))
        except (csv.Error, StopIteration):
            return text
        return ",".join(c for c in cells if c.strip())
    if bare.startswith("#"):
        return bare.rstrip(",; \t")
    return text
