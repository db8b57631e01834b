"""Toolpaths to compensate: G-code (G0/G1, G21 mm, G90 absolute) or a CSV of points
(``x_mm,y_mm,z_mm``, other columns kept). Pure text in, text out.

``read_toolpath(text, name)`` returns a ``Toolpath``: the file's lines and its moves, each with
its absolute end point (modal coordinates resolved) and the point it starts from (None where an
axis is not known yet). ``write_toolpath(path, pieces, marks)`` gives the text back with each
move replaced by its pieces: in G-code the original line carries the first piece (its other
words and comments kept) and the rest follow as ``G1 X Y Z`` lines; in a CSV the inserted rows
come before the original row and copy its other columns. Every other line is kept verbatim.
Anything not understood is refused with ``ToolpathError`` naming the line.

What a controller could read otherwise is refused too (a wrong Z at a machine tool crashes a
cutter): a subprogram call or return (M98, M97, M99, M198: the called code would run from the
call's position, not from the one the text gives), motion after the program's end (M2, M30),
axis words on a dwell line (G4: a time on a Fanuc, a move on Grbl), a second work offset (the
map is one plate in one frame), and a control character other than a tab inside a line (a form feed or NEL in a comment is a new block to some readers; only
LF, CRLF -- or CR in a file without LF -- end a line). Axis words without a decimal point are
read as mm, as LinuxCNC, Grbl and Mach3 do (``whole_numbers`` lists them: on a Fanuc-type control
without decimal-point programming they are thousandths, and the command says so); a move before
the program says G21 and G90 is read as mm and absolute (``assumed``: the command says so, as a
control left in inches or incremental would read the heights added 25.4 x or relative).
"""
from __future__ import annotations

import csv
import math
import re

from adaptive_cal.formats.toolpath_base import (DIGITS, Move, Point, Toolpath,  # noqa: F401
                                                ToolpathError, fmt, newline_of)
from adaptive_cal.formats.toolpath_csv import read_csv_toolpath, write_csv_toolpath

# G codes that change nothing we compensate (plane, mm, cutter comp off, length offset, work
# offsets, path mode, canned cycle off, absolute, feed per minute, dwell)
HARMLESS_G = {4, 17, 21, 40, 43, 49, 54, 55, 56, 57, 58, 59, 61, 64, 80, 90, 94}
WORK_OFFSETS = {54, 55, 56, 57, 58, 59}
REFUSED_M = {97: "M97 (local subprogram call)", 98: "M98 (subprogram call)",
             99: "M99 (subprogram return or program loop)", 198: "M198 (external subprogram call)"}
PROGRAM_END_M = {2, 30}
#: M codes a control runs after the line's motion: stop, optional stop, end, pallet change
AFTER_MOTION_M = {0, 1, 2, 30, 60}
# inside a line: control characters other than a tab (some readers end a block at them)
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f\x85\u2028\u2029]")
REFUSED_G = {
    2: "G2 (clockwise arc): arcs are not supported; post-process the path into G1 lines",
    3: "G3 (counter-clockwise arc): arcs are not supported; post-process the path into G1 lines",
    20: "G20 (inches): only millimetres (G21) are supported",
    91: "G91 (relative coordinates): only absolute coordinates (G90) are supported",
    92: "G92 (coordinate offset): shifting the coordinates is not supported",
    28: "G28 (return home through a point): not supported",
    53: "G53 (machine coordinates): not supported; the map is in the workplane frame",
}
# ASCII only: a control reads no Arabic-Indic digit or no-break space (Python's \d and \s would)
_WORD = re.compile(r"([A-Za-z])[ \t]*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")
_EXPONENT = re.compile(r"[eE][-+]?\d")  # right after a number: 1.5e2 is no G-code number
# a line of words and blanks alone, no exponent after a number: ``_words``'s quick path
_PLAIN = re.compile(r"(?:[ \t]*[A-Za-z][ \t]*[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?![eE][-+]?[0-9]))*"
                    r"[ \t]*")
# axis words of other machines: rotary A B C, parallel U V W, arc centre I J K and radius R, and
# E, the extruder axis of RepRap-style controllers (Marlin, RepRapFirmware, Klipper)
OTHER_AXES = "ABCEUVWIJKR"
_COMMENT = re.compile(r"\([^)]*\)|;.*$")
#: the header comment a compensated program carries (``Toolpath.compensated``: compensate refuses
#: such a program, whose heights would be added twice)
MADE_BY = re.compile(r"\(adaptive-cal [^)]* compensate,")


def read_toolpath(text: str, name: str = "program") -> Toolpath:
    """G-code unless the first line is a CSV header naming x_mm, y_mm and z_mm."""
    bom = text.startswith("\ufeff")
    text = text[1:] if bom else text
    line = re.split(r"\r\n|\n|\r", text, maxsplit=1)[0].strip()
    first = [f.strip().lower() for f in next(csv.reader([line]), [])]
    if "x_mm" in first:
        return read_csv_toolpath(text, name, bom)
    if any("x_mm" in [f.strip().strip('"').lower() for f in line.split(sep)]
           for sep in (";", "\t")):  # a header, but not of a comma-separated file
        raise ToolpathError(f"{name} line 1: {line[:60]!r} looks like a point table's header, but "
                            "a point CSV is comma-separated with the header x_mm,y_mm,z_mm")
    return _read_gcode(text, name, bom)


def _words(line: str, where: str) -> list[tuple[str, float, tuple[int, int]]]:
    """(letter, value, span in the line) of each word outside comments; anything else refused."""
    if _PLAIN.fullmatch(line):  # words alone (most lines): nothing to refuse, read them at once
        return [(m.group(1).upper(), float(m.group(2)), m.span()) for m in _WORD.finditer(line)]
    code = _COMMENT.sub(lambda m: " " * len(m.group()), line)
    if "(" in code or ")" in code:
        raise ToolpathError(f"{where}: unbalanced parenthesis comment")
    out, pos = [], 0
    if code.strip(" \t") == "%":  # the tape mark: a line of its own (inside a line it ends the
        return out                 # record on a Fanuc, and a reader drops the words after it)
    for m in _WORD.finditer(code):
        gap = code[pos:m.start()].strip(" \t")
        if "%" in gap:
            raise ToolpathError(f"{where}: '%' inside a line: the tape mark stands on a line of "
                                "its own (a Fanuc ends the record there, and readers drop the "
                                "words after it)")
        if gap:
            raise ToolpathError(f"{where}: cannot read {_token(code, pos, gap)[:30]!r} (expressions, "
                                "parameters and block delete are not supported)")
        if _EXPONENT.match(code, m.end()):
            word = code[m.start():_EXPONENT.match(code, m.end()).end()]
            raise ToolpathError(f"{where}: {word.strip()!r} is exponent notation, not a G-code "
                                "number: write the value in plain decimals (150 for 1.5e2)")
        out.append((m.group(1).upper(), float(m.group(2)), m.span()))
        pos = m.end()
    gap = code[pos:].strip(" \t")
    if "%" in gap:
        raise ToolpathError(f"{where}: '%' inside a line: the tape mark stands on a line of its "
                            "own")
    if gap:
        hint = ("; a point table (CSV) needs the header line x_mm,y_mm,z_mm first"
                if "," in line and re.fullmatch(r"[\s\w.,+-]*", line) else "")
        raise ToolpathError(f"{where}: cannot read {_token(code, pos, gap)[:30]!r}{hint}")
    return out


def _token(code: str, pos: int, gap: str) -> str:
    """What cannot be read, with the word it is stuck to ('X1.0.5', not '.5')."""
    start = pos + (len(code[pos:]) - len(code[pos:].lstrip(" \t")))
    if start != pos or pos == 0 or code[pos - 1] in " \t":
        return gap
    while start > 0 and code[start - 1] not in " \t":
        start -= 1
    end = pos
    while end < len(code) and code[end] not in " \t":
        end += 1
    return code[start:end]


def _lines(text: str) -> list[str]:
    """The lines as a controller ends its blocks: at LF (a CR before it dropped), or at CR in a
    file without any LF -- not at a form feed, NEL or U+2028 as ``str.splitlines`` would."""
    if "\n" not in text:
        parts = text.split("\r")
    else:
        parts = [p[:-1] if p.endswith("\r") else p for p in text.split("\n")]
    return parts[:-1] if parts and parts[-1] == "" else parts


def _read_gcode(text: str, name: str, bom: bool = False) -> Toolpath:
    newline, final = newline_of(text)
    lines = _lines(text)
    pos: list = [None, None, None]
    mode = None  # 0 or 1 once set
    moves, whole, offset, ended, assumed, blend, made = [], [], None, None, set(), None, None
    said = {21: None, 90: None}  # the line each was first given on
    for i, line in enumerate(lines):
        where = f"{name} line {i + 1}"
        bad = _CONTROL.search(line)
        if bad:
            raise ToolpathError(f"{where}: control character U+{ord(bad.group()):04X} inside the "
                                "line (some controls start a new block there, some do not): "
                                "remove it")
        words = _words(line, where)
        gs = [v for k, v, _ in words if k == "G"]
        for g in gs:
            if g in REFUSED_G:
                raise ToolpathError(f"{where}: {REFUSED_G[g]}")
            if g not in (0, 1) and g not in HARMLESS_G:
                raise ToolpathError(f"{where}: G{g:g} is not supported (supported: G0, G1 and "
                                    f"G{', G'.join(str(c) for c in sorted(HARMLESS_G))})")
            if g in said and said[g] is None:
                said[g] = i + 1
            if g in WORK_OFFSETS:
                if offset is not None and offset[0] != g:
                    raise ToolpathError(
                        f"{where}: G{g:g} after G{offset[0]:g} (line {offset[1]}): the map is one "
                        "plate in one frame; compensate each work offset's part with its own map")
                offset = offset or (g, i + 1)
        for k, v, _ in words:
            if k == "M" and v in REFUSED_M:
                raise ToolpathError(f"{where}: {REFUSED_M[v]} is not supported: the called code "
                                    "runs from the call's position, not the one the text gives; "
                                    "expand the subprogram into the program")
        if made is None and MADE_BY.search(line):
            made = (i + 1, line.strip())
        if 64 in gs:  # path blending: the control may leave the path by up to P, and LinuxCNC
            # merges nearly collinear points (the splits) within Q (P where no Q is given)
            tol = max([v for k, v, _ in words if k in "PQ"], default=0.0)
            if blend is None or tol > blend[1]:
                blend = (i + 1, tol)
        if 4 in gs and any(k in "XYZ" for k, _, _ in words):
            # dwell: its P (or a Fanuc's X) is a time, on Grbl an X/Y/Z is a move too
            raise ToolpathError(f"{where}: axis words on a dwell (G4) line: a time on some "
                                "controls, a move on others; give the dwell with P alone")
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
        if axes and ended:
            raise ToolpathError(f"{where}: a move after the program's end (M2/M30 at line "
                                f"{ended}): a subprogram or a second program; give one program")
        if ended is None and any(k == "M" and v in PROGRAM_END_M for k, v, _ in words):
            ended = i + 1  # a move on the end's own line still runs
        if not axes:
            continue
        if mode is None:
            raise ToolpathError(f"{where}: {', '.join(sorted(axes))} before any G0 or G1: a move "
                                "in no motion mode yet (a G43 H1 Z50. moves in the modal one); "
                                "give G0 on that line, or a G0 move before it")
        assumed |= {f"G{g}" for g, at in said.items() if at is None}
        whole += [(i + 1, line[a:b].strip()) for k, _, (a, b) in words
                  if k in "XYZ" and "." not in line[a:b]]
        for k, v in axes.items():
            if not math.isfinite(v):
                raise ToolpathError(f"{where}: {k} is not a finite number")
        start = tuple(pos)
        for j, k in enumerate("XYZ"):
            if k in axes:
                pos[j] = axes[k]
        moves.append(Move(i, i + 1, mode == 1, start, tuple(pos)))
    return Toolpath("gcode", lines, moves, newline, final, bom=bom, whole_numbers=tuple(whole),
                    assumed=tuple(sorted(assumed)), blend=blend, compensated=made)


def _replace_words(line: str, values: dict) -> str:
    """The line with its X/Y/Z words set to ``values`` (letter -> mm): existing words replaced in
    place, missing ones inserted after the last axis word (or before the first comment)."""
    spans = {k: span for k, _, span in _words(line, "line") if k in "XYZ"}
    out, grown = line, {}
    for k in sorted(spans, key=lambda k: -spans[k][0]):  # right to left: spans stay valid
        if k in values:
            a, b = spans[k]
            word = k + fmt(values[k])
            out = out[:a] + word + out[b:]
            grown[k] = len(word) - (b - a)
    extra = " ".join(k + fmt(values[k]) for k in "XYZ" if k in values and k not in spans)
    if not extra:
        return out
    if spans:  # where the last axis word ends now: its end moved by every word replaced up to it
        last = max(spans, key=lambda k: spans[k][0])
        at = spans[last][1] + sum(grown.values())
    else:
        comment = _COMMENT.search(out)
        at = len(out[:comment.start()].rstrip()) if comment else len(out.rstrip())
    tail = out[at:]
    return out[:at] + " " + extra + (tail if not tail or tail[0].isspace() else " " + tail)


def _plain(text: str) -> str:
    """A note as a G-code comment holds it everywhere: no ';' (a comment to some readers), '%'
    (the tape mark) or parentheses."""
    return (text.replace("%", "pct").replace(";", ",").replace("(", "[").replace(")", "]"))


def write_toolpath(path: Toolpath, pieces: dict, marks: dict | None = None,
                   header_comment: str | None = None, note_column: str = "compensate_note") -> str:
    """The toolpath as text with ``pieces[item]`` (a list of (x, y, z) mm, the last one the
    move's end) in place of each listed move, ``marks[item]`` a note on that move's line(s),
    ``header_comment`` a first comment line (G-code only)."""
    marks = marks or {}
    bom = "\ufeff" if path.bom else ""
    if path.kind == "csv":
        return bom + write_csv_toolpath(path, pieces, marks, note_column)
    out = []
    # the header comment after a leading % and O number (a Fanuc or Haas loads a program by its
    # O number on its first line), else first
    lead = 0
    while (lead < len(path.lines) and header_comment
           and re.match(r"\s*(%|[Oo]\d)", path.lines[lead]) and lead < 2):
        lead += 1
    rapid = {m.item for m in path.moves if not m.cut}  # a rapid's pieces stay rapids
    for i, line in enumerate(path.lines):
        if i == lead and header_comment:
            out.append(f"({header_comment})")
        note = f" ({_plain(marks[i])})" if i in marks else ""
        if i in pieces:
            first, *rest = pieces[i]
            # unsplit: only Z changes (X, Y as written, or modal); split: the first piece in full
            given = {k: v for k, v in zip("XYZ", first) if v is not None and (rest or k == "Z")}
            # a stop or the program's end acts after the line's motion: it goes with the last
            # piece (on the first, the program would end 25 mm into a 200 mm cut)
            after = [(span, v) for k, v, span in (_words(line, "line") if rest else ())
                     if k == "M" and v in AFTER_MOTION_M]
            for (a, b), _ in sorted(after, reverse=True):
                tail = line[b:].strip()
                line = line[:a].rstrip() + (" " + tail if tail else "")
            ends = "".join(f" M{v:g}" for _, v in after)
            out.append(_replace_words(line, given) + note)
            g = "G0" if i in rapid else "G1"
            out += [f"{g} X{fmt(x)} Y{fmt(y)} Z{fmt(z)}{ends if j == len(rest) - 1 else ''}{note}"
                    for j, (x, y, z) in enumerate(rest)]
        else:
            out.append(line + note)
    if lead == len(path.lines) and header_comment:
        out.append(f"({header_comment})")
    return bom + path.newline.join(out) + (path.newline if path.final_newline else "")
