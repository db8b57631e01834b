"""What the G-code and the CSV toolpath readers share (``formats.toolpath`` re-exports it): the
error, a move, the toolpath, how a coordinate is written and which line end a file uses."""
from __future__ import annotations

from dataclasses import dataclass

Point = tuple  # (x_mm, y_mm, z_mm), None where not known yet
DIGITS = 4  # written coordinates: 0.1 um


class ToolpathError(ValueError):
    """A toolpath this tool cannot read or does not support; the message names the line."""


@dataclass(frozen=True, slots=True)  # slots: a million-line program holds a million
class Move:
    """One straight move: ``cut`` (G1 or a CSV row) or a rapid (G0); ``item``: its index in
    ``Toolpath.lines``; ``line``: its 1-based line number in the file; ``start``: None for a
    CSV's first point (a point, not a move)."""

    item: int
    line: int
    cut: bool
    start: Point
    end: Point


@dataclass(frozen=True)
class Toolpath:
    kind: str  # "gcode" or "csv"
    lines: list  # G-code: the lines; CSV: the rows (lists of fields), header first
    moves: list
    newline: str = "\n"
    final_newline: bool = True
    columns: tuple = ()  # CSV: indices of x_mm, y_mm, z_mm
    bom: bool = False  # the file began with a UTF-8 byte order mark (written back)
    whole_numbers: tuple = ()  # G-code: (line, word) of axis words without a decimal point
    assumed: tuple = ()  # G-code: "G21", "G90" where a move came before the program said it
    # G-code: (line, mm) of the largest G64 P or Q (path blending: the control may leave the
    # path, or merge split points, by up to it), or None
    blend: tuple | None = None
    # G-code: (line, text) of adaptive-cal's own header comment -- the program is an output of
    # compensate -- or None
    compensated: tuple | None = None


def fmt(value: float) -> str:
    return f"{value:.{DIGITS}f}"


def newline_of(text: str) -> tuple[str, bool]:
    """The file's line end (CRLF, LF, or CR in a file without LF) and whether it ends with one:
    written back as read."""
    if "\r\n" in text:
        end = "\r\n"
    else:
        end = "\r" if "\r" in text and "\n" not in text else "\n"
    return end, text.endswith(("\n", "\r"))
