"""Recording format v1: the validating reader (writer, repair of a cut last row: ``formats.writing``).

UTF-8 CSV. Lines starting with ``#`` are metadata; the first is ``# adaptive-cal recording v1``.
Then one header line and one row per probe touch, in touch order::

    seq,t_s,x_mm,y_mm,z_mm,reading_mm[,optional columns...]

Nominal relation: reading = surface(x, y) - z_mm + probe zero + noise. Optional columns
(``temp_c``, ``j1_deg``..``j6_deg``, ``round``, ``flags``) may follow; readers ignore columns they
do not know. The writer flushes and fsyncs each row as it is taken, so a crash loses nothing.
Another tool's CSV is read as CSV (RFC 4180, ``split_cells``): a field may be quoted
(``"rejected;stroke_end"``, ``"0.000"``, a header ``"seq","t_s",...``, a note ``"a, b"`` or one
holding a line break), ``""`` is an empty field. A number is ASCII as a CSV writer writes it
(``5_1.0`` or Arabic-Indic digits, which Python's ``float`` takes, are refused). A column this
tool does not know may be named twice (it is ignored); a ``# probe_zero_mm`` that is not a number
is said and ignored. A header split by ``;`` or tabs (a spreadsheet's export) is refused, saying so.

Flags (``;``-separated in the ``flags`` column) say what the loop did with a reading:
``gated`` (failed the Mahalanobis gate: not fused, the point is taken again once), ``retake``
(the second reading at that point; fused if it passes the gate), ``surprise`` (a retake that
failed the gate too but agreed with the first reading: fused -- the surface really is there),
``rejected`` (not fused: disagreed with both, or outside the usable stroke, or too much spread),
``invalid`` (with ``rejected``: NaN or infinite, off the workplane or inside a keep-out; a NaN is
written as 0, flagged ``nonfinite``; another tool's blank or NaN on such a row is read so),
``outlier=0.12`` (its outlier probability p; weight 1 - p). Flag words are read stripped and
lower-cased; a word this tool does not know is kept and said once per file, fusing nothing.
A file whose ``#`` lines were removed (a spreadsheet's round trip) but whose first line is a
recording's header is read as a recording and says so; any other table of x, y and a reading is
read by ``formats.table``, its flags honoured alike. Notes: ``Recording.notes``, said once.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from adaptive_cal.formats.cells import (MAGIC, OPTIONAL, REQUIRED, RecordingError,  # noqa: F401
                                        _header, _number, _OpenQuote,  # (re-exported: writing,
                                        field_count_error, split_cells)  # callers)
from adaptive_cal.formats.table import (MAX_ROWS, NOT_FUSED, not_read, parse_flags,
                                        read_table, strict_float, unknown_flag_note)
from adaptive_cal.formats.cut import cut_last_row
from adaptive_cal.formats.spread import unspread
from adaptive_cal.formats.text import not_utf8, separated_hint
from adaptive_cal.formats.times import time_backwards

_SAID: set[str] = set()


def say(notes: Iterable[str], prefix: str = "warning: ") -> None:
    """Print each note on stderr once per process (a recording read again says nothing new)."""
    for note in notes:
        if note not in _SAID:
            _SAID.add(note)
            print(prefix + note, file=sys.stderr)


def surface_height_mm(reading_mm, z_mm, probe_zero_mm):
    """The surface height a reading implies (mm), inverting the nominal relation:
    height = reading - probe zero + z. The one height conversion of the package."""
    return reading_mm - probe_zero_mm + z_mm


@dataclass(frozen=True)
class Recording:
    """A recording as arrays (one entry per touch, in touch order).

    ``extra`` holds the optional numeric columns by name, ``flags`` a tuple of flag sets,
    ``meta`` the ``# key: value`` metadata lines and ``notes`` what the reader said about the
    file (a table read as a recording, unknown flag words).
    """

    seq: np.ndarray
    t_s: np.ndarray  # NaN where unknown
    x_mm: np.ndarray
    y_mm: np.ndarray
    z_mm: np.ndarray
    reading_mm: np.ndarray
    flags: tuple[frozenset[str], ...] = ()
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    meta: Mapping[str, str] = field(default_factory=dict)
    path: str | None = None
    notes: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.seq.shape[0])

    @property
    def fused(self) -> np.ndarray:
        """Boolean mask of the rows the belief fuses (not flagged gated, rejected or invalid)."""
        if not self.flags:
            return np.ones(len(self), bool)
        return np.array([not (f & NOT_FUSED) for f in self.flags], bool)

    @property
    def direction(self) -> np.ndarray:
        """Direction of arrival along x: +1 moving +x into the point, -1 moving -x, 0 unknown.

        Follows from the order of the rows (DESIGN.md); the first touch and repeats in place
        take the direction of the previous move, 0 if there is none.
        """
        d = np.zeros(len(self))
        dx = np.diff(self.x_mm)
        last = 0.0
        for i, step in enumerate(dx, start=1):
            if step > 1e-9:
                last = 1.0
            elif step < -1e-9:
                last = -1.0
            d[i] = last
        return d

    @property
    def rounds(self) -> list[float]:
        """The values of the optional ``round`` column, in the order they first appear (one
        value, or none without the column, for a recording of one round)."""
        r = self.extra.get("round")
        if r is None:
            return []
        return list(dict.fromkeys(v for v in np.asarray(r, float).tolist() if math.isfinite(v)))

    def one_round(self, what: str) -> "Recording":
        """This recording, refused (RecordingError naming the column and its values) where its
        ``round`` column holds several rounds: ``what`` (a flatness, a map) is of one surface,
        and several rounds' tilts stacked as one read as millimetres of form."""
        rounds = self.rounds
        if len(rounds) <= 1:
            return self
        shown = ", ".join(f"{v:g}" for v in rounds[:6]) + (", ..." if len(rounds) > 6 else "")
        pick = {"flatness": "pick one (flatness --round R; --compare-round R for the second of "
                "two) or ", "a report's map": "pick one (report --round R) or "}.get(what, "")
        raise RecordingError(
            f"{self.path or 'the recording'}: column round holds {len(rounds)} rounds ({shown}); "
            f"{what} is of one round's surface: {pick}give each round as its own file (the "
            "rows of one round value; explain takes every round of one file as it is)")

    def select(self, mask: np.ndarray) -> "Recording":
        """Rows where ``mask`` holds (metadata kept)."""
        mask = np.asarray(mask, bool)
        flags = tuple(f for f, m in zip(self.flags, mask) if m) if self.flags else ()
        return Recording(self.seq[mask], self.t_s[mask], self.x_mm[mask], self.y_mm[mask],
                         self.z_mm[mask], self.reading_mm[mask], flags, {k: v[mask] for k, v
                         in self.extra.items()}, self.meta, self.path, self.notes)


#: Limits of a readable recording: positions within 10 m, indications within 1 m, MAX_ROWS
#: touches (a week at 3 s each; explain: under a minute). Beyond them a value is a typo or a
#: unit error, or a file this tool cannot analyse in memory: refused with the line.
MAX_ABS_POSITION_MM = 1e4
MAX_ABS_READING_MM = 1e3
MAX_T_S = 1e8  # MAX_ROWS is formats.table's: a plain table is read as a recording
MAX_BYTES = 64 * 2**20
_LIMITS = {"x_mm": MAX_ABS_POSITION_MM, "y_mm": MAX_ABS_POSITION_MM, "z_mm": MAX_ABS_POSITION_MM,
           "reading_mm": MAX_ABS_READING_MM, "t_s": MAX_T_S, "seq": 1e15}


def _limited(text: str, column: str, where: str, blank_ok: bool = False) -> float:
    value = _number(text, where=where, blank_ok=blank_ok)
    limit = _LIMITS.get(column)
    if limit is not None and abs(value) > limit:
        raise RecordingError(f"{where}: {text.strip()!r} is beyond +-{limit:g} (a typo or a unit "
                             "error?)")
    return value


def read_recording(path: str | os.PathLike) -> Recording:
    """Read and validate a v1 recording; errors name the line number and the column.

    A byte-order mark (a spreadsheet's UTF-8) and CR / CRLF line ends are accepted. Values
    beyond the physical limits above, a header naming a column twice, more than ``MAX_ROWS``
    rows or ``MAX_BYTES`` bytes are refused with the line."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    if path.is_dir():
        raise RecordingError(f"{path}: a folder, not a recording")
    if size > MAX_BYTES:
        raise RecordingError(f"{path}: {size / 2**20:.0f} MiB; a recording this tool reads holds at "
                             f"most {MAX_ROWS} rows ({MAX_BYTES // 2**20} MiB): split it by round")
    meta: dict[str, str] = {}
    header: list[str] | None = None
    col: dict[str, int] = {}
    numeric_extra: list[str] = []
    data: dict[str, list[float]] = {c: [] for c in REQUIRED}
    extra: dict[str, list[float]] = {}
    flags: list[frozenset[str]] = []
    unknown: dict[str, tuple[int, int]] = {}  # flag word: (first line, rows)
    labels: dict[int, str] = {}  # row: a round given as text ("first", "A")
    notes: list[str] = []
    headless = False  # the first line is the header: the '#' lines were removed
    timeless = False  # the header has no t_s column: every time unknown (a blank t_s)
    prev_seq = -math.inf
    lineno = 0
    pending: str | None = None  # a row whose quoted field goes on past its line's end
    first = 0  # the line a row starts on (a quoted field may span lines): errors name it
    row_lines: list[int] = []
    cut_at, cut_row, cut_said = cut_last_row(path)
    try:
        with open(path, encoding="utf-8-sig", newline=None) as f:
            for lineno, line in enumerate(f, start=1):
                line = line.rstrip("\n")
                if pending is not None:  # inside a quoted field: the line is part of it
                    line = pending + "\n" + line
                    if '"' not in line[len(pending) + 1:]:
                        pending = line  # no quote on the new line: the field is still open
                        continue
                    pending = None
                else:
                    first, line = lineno, unspread(line)  # a spreadsheet's save: as written
                    if lineno == cut_at:  # a last row a crash cut: as --resume would mend it
                        notes.append(cut_said)
                        if (line := cut_row) is None:
                            continue
                    if lineno == 1 and line.strip() == MAGIC:
                        continue
                    if lineno == 1:
                        try:
                            names = split_cells(line, f"{path}:1")
                        except (_OpenQuote, RecordingError):
                            names = []
                        if not all(c in names for c in REQUIRED):
                            # a plain table of x, y, reading (formats.table)?
                            if (table := read_table(path, line)) is None:
                                raise RecordingError(f"{path}:1: first line must be {MAGIC!r} (or "
                                                     f"a table's x_mm,y_mm,reading_mm)"
                                                     + separated_hint(line))
                            say(table["notes"])
                            return Recording(**table)
                        headless = True  # a recording's header first: its '#' lines removed
                        notes.append(f"{path}: its first line is the header of a recording, "
                                     f"not {MAGIC!r} (were the '#' lines removed?): read as a "
                                     "recording without its metadata")
                    if line.startswith("#"):
                        _metadata(line, meta, notes, f"{path}:{lineno}")
                        continue
                    if not line.strip():
                        continue
                where = f"{path}:{first}"
                try:
                    cells = split_cells(line, where)
                except _OpenQuote:
                    pending = line
                    continue
                if header is None:
                    if "t_s" not in cells and all(c in cells for c in REQUIRED if c != "t_s"):
                        timeless, cells = True, cells + ["t_s"]  # DESIGN.md: t_s may be blank
                        notes.append(f"{where}: the header has no t_s column: every touch's time "
                                     "is read as unknown, as a blank t_s")
                    header, header_line = _header(cells, where), first
                    col = {name: i for i, name in enumerate(header)}
                    numeric_extra = [c for c in header if c not in REQUIRED and c != "flags"
                                     and header.count(c) == 1]  # a name given twice: ignored
                    extra = {c: [] for c in numeric_extra}
                    continue
                if timeless:
                    cells = cells + [""]
                if len(cells) != len(header):
                    raise field_count_error(where, len(cells) - timeless, header[:len(header)
                                            - timeless], header_line, len(row_lines))
                if len(flags if "flags" in col else data["seq"]) >= MAX_ROWS:
                    raise RecordingError(f"{where}: more than {MAX_ROWS} rows; a recording "
                                         "this tool reads holds at most that many: split it by round")
                if "flags" in col and not_read(cells[col["reading_mm"]], cells[col["flags"]]):
                    cells[col["reading_mm"]] = "0"  # as this tool writes a reading not taken
                    cells[col["flags"]] += ";nonfinite"
                for c in REQUIRED:
                    data[c].append(_limited(cells[col[c]], c, f"{where}: column {c}",
                                            blank_ok=(c == "t_s")))
                if data["t_s"][-1] < 0:
                    raise RecordingError(f"{where}: column t_s: {cells[col['t_s']]!r} is "
                                         "negative (seconds since the start of the run)")
                seq = data["seq"][-1]
                if seq != int(seq) or seq < 0:
                    raise RecordingError(f"{where}: column seq: {cells[col['seq']]!r} is "
                                         "not a non-negative integer")
                if seq <= prev_seq:
                    raise RecordingError(f"{where}: column seq: {int(seq)} does not "
                                         f"increase (previous {int(prev_seq)})")
                prev_seq = seq
                row_lines.append(first)
                for c in numeric_extra:
                    try:
                        extra[c].append(_number(cells[col[c]], where="", blank_ok=True))
                    except RecordingError:
                        extra[c].append(math.nan)  # unknown optional text columns are ignored
                        if c == "round":
                            labels[len(extra[c]) - 1] = cells[col[c]].strip()
                if "flags" in col:
                    words, odd = parse_flags(cells[col["flags"]], f"{where}: column "
                                             "flags", RecordingError)
                    flags.append(words)
                    for word in odd:
                        n_first, n = unknown.get(word, (first, 0))
                        unknown[word] = (n_first, n + 1)
        if pending is not None:
            raise RecordingError(f"{path}:{first}: a quoted field opened on this line is not "
                                 "closed by the end of the file")
    except UnicodeDecodeError:  # the decoder reads ahead of the line: name the byte itself
        raise RecordingError(not_utf8(path)) from None
    if lineno == 0:
        raise RecordingError(f"{path}:1: empty file; first line must be {MAGIC!r}")
    if header is None:
        raise RecordingError(f"{path}: no header line")
    arrays = {c: np.asarray(v, float) for c, v in data.items()}
    if headless and "flags" in col:  # the '#' lines were removed: say what the flags still do
        left_out = sum(bool(f & NOT_FUSED) for f in flags)
        notes[0] += (f"; its flags column is honoured: {left_out} of {len(flags)} rows flagged "
                     f"{'/'.join(sorted(NOT_FUSED))} are not used")
    if unknown:
        notes.append(unknown_flag_note(path, unknown))
    if labels:  # a round is a label: numbered in order of first appearance, not dropped
        keys = [labels.get(i, v) for i, v in enumerate(extra["round"])]
        codes = {k: n for n, k in enumerate(dict.fromkeys(
            k for k in keys if isinstance(k, str) or math.isfinite(k)))}
        extra["round"] = [codes.get(k, math.nan) for k in keys]
        notes.append(f"{path}: column round holds labels: rounds numbered in order of first "
                     "appearance, " + ", ".join(f"{k} = {n}" for k, n in list(codes.items())[:6]))
    notes += [n for n in [time_backwards(path, arrays["t_s"], extra.get("round"), row_lines)] if n]
    say(notes)
    return Recording(arrays["seq"].astype(np.int64), arrays["t_s"], arrays["x_mm"],
                     arrays["y_mm"], arrays["z_mm"], arrays["reading_mm"], tuple(flags),
                     {c: np.asarray(v, float) for c, v in extra.items()}, meta, str(path),
                     tuple(notes))


def _metadata(line: str, meta: dict[str, str], notes: list[str], where: str) -> None:
    """A ``# key: value`` line into ``meta``. DESIGN.md defines no key; this tool reads
    ``probe_zero_mm`` (mm): a value that is not a number (``5.0 mm``, ``unknown``, another
    tool's words) is said once and ignored -- heights are then relative, as without it -- but a
    number beyond +-1,000 mm is refused (a typo or a unit error)."""
    key, sep, value = line[1:].partition(":")
    if not sep:
        return
    key, value = key.strip(), value.strip()
    if key == "probe_zero_mm":
        number = strict_float(value)
        if number is None or math.isnan(number):
            notes.append(f"{where}: metadata probe_zero_mm: {value!r} is not a number (mm); "
                         "ignored (heights are then relative, as without it)")
            meta.pop(key, None)
            return
        _limited(value, "reading_mm", f"{where}: probe_zero_mm")
    meta[key] = value
