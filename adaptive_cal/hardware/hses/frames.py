"""User frame <-> base frame, for the HSES position read (0x75 answers in the base frame only).

A user frame is given as the pendant shows it: its origin in the base frame (mm) and its
rotation Rx Ry Rz (degrees), composed as R = Rz(rz) Ry(ry) Rx(rx) (rotations about the base
frame's fixed X, then Y, then Z axes; the convention of Yaskawa's Cartesian poses, verify on the
controller: docs/adapters/hses.md says how). A point p given in the user frame lies at
b = R p + origin in the base frame.
"""
from __future__ import annotations

import math

Vec = tuple[float, float, float]


def rotation(rx_deg: float, ry_deg: float, rz_deg: float) -> tuple[Vec, Vec, Vec]:
    """R = Rz Ry Rx, rows."""
    a, b, c = (math.radians(v) for v in (rx_deg, ry_deg, rz_deg))
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    return ((cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa),
            (sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa),
            (-sb, cb * sa, cb * ca))


def user_to_base(p: Vec, origin_mm: Vec, rotation_deg: Vec) -> Vec:
    """b = R p + origin."""
    r = rotation(*rotation_deg)
    return tuple(sum(r[i][j] * p[j] for j in range(3)) + origin_mm[i] for i in range(3))


def base_to_user(b: Vec, origin_mm: Vec, rotation_deg: Vec) -> Vec:
    """p = R^T (b - origin)."""
    r = rotation(*rotation_deg)
    d = [b[i] - origin_mm[i] for i in range(3)]
    return tuple(sum(r[i][j] * d[i] for i in range(3)) for j in range(3))
