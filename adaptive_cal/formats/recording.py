"""Recording format v1: append-only writer, validating reader.

UTF-8 CSV. Lines starting with ``#`` are metadata; the first is ``# adaptive-cal recording v1``.
Then one header line and one row per probe touch, in touch order::

    seq,t_s,x_mm,y_mm,z_mm,reading_mm[,optional columns...]

Nominal relation: reading = surface(x, y) - z_mm + probe zero + noise. Optional columns
(``temp_c``, ``j1_deg``..``j6_deg``, ``round``, ``flags``) may follow; readers ignore columns they
do not know. The writer flushes and fsyncs each row as it is taken, so a crash loses nothing.

Flags (``;``-separated in the ``flags`` column) say what the loop did with a reading:
``gated`` (failed the Mahalanobis gate: not fused, the point is taken again once), ``retake``
(the second reading at that point; fused if it passes the gate), ``surprise`` (a retake that
failed the gate too but agreed with the first reading: fused -- the surface really is there),
``rejected`` (not fused: disagreed with both, or outside the usable stroke, or too much spread),
``invalid`` (with ``rejected``: NaN or infinite, off the workplane or inside a keep-out; a
non-finite value is written as 0 and flagged ``nonfinite``), ``outlier=0.12`` (the reading's
posterior outlier probability, two decimals; a fused reading carries the weight 1 - p).
Flag words are read stripped of white space and lower-cased (a hand edit's `` Rejected``); a
word this tool does not know is kept and said once per file (``warning:`` on stderr, with its
line), and changes nothing about what is fused.

A file whose ``#`` lines were removed (a spreadsheet's round trip) but whose first line is a
recording's header is read as a recording, flags and all, and says so; any other table of
x, y and a reading is read by ``formats.table``, its ``flags`` column honoured the same way.
What the reader has to say is in ``Recording.notes`` and is printed once (``say``).
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from adaptive_cal.formats.table import (KNOWN_FLAGS, MAX_ROWS, NOT_FUSED, parse_flags,
                                        read_table, unknown_flag_note)

MAGIC = "# adaptive-cal recording v1"
REQUIRED = ("seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm")
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


class RecordingError(ValueError):
    """A recording that cannot be read: the message names the file, line and column."""


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

    def select(self, mask: np.ndarray) -> "Recording":
        """Rows where ``mask`` holds (metadata kept)."""
        mask = np.asarray(mask, bool)
        flags = tuple(f for f, m in zip(self.flags, mask) if m) if self.flags else ()
        return Recording(self.seq[mask], self.t_s[mask], self.x_mm[mask], self.y_mm[mask],
                         self.z_mm[mask], self.reading_mm[mask], flags,
                         {k: v[mask] for k, v in self.extra.items()}, self.meta, self.path,
                         self.notes)


def _number(text: str, *, where: str, blank_ok: bool = False) -> float:
    text = text.strip()
    if text == "":
        if blank_ok:
            return math.nan
        raise RecordingError(f"{where}: empty value")
    try:
        value = float(text)
    except ValueError:
        raise RecordingError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise RecordingError(f"{where}: {text!r} is not a finite number")
    return value


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
    notes: list[str] = []
    prev_seq = -math.inf
    lineno = 0
    try:
        with open(path, encoding="utf-8-sig", newline=None) as f:
            for lineno, line in enumerate(f, start=1):
                line = line.rstrip("\n")
                if lineno == 1 and line.strip() == MAGIC:
                    continue
                if lineno == 1 and not all(c in [h.strip() for h in line.split(",")]
                                           for c in REQUIRED):
                    # a plain table of x, y, reading (formats.table)?
                    if (table := read_table(path, line)) is None:
                        raise RecordingError(f"{path}:1: first line must be {MAGIC!r}"
                                             " (or a table's x_mm,y_mm,reading_mm)")
                    say(table["notes"])
                    return Recording(**table)
                if lineno == 1:  # a recording's header first: its '#' lines were removed
                    notes.append(f"{path}: its first line is the header of a recording, not "
                                 f"{MAGIC!r} (were the '#' lines removed?): read as a recording "
                                 "without its metadata")
                if line.startswith("#"):
                    key, sep, value = line[1:].partition(":")
                    if sep:
                        meta[key.strip()] = value.strip()
                        if key.strip() == "probe_zero_mm":
                            _limited(value, "reading_mm", f"{path}:{lineno}: probe_zero_mm")
                    continue
                if not line.strip():
                    continue
                cells = [c.strip() for c in line.split(",")]
                if header is None:
                    header = _header(cells, f"{path}:{lineno}")
                    col = {name: i for i, name in enumerate(header)}
                    numeric_extra = [c for c in header if c not in REQUIRED and c != "flags"]
                    extra = {c: [] for c in numeric_extra}
                    continue
                if len(cells) != len(header):
                    raise RecordingError(
                        f"{path}:{lineno}: {len(cells)} fields, the header has {len(header)}")
                if len(flags if "flags" in col else data["seq"]) >= MAX_ROWS:
                    raise RecordingError(f"{path}:{lineno}: more than {MAX_ROWS} rows; a recording "
                                         "this tool reads holds at most that many: split it by round")
                for c in REQUIRED:
                    where = f"{path}:{lineno}: column {c}"
                    data[c].append(_limited(cells[col[c]], c, where, blank_ok=(c == "t_s")))
                if data["t_s"][-1] < 0:
                    raise RecordingError(f"{path}:{lineno}: column t_s: {cells[col['t_s']]!r} is "
                                         "negative (seconds since the start of the run)")
                seq = data["seq"][-1]
                if seq != int(seq) or seq < 0:
                    raise RecordingError(f"{path}:{lineno}: column seq: {cells[col['seq']]!r} is "
                                         "not a non-negative integer")
                if seq <= prev_seq:
                    raise RecordingError(f"{path}:{lineno}: column seq: {int(seq)} does not "
                                         f"increase (previous {int(prev_seq)})")
                prev_seq = seq
                for c in numeric_extra:
                    try:
                        extra[c].append(_number(cells[col[c]], where="", blank_ok=True))
                    except RecordingError:
                        extra[c].append(math.nan)  # unknown optional text columns are ignored
                if "flags" in col:
                    words, odd = parse_flags(cells[col["flags"]], f"{path}:{lineno}: column "
                                             "flags", RecordingError)
                    flags.append(words)
                    for word in odd:
                        first, n = unknown.get(word, (lineno, 0))
                        unknown[word] = (first, n + 1)
    except UnicodeDecodeError as e:
        raise RecordingError(f"{path}:{lineno + 1}: not UTF-8 text ({e.reason} at byte "
                             f"{e.start} of the line)") from None
    if lineno == 0:
        raise RecordingError(f"{path}:1: empty file; first line must be {MAGIC!r}")
    if header is None:
        raise RecordingError(f"{path}: no header line")
    arrays = {c: np.asarray(v, float) for c, v in data.items()}
    if notes and "flags" in col:  # the '#' lines were removed: say what the flags still do
        left_out = sum(bool(f & NOT_FUSED) for f in flags)
        notes[0] += (f"; its flags column is honoured: {left_out} of {len(flags)} rows flagged "
                     f"{'/'.join(sorted(NOT_FUSED))} are not used")
    if unknown:
        notes.append(unknown_flag_note(path, unknown))
    say(notes)
    return Recording(arrays["seq"].astype(np.int64), arrays["t_s"], arrays["x_mm"],
                     arrays["y_mm"], arrays["z_mm"], arrays["reading_mm"], tuple(flags),
                     {c: np.asarray(v, float) for c, v in extra.items()}, meta, str(path),
                     tuple(notes))


def _header(cells: list[str], where: str) -> list[str]:
    """The header's column names: every required one, none twice (which would be read?)."""
    missing = [c for c in REQUIRED if c not in cells]
    if missing:
        raise RecordingError(f"{where}: header lacks column(s) {', '.join(missing)}")
    twice = sorted({c for c in cells if cells.count(c) > 1})
    if twice:
        raise RecordingError(f"{where}: header names column(s) {', '.join(twice)} more than once")
    return cells


#: decimals the writer gives each required number: a cut row whose last field is one of these
#: is complete only when it has them all (``5.01`` may be the start of ``5.010300``)
_WRITTEN_DECIMALS = {"t_s": 3, "x_mm": 4, "y_mm": 4, "z_mm": 4, "reading_mm": 6}


def cut_file(path: str | os.PathLike) -> Path:
    """Where the text a repair drops is kept: ``recording.cut.txt`` beside ``recording.csv``."""
    path = Path(path)
    return path.with_name(path.stem + ".cut.txt")


def repair_cut_row(path: str | os.PathLike) -> str | None:
    """Repair a recording whose last line lacks its newline (a crash mid-write); returns the
    text dropped from it, None when nothing was (``repair_cut_row_said`` says what was done)."""
    return _repair(path)[0]


def repair_cut_row_said(path: str | os.PathLike) -> str | None:
    """``repair_cut_row``, returning the message for the user (None when nothing was cut)."""
    return _repair(path)[1]


def _repair(path) -> tuple[str | None, str | None]:
    """A last line without its newline is a row cut by a crash mid-write. Where every required
    field is there in full, the row is completed: a cut optional field is left blank, a cut
    flags word dropped; where its flags could have held ``rejected`` or ``gated`` (they were
    cut before those words' place in the writer's sorted order), the row is flagged
    ``cut;rejected`` besides, never fused: a reading must not be fused on a guess. Else (a
    required number missing or possibly cut) the row is dropped. The original line is first
    appended to ``cut_file(path)`` (never overwritten). Earlier rows are never touched, and a
    file that is not a recording with a header before its last line is left as it is (the
    reader then says what is wrong with it). Idempotent."""
    path = Path(path)
    data = path.read_bytes() if path.exists() else b""
    if not data or data.endswith(b"\n"):
        return None, None
    start = data.rfind(b"\n") + 1
    before = data[:start].decode("utf-8", "replace").lstrip("\ufeff")
    header = _header_line(before)
    if not before.startswith(MAGIC) or header is None:
        return None, None
    tail = data[start:].decode("utf-8", "replace")
    lineno = before.count("\n") + 1
    where = f"{path}:{lineno}"
    row, dropped, what = _completed(header, tail)
    if row == tail:  # a whole row that only lacks its newline
        with open(path, "ab") as f:
            f.write(b"\n")
            f.flush()
            os.fsync(f.fileno())
        return None, None
    kept = cut_file(path)
    with open(kept, "a", encoding="utf-8") as f:  # first: the text is safe before it goes
        f.write(f"# {path.name} line {lineno}, cut by a crash mid-write; {what}:\n{tail}\n")
        f.flush()
        os.fsync(f.fileno())
    with open(path, "r+b") as f:
        f.truncate(start)
        if row is not None:
            f.seek(start)
            f.write((row + "\n").encode("utf-8"))
        f.flush()
        os.fsync(f.fileno())
    return dropped, f"{where}: the last row was cut by a crash mid-write: {what} (the line as it was is kept in {kept})"


def _header_line(text: str) -> str | None:
    return next((l for l in text.splitlines() if l.strip() and not l.startswith("#")), None)


def _completed(header: str, line: str) -> tuple[str | None, str, str]:
    """(the row to write instead of the cut ``line``, or None to drop it; the text dropped;
    what was done, in words). ``line`` itself when it is whole."""
    names = [h.strip() for h in header.split(",")]
    cells = line.split(",")
    if (line.startswith("#") or len(cells) > len(names) or not all(c in names for c in REQUIRED)
            or any(names.index(c) >= len(cells) for c in REQUIRED)):
        return None, line, f"dropped, a required number is missing ({line[:80]!r})"
    try:
        for c in REQUIRED:
            _number(cells[names.index(c)], where=c, blank_ok=(c == "t_s"))
    except RecordingError:
        return None, line, f"dropped, a required field is not a number ({line[:80]!r})"
    if len(cells) == len(names):
        return line, "", "whole"
    last = len(cells) - 1  # the field the crash cut
    name, text = names[last], cells[last].strip()
    if name in REQUIRED:
        decimals = _WRITTEN_DECIMALS.get(name)
        frac = text.partition(".")[2]
        if decimals is None or len(frac) != decimals or not frac.isdigit():
            return None, line, (f"dropped, its {name} {text!r} may itself be cut (the writer "
                                f"gives {decimals or 'an unknown number of'} decimals)")
    flag_col = names.index("flags") if "flags" in names else None
    words, cut_word, said = [], "", []
    if flag_col is not None and flag_col <= last:
        written = cells[flag_col]
        if flag_col == last:  # the flags were cut: the last word may be part of one
            parts = [w.strip() for w in written.split(";")]
            words, cut_word = [w for w in parts[:-1] if w], parts[-1]
            if cut_word.lower() in KNOWN_FLAGS:  # whole: only the ';' after it may be cut
                words, cut_word = words + [cut_word], ""
            elif cut_word:
                said.append(f"the cut flags word {cut_word!r} dropped")
            # The writer sorts its words, so the words cut off come after the last one read
            # (the cut word's whole is at or after it): none of them can be 'rejected' or 'gated'
            # when that lies past max(NOT_FUSED) in the sorted order.
            low = [w.lower() for w in words]
            if cut_word:
                could_follow = max(NOT_FUSED) >= cut_word.lower()
            else:
                could_follow = not low or max(NOT_FUSED) > low[-1]
            unsure = not (set(low) & NOT_FUSED) and (could_follow or low != sorted(low))
        else:
            words, unsure = [w for w in written.split(";") if w.strip()], False
    else:  # cut before its flags: what the loop decided about the reading is not known
        unsure = flag_col is not None
    if unsure:
        words += ["cut", "rejected"]
        said.append("its flags are not known in full, so it is flagged cut;rejected and not "
                    "fused (edit the flags after checking the reading to use it)")
    out = [c.strip() for c in cells] + [""] * (len(names) - len(cells))
    if name not in REQUIRED and last != flag_col and text:
        said.append(f"its cut {name} {text!r} left blank")
        out[last] = ""
    if flag_col is not None:
        out[flag_col] = ";".join(sorted(dict.fromkeys(w.strip() for w in words)))
    dropped = cut_word if last == flag_col else (text if name not in REQUIRED else "")
    what = "kept, its required fields whole" + ("; " + "; ".join(said) if said else
                                                 "; the fields after them left blank")
    return ",".join(out), dropped, what


class RecordingWriter:
    """Append-only v1 writer: every row is flushed and fsynced as it is written.

    Opening an existing recording appends to it (``--resume``); its header must match, and a
    row cut by a crash is repaired first (``repair_cut_row``).
    """

    COLUMNS = REQUIRED + ("flags",)

    def __init__(self, path: str | os.PathLike, meta: Mapping[str, str] | None = None,
                 extra_columns: Iterable[str] = ()):
        self.path = Path(path)
        self.columns = self.COLUMNS + tuple(extra_columns)
        exists = self.path.exists() and self.path.stat().st_size > 0
        if exists:
            header = next((l for l in self.path.read_text(encoding="utf-8").splitlines()
                           if l.strip() and not l.startswith("#")), "")
            if tuple(h.strip() for h in header.split(",")) != self.columns:
                raise RecordingError(f"{self.path}: cannot append, its header {header!r} differs "
                                     f"from {','.join(self.columns)!r}")
            repair_cut_row(self.path)  # a row cut by a crash mid-write
            self._file = open(self.path, "a", encoding="utf-8", newline="")
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "w", encoding="utf-8", newline="")
            self._file.write(MAGIC + "\n")
            for k, v in (meta or {}).items():
                self._file.write(f"# {k}: {v}\n")
            self._file.write(",".join(self.columns) + "\n")
            self._sync()

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def append(self, *, seq: int, t_s: float | None, x_mm: float, y_mm: float, z_mm: float,
               reading_mm: float, flags: Iterable[str] = (), **extra: float) -> None:
        """Write one touch and flush it to disk before returning."""
        unknown = set(extra) - set(self.columns)
        if unknown:
            raise KeyError(f"recording has no column(s) {sorted(unknown)}")
        values = {"seq": str(int(seq)),
                  "t_s": "" if t_s is None or not math.isfinite(t_s) else f"{t_s:.3f}",
                  "x_mm": f"{x_mm:.4f}", "y_mm": f"{y_mm:.4f}", "z_mm": f"{z_mm:.4f}",
                  "reading_mm": f"{reading_mm:.6f}", "flags": ";".join(sorted(flags))}
        for k, v in extra.items():
            values[k] = "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.6g}"
        self._file.write(",".join(values.get(c, "") for c in self.columns) + "\n")
        self._sync()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
