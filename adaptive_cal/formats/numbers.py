"""Numbers as the outputs write them (standard library only)."""
from __future__ import annotations


def fixed(value: float, decimals: int, sign: str = "") -> str:
    """``value`` to ``decimals`` places, never "-0.0" (a value that rounds to zero has no sign;
    ``sign`` "+": every other value carries its sign)."""
    text = f"{value:{sign}.{decimals}f}"
    return text if float(text) != 0 else f"{0.0:{sign}.{decimals}f}"
