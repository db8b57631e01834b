"""A seeded config fuzzer: mutants of configs/sim-cell.yaml (a key deleted or renamed, a number
set to NaN / inf / -1e9 / 1e9 / 0 / "x", a key given twice, deep nesting, an alias bomb, wrong
types, a control character in a name). Each must end in a clean ConfigError that names a key or
a line, or load to a Cell whose numbers are all finite -- no other exception, no hang."""
import copy
import random
import re
import signal
import time

import pytest
import yaml

from adaptive_cal.cell.files import non_finite
from adaptive_cal.cell.schema import Cell, ConfigError, load_cell

from helpers import SIM_CELL

SEED, MUTANTS, SECONDS_EACH = 16, 360, 2
BAD_VALUES = [float("nan"), float("inf"), float("-inf"), -1e9, 1e9, 0, -1, "x", None, True,
              [], {}, [1, 2, 3], "nan", "1e999", 10**30]
# a key path ("robot.safe_height_mm", "keep_outs[0]") or a line ("cell.yaml:12:")
NAMES_A_KEY = re.compile(r"(^|\n)  [\w.\[\]()]+( \w+)?: |\.yaml:\d+(:\d+)?: |\.yaml: nested")


def _paths(value, path=()):
    """Every key path of a parsed file: (path, value) for mappings, lists and leaves."""
    yield path, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, path + (i,))


def _set(data, path, value=None, delete=False):
    for p in path[:-1]:
        data = data[p]
    if delete:
        del data[path[-1]]
    else:
        data[path[-1]] = value


def _bomb(depth=9):
    lines = ['b0: &b0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"b{i}: &b{i} [" + ", ".join([f"*b{i - 1}"] * 9) + "]" for i in range(1, depth + 1)]
    return "\n".join(lines) + "\n"


def mutant(rng: random.Random, base: dict, text: str) -> tuple[str, str]:
    """(description, YAML text) of one mutant."""
    data = copy.deepcopy(base)
    paths = [p for p, _ in _paths(data) if p]
    leaves = [p for p, v in _paths(data) if p and not isinstance(v, (dict, list))]
    kind = rng.choice(["delete", "value", "value", "value", "type", "rename", "duplicate",
                       "nest", "bomb", "name"])
    if kind == "delete":
        p = rng.choice(paths)
        _set(data, p, delete=True)
    elif kind == "value":
        p = rng.choice(leaves)
        _set(data, p, rng.choice(BAD_VALUES))
    elif kind == "type":
        p = rng.choice(paths)
        _set(data, p, rng.choice(["text", 3.5, [0.5], {"k": 1}, None, [[1, 2], [3]]]))
    elif kind == "rename":
        p = rng.choice([q for q in paths if isinstance(q[-1], str)])
        parent = data
        for q in p[:-1]:
            parent = parent[q]
        parent[p[-1] + rng.choice(["_", "s", "X"])] = parent.pop(p[-1])
    elif kind == "nest":
        p = rng.choice(paths)
        deep = 1.0
        for _ in range(rng.choice([5, 70, 300])):
            deep = [deep] if rng.random() < 0.5 else {"k": deep}
        _set(data, p, deep)
    elif kind == "name":
        data["name"] = rng.choice(["a\nb", "tab\t", "\x00", "$x^2$", "é" * 300, "", "ok name"])
    out = yaml.safe_dump(data, sort_keys=False, width=10**6) if kind not in (
        "duplicate", "bomb") else text
    if kind == "duplicate":
        lines = out.splitlines()
        keyed = [i for i, l in enumerate(lines) if re.match(r"^\s*\w+:", l)]
        i = rng.choice(keyed)
        lines.insert(i + 1, lines[i].split(":")[0] + ": 1")
        out = "\n".join(lines) + "\n"
        p = (lines[i].strip().split(":")[0],)
    if kind == "bomb":
        target = rng.choice(["name", "robot", "plan", "simulation"])
        out = _bomb(rng.choice([6, 9, 12])) + re.sub(rf"(?m)^{target}:.*(\n[ -].*)*",
                                                     f"{target}: *b6", text, count=1)
        p = (target,)
    return f"{kind} {'.'.join(map(str, p)) if kind != 'name' else 'name'}", out


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def test_every_config_mutant_is_refused_cleanly_or_loads_a_valid_cell(tmp_path):
    rng = random.Random(SEED)
    text = SIM_CELL.read_text()
    base = yaml.safe_load(text)
    f = tmp_path / "cell.yaml"
    old = signal.signal(signal.SIGALRM, _alarm)
    counts = {"refused": 0, "loaded": 0}
    kinds = set()
    t_start, slowest = time.monotonic(), 0.0
    try:
        for n in range(MUTANTS):
            what, out = mutant(rng, base, text)
            kinds.add(what.split()[0])
            f.write_text(out)
            t0 = time.monotonic()
            signal.alarm(SECONDS_EACH)
            try:
                cell = load_cell(f)
            except ConfigError as e:
                message = str(e)
                assert NAMES_A_KEY.search(message), f"mutant {n} ({what}): {message!r}"
                assert len(message) < 2000, f"mutant {n} ({what}): {len(message)} characters"
                assert "Traceback" not in message
                counts["refused"] += 1
            except _Timeout:
                pytest.fail(f"mutant {n} ({what}) took more than {SECONDS_EACH} s")
            except Exception as e:  # noqa: BLE001 -- any other exception is the defect
                pytest.fail(f"mutant {n} ({what}): {type(e).__name__}: {str(e)[:300]}")
            else:
                assert isinstance(cell, Cell)
                assert not list(non_finite(cell)), f"mutant {n} ({what})"
                assert cell.robot.safe_height_mm > 0 and "\n" not in cell.name
                counts["loaded"] += 1
            finally:
                signal.alarm(0)
            slowest = max(slowest, time.monotonic() - t0)
    finally:
        signal.signal(signal.SIGALRM, old)
    assert sum(counts.values()) == MUTANTS >= 300
    assert kinds == {"delete", "value", "type", "rename", "duplicate", "nest", "bomb", "name"}
    assert counts["refused"] > MUTANTS / 2 and counts["loaded"] > 0, counts
    assert time.monotonic() - t_start < 20, f"{time.monotonic() - t_start:.1f} s"
