"""What every adapter's config block shares: immutable, unknown keys refused, hosts and baud
rates checked. Each family's own block sits beside its adapter (``hardware/<family>/config.py``)
under ``robot.<adapter>`` or ``probe.<adapter>`` in the cell file. Everything that HARDWARE.md
marks "(verify)" is a field, not a constant in the code.
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict

# the rates a UART and pyserial both accept; anything else is a typo
BAUD_RATES = (300, 600, 1200, 2400, 4800, 9600, 14400, 19200, 38400, 57600, 115200, 230400)


class Strict(BaseModel):
    """Base for config blocks: immutable, unknown keys are an error (a typo must fail)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def check_host(v: str) -> str:
    """A host name or address, stripped; ValueError when empty."""
    if not v or not v.strip():
        raise ValueError("host must be an IP address or a host name, got an empty string")
    return v.strip()


def check_baud(v: int | None) -> int | None:
    """A baud rate a UART has (or None: the preset's); ValueError names the bad one."""
    if v is not None and v not in BAUD_RATES:
        raise ValueError(f"baud rate {v} does not exist; use one of {list(BAUD_RATES)}")
    return v
