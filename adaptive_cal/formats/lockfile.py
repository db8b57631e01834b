"""A run folder's lock file: who holds it now (``run.folder.run_lock`` takes it)."""
from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_NAME = ".run.lock"


def busy_by(folder: str | os.PathLike) -> str | None:
    """The pid of the run that holds ``folder``'s lock now (``run_lock``), or None (no lock
    file, or nobody holds it); takes nothing."""
    path = Path(folder) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    except BlockingIOError:
        return os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
    finally:
        os.close(fd)
