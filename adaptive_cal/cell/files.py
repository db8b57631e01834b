"""Reading a YAML config file and validating it, with messages that name the key and the value.

Shared by the cell file (``cell.schema``) and the study file; free of any schema.
"""
from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ValidationError


class ConfigError(ValueError):
    """A cell or study file that cannot be used; the message names the key and the value."""


def _format(err: ValidationError, source: str) -> str:
    lines = [f"{source}: {err.error_count()} problem(s):"]
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "(top level)"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown key (check the spelling; unknown keys are refused)"
        lines.append(f"  {key}: {msg} (got {e.get('input')!r})" if e["type"] != "missing"
                     else f"  {key}: missing")
    return "\n".join(lines)


def validate(model: type[BaseModel], data: dict, source: str):
    """Validate ``data`` against a schema; raise ConfigError naming each bad key and value."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(_format(e, source)) from None


def load_yaml(path: str | Path) -> dict:
    """The mapping a YAML file holds ({} for an empty file); ConfigError names the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {e}") from None
    return data if data is not None else {}
