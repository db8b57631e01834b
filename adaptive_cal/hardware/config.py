"""What every adapter's config block shares: immutable, unknown keys refused, hosts and baud
rates checked. Each family's own block sits beside its adapter (``hardware/<family>/config.py``)
under ``robot.<adapter>`` or ``probe.<adapter>`` in the cell file. Everything that HARDWARE.md
marks "(verify)" is a field, not a constant in the code.
"""
from __future__ import annotations

import math
import typing

from pydantic import BaseModel, ConfigDict, model_validator

# the rates a UART and pyserial both accept; anything else is a typo
BAUD_RATES = (300, 600, 1200, 2400, 4800, 9600, 14400, 19200, 38400, 57600, 115200, 230400)


def _numeric(annotation) -> bool:
    """A number field (int or float, optional or not; not one that also takes text or a bool)."""
    args = typing.get_args(annotation) or (annotation,)
    kinds = {a for a in args if a is not type(None)}
    return bool(kinds) and any(a in (int, float) for a in kinds) and not any(
        a in (str, bool) or typing.get_origin(a) is typing.Literal for a in kinds)


class Strict(BaseModel):
    """Base for config blocks: immutable, unknown keys are an error (a typo must fail), and a
    yes/no is no number: ``max_touches: true`` (YAML's yes, on, true) is refused naming the key,
    not read as 1. Text that reads as a number stays allowed: PyYAML leaves ``4e-3`` (no dot)
    a string, and a cell file that writes it means the number. NaN and inf are refused in
    every number field, as in the cell file's own blocks (``cell.block``): a block built in
    Python meets the same checks as one read from a file."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _numbers_are_numbers(cls, data):
        if isinstance(data, dict):
            for name, field in cls.model_fields.items():
                v = data.get(name)
                if isinstance(v, bool) and _numeric(field.annotation):
                    raise ValueError(f"{name}: a yes/no, not a number (YAML reads yes, no, "
                                     f"on, off, true and false as one: here {v!r})")
        return data


def check_host(v: str) -> str:
    """A host name or address, stripped; ValueError when empty."""
    if not v or not v.strip():
        raise ValueError("host must be an IP address or a host name, got an empty string")
    return v.strip()


def check_scale(v: float, unit: str) -> float:
    """A scale by which a number on the wire becomes mm (or mm one): finite and non-zero, else
    ValueError (0 read every value as 0 mm; NaN or inf none at all)."""
    if not (math.isfinite(v) and v != 0):
        raise ValueError(f"scale must be a finite, non-zero number ({unit}), got {v}")
    return v


def check_baud(v: int | None) -> int | None:
    """A baud rate a UART has (or None: the preset's); ValueError names the bad one."""
    if v is not None and v not in BAUD_RATES:
        raise ValueError(f"baud rate {v} does not exist; use one of {list(BAUD_RATES)}")
    return v
