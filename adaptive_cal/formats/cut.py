"""A recording's last row cut by a crash mid-write: what ``--resume`` puts in its place
(``_completed``; ``formats.writing`` repairs the file with it) and what a reader that does not
write takes instead (``cut_last_row``: ``flatness``, ``explain``, ``report``). Imports nothing of
the reader, which calls it."""
from __future__ import annotations

from adaptive_cal.formats.cells import (MAGIC, REQUIRED, RecordingError, _number, _OpenQuote,
                                        split_cells)
from adaptive_cal.formats.table import KNOWN_FLAGS, NOT_FUSED

_WRITTEN_DECIMALS = {"t_s": 3, "x_mm": 4, "y_mm": 4, "z_mm": 4, "reading_mm": 6}


def cut_last_row(path) -> tuple[int | None, str | None, str]:
    """For a reader that does not write (``flatness``, ``explain``, ``report``): (the line number
    of a last row a crash cut, the row ``--resume`` would put in its place or None where it
    would drop it, what is done in words); (None, None, "") where the last row is whole. The file
    is not changed. Until 2026-11-29 the readers used such a row as it was (an outside audit: a
    reading cut from 2.077597 to 2.07 mm moved the noise and the flatness, with no word)."""
    try:
        with open(path, "rb") as f:  # the last byte first: a whole file is not read twice
            if f.seek(0, 2) == 0:
                return None, None, ""
            f.seek(-1, 2)
            if f.read(1) in (b"\n", b"\r"):
                return None, None, ""
            f.seek(0)
            data = f.read()
    except OSError:
        return None, None, ""  # the reader says what is wrong
    start = data.rfind(b"\n") + 1
    before = data[:start].decode("utf-8", "replace").lstrip("\ufeff")
    header = _header_line(before)
    if not before.startswith(MAGIC) or header is None:
        return None, None, ""
    tail = data[start:].decode("utf-8", "replace")
    row, _, what = _completed(header, tail)
    if what == "whole":  # every field there: the last may still be cut short (another tool's
        row, what = _shorter_than_before(header, before, tail)  # file, its reading last)
        if what is None:
            return None, None, ""
    line = before.count("\n") + 1
    return line, row, (f"{path}:{line}: the last row lacks its line end, cut by a crash "
                       f"mid-write: {what}, here as `adaptive-cal run --resume` would (the file "
                       "is left as it is)")


def _shorter_than_before(header: str, before: str, tail: str) -> tuple[str | None, str | None]:
    """A whole last row whose last number has fewer decimals than every row before it, where
    those all have the same count (a writer of fixed decimals; one that trims zeros, 5.1 after
    5.123, says nothing of a cut): (the row to read instead -- None where that field is
    required, else the row with it blank -- what was done); (tail, None) where nothing says it
    was cut."""
    rows = [l for l in before.splitlines() if l.strip() and not l.startswith("#")][1:]
    if len(rows) < 2 or '"' in tail or any('"' in r for r in rows[-20:]):
        return tail, None
    text, prev = tail.rsplit(",", 1)[-1].strip(), rows[-1].rsplit(",", 1)[-1].strip()
    try:
        float(text), float(prev)
    except ValueError:
        return tail, None
    counts = {len(r.rsplit(",", 1)[-1].strip().partition(".")[2]) for r in rows[-20:]}
    if len(counts) > 1 or len(text.partition(".")[2]) >= len(prev.partition(".")[2]):
        return tail, None
    name = header.rsplit(",", 1)[-1].strip()
    said = f"its {name} {text!r} has fewer decimals than the row before's ({prev!r}): it may be cut"
    if name in REQUIRED:
        return None, f"dropped, {said}"
    return tail[:tail.rfind(",") + 1], f"kept with {name} left blank, {said}"


def _header_line(text: str) -> str | None:
    return next((l for l in text.splitlines() if l.strip() and not l.startswith("#")), None)


def _completed(header: str, line: str) -> tuple[str | None, str, str]:
    """(the row to write instead of the cut ``line``, or None to drop it; the text dropped;
    what was done, in words). ``line`` itself when it is whole."""
    try:
        names = split_cells(header, "header")
    except (_OpenQuote, RecordingError):
        return None, line, f"dropped, the header is not a CSV row ({_shown(line)})"
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
        return None, line, f"dropped, a quoted row cut mid-write ({_shown(line)})"
    cells = line.split(",")
    if (line.startswith("#") or len(cells) > len(names) or not all(c in names for c in REQUIRED)
            or any(names.index(c) >= len(cells) for c in REQUIRED)):
        return None, line, f"dropped, a required number is missing ({_shown(line)})"
    try:
        for c in REQUIRED:
            _number(cells[names.index(c)], where=c, blank_ok=(c == "t_s"))
    except RecordingError:
        return None, line, f"dropped, a required field is not a number ({_shown(line)})"
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


def _shown(line: str) -> str:
    """The start of a dropped line for a message, a run of NUL bytes (a power loss pads a file
    with them) said as its count, not as dozens of escapes."""
    import re

    text = re.sub("\x00+", lambda m: f"<{len(m.group())} NUL bytes>", line)
    return repr(text[:80])
