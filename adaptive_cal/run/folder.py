"""A run folder's integrity: one process at a time (an exclusive lock), and files replaced whole.

The lock is ``fcntl.flock`` on ``.run.lock`` inside the folder (Linux): the kernel drops it when
the holding process exits in any way (normal end, error, Ctrl-C, SIGKILL), so a lock left by a
killed process never blocks. The file keeps the holder's pid for the message; it is not deleted
(deleting a flock file races with a process opening it).

Results are written to a temporary file in the same folder, flushed to disk and moved over the
old one with ``os.replace``: a reader sees the old file or the new one, never half of one.
"""
from __future__ import annotations

import fcntl
import json
import math
import os
import re
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from adaptive_cal.formats.lockfile import LOCK_NAME  # noqa: F401 (where tests look)

#: ``replace_atomically``'s temporary files: ".NAME.PID.HEX8.tmp"
TMP_NAME = re.compile(r"\..+\.([0-9]+)\.[0-9a-f]{8}\.tmp")


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (a report writing beside a run keeps its file)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return pid < 2**31  # another user's process (an impossible pid: not alive)
    return True


class RunFolderBusy(FileExistsError):
    """Another process holds the run folder's lock; the message names the folder and its pid."""


@contextmanager
def run_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold ``folder``'s exclusive lock for the block (the folder is created if needed); raise
    ``RunFolderBusy`` at once when another process holds it."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            raise RunFolderBusy(f"{folder} is in use by another run (pid {holder}): wait for it "
                                "to end (or give a new run another --out)") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        for left in folder.glob(".*.tmp"):  # a kill mid-write left them (an outside audit)
            m = TMP_NAME.fullmatch(left.name)
            if m and not _alive(int(m.group(1))):
                left.unlink(missing_ok=True)
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def replace_atomically(path: str | os.PathLike, write: Callable[[object], None],
                       binary: bool = False) -> None:
    """Write ``path`` whole or not at all: ``write(file)`` fills a temporary file in the same
    folder, which is fsynced and moved over ``path``."""
    path = Path(path)
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as usual
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def finite_json(value):
    """``value`` with every non-finite float (NaN, +-inf) replaced by None, so that
    ``json.dumps(..., allow_nan=False)`` holds (NaN and Infinity are not JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if hasattr(value, "item") and getattr(value, "shape", None) == ():  # numpy scalars
        return finite_json(value.item())
    if hasattr(value, "tolist"):
        return finite_json(value.tolist())
    return value


def write_json(path: str | os.PathLike, value) -> None:
    """``value`` as indented JSON, non-finite numbers as null, replaced atomically."""
    text = json.dumps(finite_json(value), indent=2, allow_nan=False) + "\n"
    replace_atomically(path, lambda f: f.write(text))
