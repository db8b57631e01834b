"""Numbers and counts as the outputs write them (standard library only)."""
from __future__ import annotations


def fixed(value: float, decimals: int, sign: str = "") -> str:
    """``value`` to ``decimals`` places, never "-0.0" (a value that rounds to zero has no sign;
    ``sign`` "+": every other value carries its sign)."""
    text = f"{value:{sign}.{decimals}f}"
    return text if float(text) != 0 else f"{0.0:{sign}.{decimals}f}"


def count(n: int, noun: str = "plate", plural: str = "") -> str:
    """``n`` and the noun, plural unless one: "1 plate", "2 plates" (``plural``: an irregular
    one, "strategies")."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"
