"""Writing a recording: the append-only writer (``RecordingWriter``, every row flushed and
fsynced as it is written) and the repair of a last row a crash cut mid-write (``--resume``, and
the writer before it appends, do it first).

A row whose required fields are whole is kept (its cut optional fields left blank, a cut flag
word dropped, and where that word could have been ``rejected`` or ``gated`` the row is written
``cut;rejected``: a stroke-end placeholder is never fused on a guess); otherwise the cut text is
dropped. Whatever is dropped is first appended to ``recording.cut.txt`` beside the recording.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Iterable, Mapping

from adaptive_cal.formats.recording import (MAGIC, REQUIRED, RecordingError, _number, _OpenQuote,
                                            split_cells)
from adaptive_cal.formats.table import KNOWN_FLAGS, NOT_FUSED

_WRITTEN_DECIMALS = {"t_s": 3, "x_mm": 4, "y_mm": 4, "z_mm": 4, "reading_mm": 6}


def provenance() -> dict[str, str]:
    """Which software wrote a file and when: {"software": "adaptive-cal VERSION",
    "written_utc": ISO 8601 to the second}, the keys result.json and the other JSON outputs
    carry (a recording's metadata says ``started_utc``), so a measurement can be traced to the
    code that made it (a figure changes with the version)."""
    import datetime

    from adaptive_cal import __version__

    now = datetime.datetime.now(datetime.timezone.utc)
    return {"software": f"adaptive-cal {__version__}",
            "written_utc": now.strftime("%Y-%m-%dT%H:%M:%SZ")}


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
    try:
        names = split_cells(header, "header")
    except (_OpenQuote, RecordingError):
        return None, line, f"dropped, the header is not a CSV row ({line[:80]!r})"
    if '"' in line:  # another tool's quoted row (the writer quotes nothing): kept only if whole
        try:
            quoted = split_cells(line, "row")
        except (_OpenQuote, RecordingError):
            quoted = []
        if len(quoted) == len(names) and all(c in names for c in REQUIRED):
            try:
                for c in REQUIRED:
                    _number(quoted[names.index(c)], where=c, blank_ok=(c == "t_s"))
                return line, "", "whole"
            except RecordingError:
                pass
        return None, line, f"dropped, a quoted row cut mid-write ({line[:80]!r})"
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
        self.newline = "\n"
        exists = self.path.exists() and self.path.stat().st_size > 0
        if exists:  # read as the reader does (a byte-order mark, CRLF line ends accepted)
            text = self.path.read_bytes().decode("utf-8-sig", "replace")
            header = next((l for l in text.splitlines()
                           if l.strip() and not l.startswith("#")), "")
            try:
                names = tuple(split_cells(header, str(self.path)))
            except _OpenQuote:
                names = ()
            if sorted(names) != sorted(self.columns):
                raise RecordingError(f"{self.path}: cannot append, its columns {header!r} are not "
                                     f"those this run writes ({','.join(self.columns)!r}): "
                                     "continue it in a new folder")
            self.columns = names  # appended in the file's own column order and line ends
            self.newline = "\r\n" if "\r\n" in text[:text.find("\n") + 1] else "\n"
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
        self._file.write(",".join(values.get(c, "") for c in self.columns) + self.newline)
        self._sync()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
