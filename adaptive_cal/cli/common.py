"""What every command shares, kept free of heavy imports so ``--help`` stays fast."""
from __future__ import annotations

import argparse
from pathlib import Path


class UserError(Exception):
    """An error the user can fix; printed without a traceback."""


class DefaultsShown(argparse.HelpFormatter):
    """Appends "(default: X)" to an option's help only where X is a real default: not for
    required options, flags (store_true/false), or options whose default is None or suppressed,
    and not where the help already places ``%(default)``."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("%(default)" in text or action.required or default is None or default is False
                or default is argparse.SUPPRESS or action.nargs == 0):
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return text + " (default: %(default)s)"
        return text


def at_least(minimum: int, maximum: int | None = None, why: str = ""):
    """argparse type: an integer of at least ``minimum`` (and at most ``maximum``: ``why`` says
    why); argparse names the option and the value ("argument --seed: -1 is below 0") instead of
    failing later inside numpy, or running for hours."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is below {minimum}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{value} is above {maximum}{why}")
        return value
    return parse


def seconds(positive: bool):
    """argparse type: a finite time in s, > 0 (``positive``) or >= 0."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid number of seconds: {text!r}") from None
        if not (value > 0 if positive else value >= 0) or value == float("inf"):
            raise argparse.ArgumentTypeError(
                f"{text} s: must be a finite time {'above' if positive else 'of at least'} 0 s")
        return value
    return parse


RECORDING_MAGIC = "# adaptive-cal recording v1"  # formats.recording.MAGIC (kept stdlib-only here)
RECORDING_FORMAT = (
    "A recording is a UTF-8 CSV: first line '# adaptive-cal recording v1', more '#' lines of "
    "metadata, one header line with the columns seq, t_s, x_mm, y_mm, z_mm, reading_mm (more "
    "may follow), then one row per touch; or a plain table whose first line names x_mm, y_mm "
    "and reading_mm or height_mm. The format: docs/recording.md")


def _first_line(path: Path) -> str:
    """The file's first line; UserError naming it when it cannot be read (permissions): say so,
    not "not a recording"."""
    try:
        with path.open(encoding="utf-8", errors="replace") as f:
            from adaptive_cal.formats.spread import unspread  # a spreadsheet's save: as written

            return unspread(f.readline().rstrip("\r\n")).strip()
    except OSError as e:
        raise UserError(f"{path}: cannot be read ({e.strerror or e})") from None


BINARY = ((b"\x1f\x8b", "a gzip-compressed file (decompress it first)"),
          (b"PK\x03\x04", "a zip archive (an .xlsx workbook is one: save the sheet as "
                          "'CSV UTF-8')"),
          (b"\xd0\xcf\x11\xe0", "an Office binary file (.xls: save the sheet as 'CSV UTF-8')"),
          (b"\x89PNG", "a PNG image"), (b"%PDF", "a PDF document"),
          (b"\xff\xd8\xff", "a JPEG image"))


def binary_kind(head: bytes) -> str | None:
    """What a file's first bytes say it is when it is no text at all (a compressed file, a
    workbook, an image: until 2026-11-29 all were called UTF-16 text); None for text, UTF-16
    included (a NUL beside most ASCII bytes)."""
    for magic, kind in BINARY:
        if head.startswith(magic):
            return kind
    if b"\x00" in head and not head.startswith((b"\xff\xfe", b"\xfe\xff")):
        if max(head[0::2].count(0), head[1::2].count(0)) < 0.3 * len(head) / 2:
            return "a binary file (NUL bytes among the others, not UTF-16 text)"
    return None


def check_recording(path: str) -> None:
    """A recording argument that is a folder or another CSV: say what is wanted instead of the
    reader's first-line error. A missing file is left to the reader ("no such file")."""
    p = Path(path)
    if p.is_dir():
        hint = f": {p / 'recording.csv'}" if (p / "recording.csv").exists() else ""
        raise UserError(f"{p} is a folder; give the recording file inside it{hint}")
    if not p.is_file():
        return
    line = _first_line(p)
    if line.startswith("# adaptive-cal recording") and line != RECORDING_MAGIC:
        raise UserError(f"{p}: {line!r} is a recording version this adaptive-cal does not read. "
                        + RECORDING_FORMAT)
    from adaptive_cal.formats.table import table_columns

    if line != RECORDING_MAGIC and table_columns(line) is None:
        head = p.read_bytes()[:4096]
        if (kind := binary_kind(head)) is not None:
            raise UserError(f"{p}: not CSV text but {kind}. " + RECORDING_FORMAT)
        if head.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in head:
            raise UserError(f"{p}: UTF-16 text (a spreadsheet's 'Unicode text'), not UTF-8: save "
                            "it as 'CSV UTF-8'. " + RECORDING_FORMAT)
        try:
            head.decode("utf-8")
        except UnicodeDecodeError as e:
            if e.start < len(head) - 4:  # not a character cut at the end of the 4 kB read
                from adaptive_cal.formats.text import not_utf8

                raise UserError(not_utf8(p) + ". " + RECORDING_FORMAT) from None
        for sep, name in ((";", "semicolons"), ("\t", "tabs")):
            if sep in line and table_columns(line.replace(sep, ",")) is not None:
                raise UserError(f"{p}: its columns are separated by {name} "
                                f"({line[:60]!r}); a recording or table separates them by "
                                "commas, with a point as the decimal mark. " + RECORDING_FORMAT)
        raise UserError(f"{p} is not an adaptive-cal recording (its first line is {line[:60]!r}). "
                        + RECORDING_FORMAT)


def check_cell_file(path: str, option: str = "--robot") -> None:
    """A recording (or another CSV) given where the cell file is expected."""
    p = Path(path)
    if p.is_dir():
        hint = f" (this folder has one: {p / 'cell.yaml'})" if (p / "cell.yaml").exists() else ""
        raise UserError(f"{option} {p}: a folder; {option} takes the cell file (YAML){hint}")
    if not p.is_file():
        return
    if _first_line(p).startswith("# adaptive-cal recording"):
        raise UserError(f"{option} {p}: this is a recording, not a cell file. {option} takes the "
                        "cell's YAML file (e.g. configs/sim-cell.yaml, or the cell.yaml a run "
                        "copies into its folder)")
    if p.suffix.lower() == ".csv":
        raise UserError(f"{option} {p}: a CSV file, not a cell file. {option} takes the cell's "
                        "YAML file (e.g. configs/sim-cell.yaml)")


#: a run folder's measurement: never overwritten by an output of report, explain or compensate
RUN_FILES = ("recording.csv", "result.json", "belief.npz", "cell.yaml")


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)  # a hard link
    except OSError:
        return False


def check_writable(option: str, out) -> None:
    """UserError naming ``option`` unless a file can be made where ``out`` goes: its nearest
    existing parent is a folder (not a file), and a scratch file is made and removed there
    (folders still missing are made later, by the writer). For outputs written at the end of long work, checked before it starts (an
    outside audit: --json /proc/x.json failed after the whole study, naming a temporary file)."""
    import tempfile

    folder = next((q for q in Path(out).absolute().parents if q.exists()), None)
    if folder is None:
        return
    if not folder.is_dir():
        raise UserError(f"{option} {out}: {folder} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".adaptive-cal-check-"):
            pass
    except OSError as e:
        raise UserError(f"{option} {out}: cannot write in {folder} "
                        f"({e.strerror or type(e).__name__}); give another place") from None


def refuse_input_as_output(option: str, out, inputs, folders=(), also=()) -> None:
    """Raise UserError when the output ``out`` of ``option`` is one of the ``inputs`` (same file,
    resolved, links followed) or one of the measurement files of a run folder: the ``folders``
    given, and the folder of an input that is a run folder's recording.csv (and the names in
    ``also`` there). Writing there would overwrite the measurement itself."""
    out = Path(out)
    protected = []  # (path, what it is)
    for given in inputs:
        if given is None:
            continue
        given = Path(given)
        protected.append((given, "an input of this command"))
        if given.name == "recording.csv" and (given.parent / "cell.yaml").exists():
            folders = (*folders, given.parent)
    for folder in folders:
        protected += [(Path(folder) / name, f"part of the run folder {folder}")
                      for name in (*RUN_FILES, *also)]
    for path, what in protected:
        if _same(out, path):
            raise UserError(f"{option} {out} is {path} itself ({what}): writing there would "
                            "destroy it; write the output to another file")
