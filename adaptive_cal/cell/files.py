"""Reading a YAML config file and validating it, with messages that name the key and the value.

Shared by the cell file (``cell.schema``) and the study file; free of any schema. What a file
cannot do to us: a key given twice is refused (naming the key and both lines) instead of the
last one silently winning; aliases may not expand the document beyond ``MAX_NODES`` nodes or
``MAX_DEPTH`` levels (a 1 kB "billion laughs" file is refused before it is built); every number
must be finite (NaN and infinity are refused naming the key); echoed values are cut to
``ECHO_CHARS`` characters.
"""
from __future__ import annotations

import math
import re
import reprlib
from pathlib import Path

import yaml
from pydantic import BaseModel, ValidationError

MAX_NODES = 100_000  # nodes of the document with every alias expanded
MAX_DEPTH = 64  # levels of nesting, aliases expanded
ECHO_CHARS = 80  # longest echo of a bad value in a message
MAX_CHARS = 1_000_000  # longest config file

_echo = reprlib.Repr()
_echo.maxlevel, _echo.maxdict, _echo.maxlist, _echo.maxtuple = 2, 4, 4, 4
_echo.maxstring, _echo.maxother, _echo.maxlong = ECHO_CHARS, ECHO_CHARS, ECHO_CHARS


_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's when built with it


class ConfigError(ValueError):
    """A cell or study file that cannot be used; the message names the key and the value."""


def echo(value) -> str:
    """A bad value as the messages show it: repr, bounded work, at most ECHO_CHARS characters."""
    text = _echo.repr(value)
    return text if len(text) <= ECHO_CHARS else text[: ECHO_CHARS - 3] + "..."


def _format(err: ValidationError, source: str) -> str:
    lines = [f"{source}: {err.error_count()} problem(s):"]
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "(top level)"
        msg = e["msg"].removeprefix("Value error, ")
        if len(msg) > 4 * ECHO_CHARS:
            msg = msg[: 4 * ECHO_CHARS - 3] + "..."
        named = re.match(r"([a-z_]\w*(?:\.\w+)+)\b", msg) if not e["loc"] else None
        if named:  # a check across blocks names its key first; the whole file is no echo
            key = named.group(1)  # said once: "key: key: ..." when the message opens with it
            lines.append(f"  {key}: {msg.removeprefix(key + ': ')}")
            continue
        if e["type"] == "extra_forbidden":
            msg = "unknown key (check the spelling; unknown keys are refused)"
        if (isinstance(e.get("input"), dict) or ", got " in msg) and e["type"] != "missing":
            # a check across a block's keys names them and the values in its message; an
            # echo of the whole block says nothing more ("probe.noise_range_mm: must be [low,
            # high] with low < high, got [0.004, 0.001] mm", not "... (got {'adapter': ..."),
            # nor one of a value the message already gives ("..., got [0.02, 0.005] mm"); a
            # message that opens with one of the block's keys is that key's ("probe: ..." was
            # printed, an outside audit: every other refusal names the whole key)
            first = re.match(r"([a-z_]\w*)(?==| must|: )", msg)  # not "transport 'tcp' needs host"
            if first and isinstance(e.get("input"), dict) and first.group(1) in e["input"]:
                key = f"{key}.{first.group(1)}" if e["loc"] else first.group(1)
            field = key.rsplit(".", 1)[-1]
            lines.append(f"  {key}: {msg.removeprefix(field + ' ').removeprefix(field + ': ')}")
            continue
        lines.append(f"  {key}: {msg} (got {echo(e.get('input'))})" if e["type"] != "missing"
                     else f"  {key}: missing")
    return "\n".join(lines)


def non_finite(value, path: str = ""):
    """(key path, value) of every NaN or infinite float in a parsed file or a validated model."""
    if isinstance(value, float):
        if not math.isfinite(value):
            yield path or "(top level)", value
    elif isinstance(value, BaseModel):
        for name in type(value).model_fields:
            yield from non_finite(getattr(value, name), f"{path}.{name}" if path else name)
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from non_finite(v, f"{path}.{k}" if path else str(k))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from non_finite(v, f"{path}[{i}]")


def _refuse_non_finite(value, source: str) -> None:
    bad = list(non_finite(value))
    if bad:
        lines = [f"{source}: {len(bad)} problem(s):"]
        lines += [f"  {k}: must be a finite number (got {v})" for k, v in bad[:10]]
        raise ConfigError("\n".join(lines))


def validate(model: type[BaseModel], data: dict, source: str):
    """Validate ``data`` against a schema; raise ConfigError naming each bad key and value
    (every number must be finite: NaN and infinity are refused, before and after parsing)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys, got {type(data).__name__}")
    _refuse_non_finite(data, source)
    try:
        value = model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(_format(e, source)) from None
    _refuse_non_finite(value, source)  # a text such as "nan" parsed as a number
    return value


def _check_nodes(node: yaml.Node, source: str) -> None:
    """Refuse duplicate keys, recursive aliases and documents whose alias-expanded size or
    depth exceeds MAX_NODES / MAX_DEPTH; linear in the size of the file (shared nodes once)."""
    done: dict[int, tuple[int, int]] = {}  # id -> (expanded nodes, expanded depth)
    active: set[int] = set()

    def visit(n: yaml.Node) -> tuple[int, int]:
        if id(n) in done:
            return done[id(n)]
        if id(n) in active:
            raise ConfigError(f"{source}:{n.start_mark.line + 1}: a recursive alias")
        if len(active) >= MAX_DEPTH:
            raise ConfigError(f"{source}:{n.start_mark.line + 1}: nested deeper than "
                              f"{MAX_DEPTH} levels")
        active.add(id(n))
        children = []
        if isinstance(n, yaml.MappingNode):
            seen: dict[str, int] = {}
            for k, v in n.value:
                if isinstance(k, yaml.ScalarNode) and k.tag != "tag:yaml.org,2002:merge":
                    line = k.start_mark.line + 1
                    if k.value in seen:
                        raise ConfigError(f"{source}:{line}: key {echo(k.value)} given twice "
                                          f"(first on line {seen[k.value]}); give it once")
                    seen[k.value] = line
                children += [k, v]
        elif isinstance(n, yaml.SequenceNode):
            children = n.value
        size, depth = 1, 0
        for c in children:
            s, d = visit(c)
            size, depth = size + s, max(depth, d)
            if size > MAX_NODES or depth + 1 > MAX_DEPTH:
                raise ConfigError(f"{source}:{n.start_mark.line + 1}: the document expands "
                                  f"to more than {MAX_NODES} values or {MAX_DEPTH} levels "
                                  "(aliases?); a config file is far smaller")
        active.discard(id(n))
        done[id(n)] = size, depth + 1
        return done[id(n)]

    visit(node)


def _flow_depth(text: str) -> int:
    """The deepest nesting of [ ] and { } outside quotes and comments (approximate, linear):
    PyYAML's scanner is quadratic in it, so a deep one is refused before YAML reads it."""
    depth = deepest = 0
    quote = None
    comment = False
    for ch in text:
        if comment:
            comment = ch != "\n"
        elif quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#":
            comment = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth = max(depth - 1, 0)
    return deepest


def _refuse_deep_events(text: str, source: str) -> None:
    """Refuse nesting deeper than MAX_DEPTH from the parser's event stream (a flat loop)."""
    depth = 0
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise ConfigError(f"{source}:{event.start_mark.line + 1}: nested deeper than "
                                  f"{MAX_DEPTH} levels")
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1


def parse_yaml(text: str, source: str = "config"):
    """The data a YAML text holds (None for an empty one), refusing duplicate keys and
    documents that aliases blow up (see module docstring)."""
    if len(text) > MAX_CHARS:
        raise ConfigError(f"{source}: {len(text)} characters; a config file is far smaller "
                          f"(at most {MAX_CHARS})")
    if _flow_depth(text) > MAX_DEPTH:
        raise ConfigError(f"{source}: nested deeper than {MAX_DEPTH} levels")
    _refuse_deep_events(text, source)  # before composing: libyaml's composer recurses in C
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_nodes(node, source)
        return loader.construct_document(node)
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply to read") from None
    finally:
        loader.dispose()


def load_yaml(path: str | Path) -> dict:
    """The mapping a YAML file holds ({} for an empty file); ConfigError names the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: a folder, not a YAML file") from None
    except UnicodeDecodeError as e:  # name the line: a byte offset sends the user counting
        line = e.object[:e.start].count(b"\n") + 1
        raise ConfigError(f"{path}:{line}: not a UTF-8 text file ({e.reason} at byte {e.start}: "
                          f"{e.object[e.start:e.start + 1]!r}; saved as Latin-1 or Windows-1252? "
                          "save it as UTF-8)") from None
    try:
        data = parse_yaml(text, str(path))
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        message = getattr(e, "problem", None) or str(e)
        if len(message) > 2 * ECHO_CHARS:
            message = message[: 2 * ECHO_CHARS - 3] + "..."
        raise ConfigError(f"{where}: not valid YAML: {message}") from None
    return data if data is not None else {}
