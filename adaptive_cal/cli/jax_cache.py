"""JAX's persistent compilation cache for the command line.

A command that loads JAX (``run``, ``study``, ``flatness``, ``report``, ``compensate``)
jit-compiles the planner's scores, the hyper-parameter objective and their kin again in every
new process: about 1-2 s of a 12 s simulated ``run`` on the 2-core development machine
(three runs each way, 2026-11-30: 12.6-12.9 s without, 11.1-12.2 s with). With the cache, a
later command loads what an earlier one compiled (JAX keys each entry by the program,
its shapes, the JAX and jaxlib versions and the machine, so a stale entry is never used).

Where: ``$ADAPTIVE_CAL_JAX_CACHE`` (a folder, or ``off``), else ``$XDG_CACHE_HOME/adaptive-cal/
jax``, else ``~/.cache/adaptive-cal/jax``; a ``JAX_COMPILATION_CACHE_DIR`` of the user's own is
left as it is. JAX's documentation calls the cache trusted (its entries are code that JAX runs),
so it is used only in a folder this user owns that no one else may write to; it is created
that way (0700). Entries are kept to ``MAX_BYTES`` in all, the least recently used dropped first
(JAX's own eviction, under a file lock: two commands at once never read a half-written entry).
Anything that goes wrong here leaves the cache off; the command runs as before.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

MAX_BYTES = 256 * 2**20  # the cache's size limit: about 2,000 of a run's entries (20-150 kB)
OFF = ("0", "off", "no", "false", "none")


def folder() -> Path | None:
    """The cache folder this command would use (not created), or None where it is turned off."""
    choice = os.environ.get("ADAPTIVE_CAL_JAX_CACHE", "").strip()
    if choice.lower() in OFF:
        return None
    if choice:
        return Path(choice).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(base) if base else Path.home() / ".cache") / "adaptive-cal" / "jax"


def private(path: Path) -> bool:
    """The folder exists, is this user's, and no one else may write to it."""
    try:
        st = path.stat()
    except OSError:
        return False
    owner_ok = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    return path.is_dir() and owner_ok and not st.st_mode & 0o022 and os.access(path, os.W_OK)


def enable() -> str | None:
    """Point JAX at the cache before it compiles anything: through the environment (read when
    JAX is first imported) and, where JAX is already loaded, its config. Returns the folder in
    use, or None (turned off, no folder that is private to this user, or ``filelock`` missing,
    without which JAX cannot keep the cache's size)."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]  # the user's own choice
    path = folder()
    if path is None:
        return None
    if importlib.util.find_spec("filelock") is None:  # JAX evicts and locks with it
        return None
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        return None
    if not private(path):
        return None
    settings = {"JAX_COMPILATION_CACHE_DIR": str(path),
                "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
                "JAX_COMPILATION_CACHE_MAX_SIZE": str(MAX_BYTES)}
    os.environ.update(settings)
    jax = sys.modules.get("jax")
    if jax is not None:
        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    return str(path)
