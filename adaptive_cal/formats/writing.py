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

import numpy as np

from adaptive_cal.formats.recording import (MAGIC, REQUIRED, RecordingError, _number, _OpenQuote,
                                            split_cells)
from adaptive_cal.formats.cut import _completed, _header_line, cut_last_row  # noqa: F401



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
    """``repair_cut_row``, then ``restore_unwritten``: the message for the user (None when
    nothing was done)."""
    said = [restore_unwritten(path), _repair(path)[1]]  # the row's cut start, then another
    said = [m for m in said + [restore_unwritten(path)] if m]
    return "; ".join(said) or None


def unwritten_file(path: str | os.PathLike) -> Path:
    """Where a row the recording could not take (a full disk) is kept: beside it."""
    path = Path(path)
    return path.with_name(path.stem + ".unwritten.csv")


def _keep_unwritten(path: Path, columns, line: str) -> Path | None:
    """Append a row the recording could not take to ``unwritten_file`` (a new, small file: a
    file-size limit or a disk with a little room left takes it); None where it could not."""
    target = unwritten_file(path)
    try:
        new = not target.exists()
        with open(target, "a", encoding="utf-8") as f:
            if new:
                f.write(",".join(columns) + "\n")
            f.write(line + "\n")
            f.flush()
            os.fsync(f.fileno())
        return target
    except OSError:
        return None


def restore_unwritten(path: str | os.PathLike) -> str | None:
    """Write the rows a full disk kept out of the recording (``unwritten_file``, same columns)
    back at its end -- those whose seq follows its last row -- then rename that file
    ``*.restored.csv`` (kept). An outside audit: the row was printed, a resume dropped its cut
    part and wrote another touch under its seq, and the reading was lost. The message, or
    None when there was nothing to restore."""
    from adaptive_cal.formats.recording import read_recording

    path, src = Path(path), unwritten_file(path)
    if not src.exists() or not path.exists():
        return None
    lines = [ln for ln in src.read_text(encoding="utf-8").splitlines() if ln.strip()]
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):  # cut mid-write: the start of a row kept here?
        start = data.rfind(b"\n") + 1
        tail = data[start:].decode("utf-8", "replace")
        if not any(ln.startswith(tail) for ln in lines[1:]):
            return None  # another cut: ``_repair`` first
        with open(cut_file(path), "a", encoding="utf-8") as f:  # first: the text is safe
            f.write(f"# {path.name}: the start of a row kept whole in {src.name}:\n{tail}\n")
            f.flush()
            os.fsync(f.fileno())
        with open(path, "r+b") as f:
            f.truncate(start)
            f.flush()
            os.fsync(f.fileno())
    text = path.read_text(encoding="utf-8-sig")
    header = _header_line(text)
    if not lines or header is None or lines[0].split(",") != header.split(","):
        return f"{src}: not written back into {path} (its columns differ): add its rows by hand"
    seq, rec = lines[0].split(",").index("seq"), read_recording(path)
    last = int(rec.seq[-1]) if len(rec) else -1
    rows = [ln for ln in lines[1:] if int(ln.split(",")[seq]) > last]
    newline = "\r\n" if "\r\n" in text[:text.find("\n") + 1] else "\n"
    with open(path, "a", encoding="utf-8", newline="") as f:
        f.writelines(ln + newline for ln in rows)
        f.flush()
        os.fsync(f.fileno())
    src.rename(src.with_name(src.stem + ".restored.csv"))
    return (f"{path}: {len(rows)} row{'s' * (len(rows) != 1)} a full disk had kept out of it "
            f"written back from {src} (seq {', '.join(ln.split(',')[seq] for ln in rows)})")


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


class RecordingWriter:
    """Append-only v1 writer: every row is flushed and fsynced as it is written.

    Opening an existing recording appends to it (``--resume``); its header must match, and a
    row cut by a crash is repaired first (``repair_cut_row``).
    """

    COLUMNS = REQUIRED + ("flags",)
    rows_written = 0  # by this writer

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
        line = ",".join(values.get(c, "") for c in self.columns)
        try:
            self._file.write(line + self.newline)
            self._sync()
            self.rows_written += 1
        except OSError as e:  # a full disk, a file-size limit: the reading kept, or said
            kept = _keep_unwritten(self.path, self.columns, line)
            where = (f"kept in {kept}: make room, then continue with --resume, which writes it "
                     "back" if kept is not None else "add it at the recording's end by hand, "
                     "make room, then continue with --resume")
            raise OSError(e.errno, f"touch seq {int(seq)} could not be written "
                          f"({e.strerror or e}); its row, taken and not in the recording, "
                          f"reads {line} ({','.join(self.columns)}); {where} (a part of the "
                          "row already written is kept in recording.cut.txt and not fused)",
                          str(self.path)) from e

    def close(self) -> None:
        if not self._file.closed:
            try:
                self._file.close()
            except OSError:  # the buffer of a row whose append failed, already reported
                pass

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def rows_digest(rec, n: int) -> str:
    """SHA-256 of a recording's first ``n`` rows as read (seq, t_s, x, y, z, reading, flags;
    not the text: a CRLF or a BOM changes nothing): belief.npz keeps the digest of the rows its
    map was made from, so a row deleted or edited since is seen (an outside audit: a deleted
    row's reading stayed in the map, and report and flatness said nothing)."""
    import hashlib

    h = hashlib.sha256()
    for a in (rec.seq, rec.t_s, rec.x_mm, rec.y_mm, rec.z_mm, rec.reading_mm):
        h.update(np.ascontiguousarray(np.asarray(a, float)[:n]).tobytes())
    for f in rec.flags[:n]:
        h.update((";".join(sorted(f)) + "\n").encode())
    return h.hexdigest()
