"""What is wrong with a file's text, for the readers' errors: where it stops being UTF-8, a
header separated by something other than commas (standard library only)."""
from __future__ import annotations

from pathlib import Path


def not_utf8(path, data: bytes | None = None) -> str:
    """"PATH:LINE: not UTF-8 text (byte 0xNN, byte K of the line: REASON)" for the first byte of
    the file (``data``: its bytes, read again when None) that is not UTF-8. A reader decoding a
    stream learns of the bad byte a chunk ahead of the line it is on: this finds the byte itself."""
    data = Path(path).read_bytes() if data is None else data
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        column = e.start - data.rfind(b"\n", 0, e.start)
        return (f"{path}:{line}: not UTF-8 text (byte 0x{data[e.start]:02x}, byte {column} of the "
                f"line: {e.reason})")
    return f"{path}: not UTF-8 text"


def separated_hint(line: str, what: str = "recording format") -> str:
    """": it looks separated by ';': save it comma separated (DESIGN.md recording format)" where
    a header line is split by ';' (a European spreadsheet's export) or by tabs rather than by
    commas -- more of those than commas; "" otherwise. For the readers' header errors; ``what``:
    the DESIGN.md section the file's format is in."""
    for sep, name in ((";", "';'"), ("\t", "tabs")):
        if line.count(sep) >= 2 and line.count(sep) > line.count(","):
            return f": it looks separated by {name}: save it comma separated (DESIGN.md {what})"
    return ""
