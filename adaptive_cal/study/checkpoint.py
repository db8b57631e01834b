"""The study's checkpoint: finished plates as JSON lines, appended as they finish.

The first line names the study (a hash of the study and its base cell), so a checkpoint of
another study is never mixed in; a line cut by an interruption is dropped and that plate runs
again.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Iterable

from adaptive_cal.study.config import Study


def study_key(study: Study, base: dict) -> str:
    text = json.dumps({"study": study.model_dump(mode="json"), "cell": base}, sort_keys=True,
                      default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def read_checkpoint(path: Path, key: str) -> list[dict]:
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
    if head["study_key"] != key:
        raise ValueError(f"{path} holds plates of another study (key {head['study_key']}, "
                         f"this study {key}; its plates, strategies, seed or settings differ): "
                         f"{where}")
    records = []
    for line in lines[1:]:
        try:
            record = json.loads(line)
        except json.JSONDecodeError:  # a line cut by the interruption: that plate runs again
            break
        if not isinstance(record, dict) or not {"plate", "strategy"} <= record.keys():
            break  # not a plate's record: it and what follows run again
        records.append(record)
    return records


class Checkpoint:
    """Append-only JSON lines, flushed and fsynced per plate."""

    def __init__(self, path: Path, key: str):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self.records = read_checkpoint(path, key)
        # rewrite without a cut last line (atomically), then append
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(json.dumps({"study_key": key}) + "\n")
            for r in self.records:
                f.write(json.dumps(r) + "\n")
        os.replace(tmp, path)
        self._f = open(path, "a", encoding="utf-8")

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
