"""The study's checkpoint: finished plates as JSON lines, appended as they finish.

The first line names the study (a hash of the study and its base cell, and of its height maps'
names and bytes), so a checkpoint of another study is never mixed in; a line cut by an
interruption is dropped and that plate runs again. A damaged line elsewhere (not a plate's
record) is skipped and named, the records after it kept; a plate's record given twice counts
once. While a study runs it holds a lock on the checkpoint (``plates.jsonl.lock`` beside it):
a second study on the same checkpoint is refused, where it used to replace the file under the
first one, whose later records then went to the replaced file and were lost (an outside audit,
2026-11-29).

Each record carries ``code``: a hash of the sources that make records (``code_fingerprint``).
Records of other code are not this code's measurement: a study refuses them unless told to keep
them (``reuse``), and then says how many it kept (an outside audit, 2026-12-02: a page's
command reused records made by the code of nine days before, and presented them as its own).
"""
from __future__ import annotations

import functools
import glob
import hashlib
import json
import os
try:
    import fcntl
except ImportError:  # not POSIX: no lock (one study per folder is then the user's to keep)
    fcntl = None
from pathlib import Path
from typing import Iterable

from adaptive_cal.study.config import Study, surface_files


#: the sources that make a study's records (the run loop drives the probe cycle of
#: ``hardware``, not its adapters; the simulator, not the emulators), and of them the modules
#: left out: those that only present, keep or schedule records, or check settings the key
#: covers -- a page's wording or a new check measures nothing
MEASURING = ("cell/**/*.py", "effects/**/*.py", "formats/**/*.py", "gaussian/**/*.py",
             "hardware/*.py", "planning/**/*.py", "run/**/*.py", "simulation/*.py",
             "study/**/*.py")
PRESENTING = ("cell/consistency.py", "cell/doc.py", "study/checkpoint.py", "study/doc.py",
              "study/figures.py", "study/overrides.py", "study/runner.py", "study/summary.py")
#: the libraries whose numerics the records rest on (a hyper-parameter fit's optimum moved
#: between two JAX releases)
LIBRARIES = ("numpy", "scipy", "jax", "jaxlib")


def _version(name: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def fingerprint(root: Path, libraries: tuple[str, ...] = LIBRARIES) -> str:
    """12 hex digits of a SHA-256 over the sources under the package folder ``root`` that make
    a study's records (their paths and bytes, line ends as LF) and the versions of
    ``libraries``: another planner, simulator, model or numerics library is another
    fingerprint; another page wording is not. Only importable modules count: a folder or file
    whose name is not a Python identifier (``.ipynb_checkpoints``, ``plan-checkpoint.py``) is
    no module of the package."""
    digest = hashlib.sha256()
    files = [root / "__init__.py"] + sorted({f for pattern in MEASURING
                                              for f in root.glob(pattern)})
    for f in files:
        rel = f.relative_to(root).as_posix()
        parts = rel[:-3].split("/")
        if rel not in PRESENTING and all(part.isidentifier() for part in parts):
            text = f.read_bytes().replace(b"\r\n", b"\n")
            digest.update(rel.encode() + b"\0" + text + b"\0")
    for name in libraries:
        digest.update(f"{name}=={_version(name)}".encode() + b"\0")
    return digest.hexdigest()[:12]


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """This code's ``fingerprint``."""
    return fingerprint(Path(__file__).resolve().parents[1])


def other_code(records: list[dict]) -> list[dict]:
    """The records made by other code than this (or before records carried their code)."""
    return [r for r in records if r.get("code") != code_fingerprint()]


def refuse_other_code(path: Path, records: list[dict]) -> None:
    """ValueError naming the checkpoint where it holds records of other code."""
    other = other_code(records)
    if other:
        codes = sorted({str(r.get("code", "none: made before records carried it")) for r in other})
        raise ValueError(
            f"{path} holds {len(other)} of {len(records)} finished runs made by other code than "
            f"this (code {', '.join(codes)}; this code {code_fingerprint()}): they are not this "
            "code's measurement. Delete it to measure again, or add --reuse-records to keep them "
            "(the summary and the page then say how many are another code's)")


def _sha256(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:  # unreadable: the run refuses it, naming the file
        return "unreadable"


def _glob_root(pattern: str) -> str:
    """The folder a glob's matches are named from: its parts before the first wildcard."""
    parts = Path(pattern).parts
    fixed = next((k for k, p in enumerate(parts) if glob.has_magic(p)), len(parts) - 1)
    return str(Path(*parts[:fixed])) if fixed else "."


def maps_key(study: Study, base: dict) -> str | None:
    """A hash of the study's height maps (plate.surface_files, the base cell's
    simulation.surface_file): the matched names, sorted (plate i is the i-th), and the bytes
    of each, so a map added, removed or rewritten in place makes another study. None without
    maps."""
    files = surface_files(study)
    root = _glob_root(study.plate.surface_files) if files else "."
    parts = [[os.path.relpath(f, root), _sha256(f)] for f in files]
    own = (base.get("simulation") or {}).get("surface_file")
    if isinstance(own, str) and own:
        parts.append(["simulation.surface_file", _sha256(own)])
    if not parts:
        return None
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()[:16]


def study_key(study: Study, base: dict) -> str:
    """The study's settings and base cell hashed, but for its number of plates (plate i is
    drawn from the seed and i alone: --plates grows or cuts a study and keeps its records);
    with height maps, "-" and their hash (``maps_key``)."""
    return _key(study, base, {k: v for k, v in study.model_dump(mode="json").items()
                              if k != "plates"})


def legacy_key(study: Study, base: dict) -> str:
    """The key as written until 2026-12-02, the plate count included: such a checkpoint is
    this study's (its records, made before they carried their code, are then refused as other
    code's unless kept with --reuse-records), not "another study"."""
    return _key(study, base, study.model_dump(mode="json"))


def _key(study: Study, base: dict, settings: dict) -> str:
    text = json.dumps({"study": settings, "cell": base}, sort_keys=True, default=str)
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    maps = maps_key(study, base)
    return key if maps is None else f"{key}-{maps}"


def read_checkpoint(path: Path, key: str, skipped: list | None = None,
                    also: tuple[str, ...] = ()) -> list[dict]:
    """The plate records of ``path`` for the study ``key`` (ValueError naming the file where it
    holds another study's); ``also``: the same study's keys in earlier formats (``legacy_key``).
    ``skipped``: the numbers of damaged lines (not a plate's record, and not the last line,
    which an interruption may cut) are appended to it."""
    if not path.exists():
        return []
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines:
        return []
    where = "delete it, or write this study elsewhere (another --out, or another --json)"
    try:
        head = json.loads(lines[0])
    except json.JSONDecodeError:
        head = None
    if not isinstance(head, dict) or not isinstance(head.get("study_key"), str):
        raise ValueError(f"{path}: not a study's checkpoint (its first line, {lines[0][:40]!r}, "
                         f"is not a study key): {where}")
    old = head["study_key"]
    if old in also:
        old = key  # this study, its key written as it was before
    if old != key and old.split("-")[0] == key.split("-")[0]:  # the settings agree
        why = ("a map of plate.surface_files added, removed, renamed or rewritten since, or the "
               "base cell's simulation.surface_file rewritten" if "-" in old else
               "it was written before a study's key covered its maps, which may have changed")
        raise ValueError(f"{path} holds plates of this study over other height maps (key {old}, "
                         f"this study {key}: {why}): {where}")
    if old != key:
        raise ValueError(f"{path} holds plates of another study (key {head['study_key']}, "
                         f"this study {key}; its strategies, seed, settings or base cell differ): "
                         f"{where}")
    records, seen = [], set()
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            record = None
        if not isinstance(record, dict) or not {"plate", "strategy"} <= record.keys():
            if number < len(lines) and skipped is not None:  # not the last line: damage
                skipped.append(number)
            continue  # the last line cut by an interruption, or a damaged one: it runs again
        if (record["plate"], record["strategy"]) not in seen:
            seen.add((record["plate"], record["strategy"]))
            records.append(record)
    return records


class Checkpoint:
    """Append-only JSON lines, flushed and fsynced per plate."""

    def __init__(self, path: Path, key: str, also: tuple[str, ...] = ()):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = _lock(path)
        try:
            self.skipped: list[int] = []
            self.records = read_checkpoint(path, key, self.skipped, also)
            # rewrite without a cut last line (atomically), then append
            tmp = path.with_name(path.name + ".tmp")
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(json.dumps({"study_key": key}) + "\n")
                for r in self.records:
                    f.write(json.dumps(r) + "\n")
            os.replace(tmp, path)
            self._f = open(path, "a", encoding="utf-8")
        except BaseException:
            self._lock.close()
            raise

    def done(self) -> set[tuple[int, str]]:
        return {(r["plate"], r["strategy"]) for r in self.records}

    def add(self, records: Iterable[dict]) -> None:
        for r in records:
            self._f.write(json.dumps(r) + "\n")
            self.records.append(r)
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()
        self._lock.close()  # the lock goes with the file; the lock file stays (no race)


def _lock(path: Path):
    """An open lock file beside ``path``, locked for this process (``fcntl.flock``; released
    when it is closed or the process ends, a kill included). ValueError naming the checkpoint
    where another study holds it."""
    lock = open(path.with_name(path.name + ".lock"), "a")
    if fcntl is None:
        return lock
    try:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        lock.close()
        raise ValueError(f"{path}: another study is writing to it now (it holds "
                         f"{path.name}.lock); wait for it to end, or write this study elsewhere "
                         "(another --out, or another --json)") from None
    return lock
