"""Toolpaths to compensate: G-code (G0/G1, G21 mm, G90 absolute) or a CSV of points
(``x_mm,y_mm,z_mm``, other columns kept). Pure text in, text out.

``read_toolpath(text, name)`` returns a ``Toolpath``: the file's lines and its moves, each with
its absolute end point (modal coordinates resolved) and the point it starts from (None where an
axis is not known yet). ``write_toolpath(path, pieces, marks)`` gives the text back with each
move replaced by its pieces: in G-code the original line carries the first piece (its other
words and comments kept) and the rest follow as ``G1 X Y Z`` lines; in a CSV the inserted rows
come before the original row and copy its other columns. Every other line is kept verbatim.
Anything not understood is refused with ``ToolpathError`` naming the line.
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass

Point = tuple  # (x_mm, y_mm, z_mm), None where not known yet

# G codes that change nothing we compensate (plane, mm, cutter comp off, length offset, work
# offsets, path mode, canned cycle off, absolute, feed per minute, dwell)
HARMLESS_G = {4, 17, 21, 40, 43, 49, 54, 55, 56, 57, 58, 59, 61, 64, 80, 90, 94}
REFUSED_G = {
    2: "G2 (clockwise arc): arcs are not supported; post-process the path into G1 lines",
    3: "G3 (counter-clockwise arc): arcs are not supported; post-process the path into G1 lines",
    20: "G20 (inches): only millimetres (G21) are supported",
    91: "G91 (relative coordinates): only absolute coordinates (G90) are supported",
    92: "G92 (coordinate offset): shifting the coordinates is not supported",
    28: "G28 (return home through a point): not supported",
    53: "G53 (machine coordinates): not supported; the map is in the workplane frame",
}
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_EXPONENT = re.compile(r"[eE][-+]?\d")  # right after a number: 1.5e2 is no G-code number
# axis words of other machines: rotary A B C, parallel U V W, arc centre I J K and radius R, and
# E, the extruder axis of RepRap-style controllers (Marlin, RepRapFirmware, Klipper)
OTHER_AXES = "ABCEUVWIJKR"
_COMMENT = re.compile(r"\([^)]*\)|;.*$")
DIGITS = 4  # written coordinates: 0.1 um


class ToolpathError(ValueError):
    """A toolpath this tool cannot read or does not support; the message names the line."""


@dataclass(frozen=True)
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


def fmt(value: float) -> str:
    return f"{value:.{DIGITS}f}"


def read_toolpath(text: str, name: str = "program") -> Toolpath:
    """G-code unless the first line is a CSV header naming x_mm, y_mm and z_mm."""
    text = text.lstrip("\ufeff")
    first = [f.strip().lower() for f in text.split("\n", 1)[0].split(",")]
    if "x_mm" in first:
        return _read_csv(text, name)
    return _read_gcode(text, name)


def _newline(text: str) -> tuple[str, bool]:
    return ("\r\n" if "\r\n" in text else "\n"), text.endswith(("\n", "\r"))


def _words(line: str, where: str) -> list[tuple[str, float, tuple[int, int]]]:
    """(letter, value, span in the line) of each word outside comments; anything else refused."""
    code = _COMMENT.sub(lambda m: " " * len(m.group()), line)
    if "(" in code or ")" in code:
        raise ToolpathError(f"{where}: unbalanced parenthesis comment")
    out, pos = [], 0
    for m in _WORD.finditer(code):
        gap = code[pos:m.start()].strip()
        if gap and gap != "%":
            raise ToolpathError(f"{where}: cannot read {gap[:30]!r} (expressions, parameters and "
                                "block delete are not supported)")
        if _EXPONENT.match(code, m.end()):
            word = code[m.start():_EXPONENT.match(code, m.end()).end()]
            raise ToolpathError(f"{where}: {word.strip()!r} is exponent notation, not a G-code "
                                "number: write the value in plain decimals (150 for 1.5e2)")
        out.append((m.group(1).upper(), float(m.group(2)), m.span()))
        pos = m.end()
    gap = code[pos:].strip()
    if gap and gap != "%":
        raise ToolpathError(f"{where}: cannot read {gap[:30]!r}")
    return out


def _read_gcode(text: str, name: str) -> Toolpath:
    newline, final = _newline(text)
    lines = text.splitlines()
    pos: list = [None, None, None]
    mode = None  # 0 or 1 once set
    moves = []
    for i, line in enumerate(lines):
        where = f"{name} line {i + 1}"
        words = _words(line, where)
        gs = [v for k, v, _ in words if k == "G"]
        for g in gs:
            if g in REFUSED_G:
                raise ToolpathError(f"{where}: {REFUSED_G[g]}")
            if g not in (0, 1) and g not in HARMLESS_G:
                raise ToolpathError(f"{where}: G{g:g} is not supported (supported: G0, G1 and "
                                    f"G{', G'.join(str(c) for c in sorted(HARMLESS_G))})")
        if 4 in gs:  # dwell: its X/P is a time, not a position
            continue
        axes = {}
        for k, v, _ in words:
            if k in "XYZ":
                if k in axes:
                    raise ToolpathError(f"{where}: axis word {k} given twice ({k}{axes[k]:g} and "
                                        f"{k}{v:g}): give each axis once on a line")
                axes[k] = v
        other = sorted({k for k, _, _ in words if k in OTHER_AXES})
        if other:  # on any line: a move of another axis alone moves the machine too
            raise ToolpathError(f"{where}: axis words {', '.join(other)} are not supported "
                                "(only X, Y, Z straight moves" + (
                                    "; E is an extruder axis" if "E" in other else "") + ")")
        motion = [g for g in gs if g in (0, 1)]
        if len(motion) > 1:
            raise ToolpathError(f"{where}: two motion codes on one line")
        if motion:
            mode = int(motion[0])
        if not axes:
            continue
        if mode is None:
            raise ToolpathError(f"{where}: coordinates before any G0 or G1")
        for k, v in axes.items():
            if not math.isfinite(v):
                raise ToolpathError(f"{where}: {k} is not a finite number")
        start = tuple(pos)
        for j, k in enumerate("XYZ"):
            if k in axes:
                pos[j] = axes[k]
        moves.append(Move(i, i + 1, mode == 1, start, tuple(pos)))
    return Toolpath("gcode", lines, moves, newline, final)


def _read_csv(text: str, name: str) -> Toolpath:
    newline, final = _newline(text)
    rows = list(csv.reader(io.StringIO(text)))
    header = [h.strip() for h in rows[0]]
    for j, h in enumerate(header):
        if h and h in header[:j]:
            raise ToolpathError(f"{name} line 1: column {h!r} given twice (columns "
                                f"{header.index(h) + 1} and {j + 1}): give each column once")
    try:
        cols = tuple(header.index(k) for k in ("x_mm", "y_mm", "z_mm"))
    except ValueError:
        raise ToolpathError(f"{name} line 1: a point CSV needs the columns x_mm, y_mm, z_mm; "
                            f"got {', '.join(header)}") from None
    moves, prev = [], None  # the first point starts nothing: it is a point, not a move
    for i, row in enumerate(rows[1:], start=1):
        if not row or all(not f.strip() for f in row):
            continue
        where = f"{name} line {i + 1}"
        if len(row) != len(header):
            raise ToolpathError(f"{where}: {len(row)} fields, the header has {len(header)}")
        point = []
        for c, k in zip(cols, ("x_mm", "y_mm", "z_mm")):
            try:
                v = float(row[c])
            except ValueError:
                raise ToolpathError(f"{where}: {k} {row[c]!r} is not a number") from None
            if not math.isfinite(v):
                raise ToolpathError(f"{where}: {k} {row[c]!r} is not finite")
            point.append(v)
        moves.append(Move(i, i + 1, True, prev, tuple(point)))
        prev = tuple(point)
    return Toolpath("csv", rows, moves, newline, final, cols)


def _replace_words(line: str, values: dict) -> str:
    """The line with its X/Y/Z words set to ``values`` (letter -> mm): existing words replaced in
    place, missing ones inserted after the last axis word (or before the first comment)."""
    spans = {k: span for k, _, span in _words(line, "line") if k in "XYZ"}
    out = line
    for k in sorted(spans, key=lambda k: -spans[k][0]):  # right to left: spans stay valid
        if k in values:
            a, b = spans[k]
            out = out[:a] + k + fmt(values[k]) + out[b:]
    extra = " ".join(k + fmt(values[k]) for k in "XYZ" if k in values and k not in spans)
    if not extra:
        return out
    axis_ends = [span[1] for k, _, span in _words(out, "line") if k in "XYZ"]
    if axis_ends:
        at = max(axis_ends)
    else:
        comment = _COMMENT.search(out)
        at = len(out[:comment.start()].rstrip()) if comment else len(out.rstrip())
    tail = out[at:]
    return out[:at] + " " + extra + (tail if not tail or tail[0].isspace() else " " + tail)


def write_toolpath(path: Toolpath, pieces: dict, marks: dict | None = None,
                   header_comment: str | None = None, note_column: str = "compensate_note") -> str:
    """The toolpath as text with ``pieces[item]`` (a list of (x, y, z) mm, the last one the
    move's end) in place of each listed move, ``marks[item]`` a note on that move's line(s),
    ``header_comment`` a first comment line (G-code only)."""
    marks = marks or {}
    if path.kind == "csv":
        return _write_csv(path, pieces, marks, note_column)
    out = []
    for i, line in enumerate(path.lines):
        if i == 0 and header_comment and not line.strip().startswith("%"):
            out.append(f"({header_comment})")
        note = f" ({marks[i]})" if i in marks else ""
        if i in pieces:
            first, *rest = pieces[i]
            # unsplit: only Z changes (X, Y as written, or modal); split: the first piece in full
            given = {k: v for k, v in zip("XYZ", first) if v is not None and (rest or k == "Z")}
            out.append(_replace_words(line, given) + note)
            out += [f"G1 X{fmt(x)} Y{fmt(y)} Z{fmt(z)}{note}" for x, y, z in rest]
        else:
            out.append(line + note)
        if i == 0 and header_comment and line.strip().startswith("%"):
            out.append(f"({header_comment})")
    return path.newline.join(out) + (path.newline if path.final_newline else "")


def _write_csv(path: Toolpath, pieces: dict, marks: dict, note_column: str) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator=path.newline)
    header = list(path.lines[0]) + ([note_column] if marks else [])
    w.writerow(header)
    cx, cy, cz = path.columns
    for i, row in enumerate(path.lines[1:], start=1):
        note = [marks.get(i, "")] if marks else []
        if i not in pieces:
            w.writerow(list(row) + note)
            continue
        *before, last = pieces[i]
        for x, y, z in before:
            new = list(row)
            new[cx], new[cy], new[cz] = fmt(x), fmt(y), fmt(z)
            w.writerow(new + note)
        new = list(row)
        new[cz] = fmt(last[2])
        w.writerow(new + note)
    return buf.getvalue()
