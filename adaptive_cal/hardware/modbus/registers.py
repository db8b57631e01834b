"""PLC address names -> Modbus (table, address), and the register-map checks done at load time.

Delta DVP (HARDWARE.md): M0-M1535 coils at 0x0800, M1536+ at 0xB000, D0-D4095 holding registers
at 0x1000, X inputs at 0x0400 and Y outputs at 0x0500, X and Y numbered in octal.
Delta DOP HMI as a slave (manual 2007PDD23000007): ``$n`` is holding register n (0-1023) and
``$Mn`` is holding register 2000+n ($M0-$M1023 = W42001-W43024): a flag kept in a whole word,
written 1 / 0 and read as set when non-zero. D4096 and up are refused: their Modbus address
differs between DVP models (see docs/adapters/modbus.md); use ``hr:N`` from your PLC's table.
Raw names: ``hr:N``, ``coil:N``, ``di:N``, ``ir:N`` (decimal or 0x hex): N is the protocol
address, counted from 0 (Modicon's 40101 is hr:100; cell.consistency warns about hr:4xxxx).
"""
from __future__ import annotations

import re
from typing import NamedTuple

TABLES = ("coil", "di", "hr", "ir")  # coils, discrete inputs, holding and input registers
BIT_TABLES = ("coil", "di")
FLAG_ROLES = ("start", "done", "fault", "probe_trigger")  # bits; the others are words
WRITTEN_FLAGS = ("start", "done", "probe_trigger")  # bits the PC writes (it clears done)
VALUE_ROLES = ("target_x", "target_y", "target_z", "probe_value", "actual_x", "actual_y",
               "actual_z")  # numbers in mm (``value_words`` registers each); the others 1 word


def width(role: str, value_words: int) -> int:
    """Registers ``role`` spans: ``value_words`` for a number in mm, else 1."""
    return value_words if role in VALUE_ROLES else 1


class Address(NamedTuple):
    """A resolved Modbus address: table and 0-based protocol address."""

    table: str
    address: int
    name: str
    word_flag: bool = False  # a flag held in a holding register (DOP $Mn)


def resolve(name: str) -> Address:
    """Translate a PLC address name; ValueError names the bad value."""
    s = str(name).strip()
    m = re.fullmatch(r"(hr|coil|di|ir):(0x[0-9a-fA-F]+|\d+)", s, re.I)
    if m:
        addr = int(m.group(2), 0)
        if addr > 0xFFFF:
            digits, table = m.group(2), m.group(1).lower()
            lead = {"hr": "4", "ir": "3", "di": "1"}.get(table)  # Modicon's 6-digit 4xxxxx ...
            hint = (f" (a 6-digit Modicon reference, counted from 1? {table}:N takes the "
                    f"protocol address: {digits} is {table}:{int(digits[1:]) - 1})"
                    if len(digits) == 6 and digits[0] == lead and int(digits[1:]) > 0 else "")
            raise ValueError(f"address {name!r} is beyond 65535{hint}")
        return Address(m.group(1).lower(), addr, s)
    m = re.fullmatch(r"\$(M?)(\d+)", s, re.I)
    if m:
        n = int(m.group(2))
        if n > 1023:
            raise ValueError(f"DOP address {name!r} is beyond ${m.group(1)}1023")
        if m.group(1):
            return Address("hr", 2000 + n, s, True)
        return Address("hr", n, s)
    m = re.fullmatch(r"([DMXY])(\d+)", s, re.I)
    if not m:
        raise ValueError(f"{name!r} is not a PLC address: use D100, M10, X17, Y7 (Delta), $100, "
                         "$M10 (DOP HMI) or hr:N, coil:N, di:N, ir:N")
    kind, digits = m.group(1).upper(), m.group(2)
    if kind in "XY":
        if re.search(r"[89]", digits):
            raise ValueError(f"{name!r}: Delta X/Y addresses are octal, so 8 and 9 cannot appear")
        n = int(digits, 8)
        if n > 0xFF:
            raise ValueError(f"{name!r} is beyond the X/Y range (X377/Y377)")
        return Address("di" if kind == "X" else "coil", (0x0400 if kind == "X" else 0x0500) + n, s)
    n = int(digits)
    if kind == "D":
        if n > 4095:
            raise ValueError(f"{name!r} is beyond D4095")
        return Address("hr", 0x1000 + n, s)
    if n > 4095:
        raise ValueError(f"{name!r} is beyond M4095")
    return Address("coil", 0x0800 + n if n < 1536 else 0xB000 + n - 1536, s)


def check_map(roles: dict[str, str], value_words: int) -> dict[str, Address]:
    """Resolve every role, check flags are bits and values are words, and refuse overlaps.

    Values (targets, probe value) span ``value_words`` registers; counters and the watchdog one.
    """
    out: dict[str, Address] = {}
    spans: list[tuple[str, str, int, int]] = []
    for role, name in roles.items():
        try:
            a = resolve(name)
        except ValueError as e:
            raise ValueError(f"registers.{role}: {e}") from None
        if role in FLAG_ROLES and a.table not in BIT_TABLES and not a.word_flag:
            raise ValueError(f"registers.{role}={name!r} must be a bit (M, X, Y, $M, coil:, di:)")
        if role not in FLAG_ROLES and (a.table in BIT_TABLES or a.word_flag):
            raise ValueError(f"registers.{role}={name!r} must be a register (D, $, hr:, ir:)")
        if role in WRITTEN_FLAGS and a.table == "di":
            raise ValueError(f"registers.{role}={name!r} is an input (read-only); the PC writes it")
        if role not in FLAG_ROLES and a.table == "ir" and role in ("target_x", "target_y",
                                                                    "target_z", "watchdog"):
            raise ValueError(f"registers.{role}={name!r} is an input register (read-only)")
        words = width(role, value_words)
        for other, table, lo, hi in spans:
            if table == a.table and a.address < hi and lo < a.address + words:
                raise ValueError(f"registers.{role}={name!r} overlaps registers.{other}="
                                 f"{roles[other]!r}")
        spans.append((role, a.table, a.address, a.address + words))
        out[role] = a
    return out
