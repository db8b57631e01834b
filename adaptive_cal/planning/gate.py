"""The gate and its retake, as one pure function of the belief and the pending retake.

A reading's height y at row h is judged by its Mahalanobis distance d = |y - h^T m| / sqrt(h^T C h + r)
against the gate g:

* no retake pending, d <= g: fused;
* no retake pending, d > g: ``gated``, not fused; the same point is taken once more;
* the retake, d <= g: fused (``retake``);
* the retake, d > g but |y - y_first| <= g sqrt(2 r): fused (``retake``, ``surprise``: the
  surface really is there);
* otherwise: ``retake``, ``rejected``; neither reading is fused.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from adaptive_cal.gaussian import belief as bl


class Retake(NamedTuple):
    """A gated reading that owes a second touch at the same point and approach height (mm)."""

    x_mm: float
    y_mm: float
    z_mm: float
    height_mm: float


class Told(NamedTuple):
    """The judgement of one reading: fused or not, the flags for the recording, the Mahalanobis
    distance, and whether the next ask is a retake. Carries the touch (position, approach
    height, the height it implies) so that ``survey.fuse`` needs nothing else."""

    fused: bool
    flags: tuple[str, ...]
    mahalanobis: float
    retake_next: bool = False
    x_mm: float = float("nan")
    y_mm: float = float("nan")
    z_mm: float = float("nan")
    height_mm: float = float("nan")


def judge(belief: bl.Belief, row: np.ndarray, height_mm: float, noise_var: float,
          gate_sigma: float, pending: Retake | None, x_mm: float, y_mm: float,
          z_mm: float) -> Told:
    """The gate decision for one reading (see module docstring); changes nothing."""
    inn = bl.innovation(belief, row, height_mm, noise_var)
    where = (x_mm, y_mm, z_mm, height_mm)
    if pending is None and inn.mahalanobis > gate_sigma:
        return Told(False, ("gated",), inn.mahalanobis, True, *where)
    if pending is None or inn.mahalanobis <= gate_sigma:
        return Told(True, ("retake",) if pending else (), inn.mahalanobis, False, *where)
    if abs(height_mm - pending.height_mm) <= gate_sigma * np.sqrt(2 * noise_var):
        return Told(True, ("retake", "surprise"), inn.mahalanobis, False, *where)
    return Told(False, ("retake", "rejected"), inn.mahalanobis, False, *where)


def pending_after(told: Told) -> Retake | None:
    """The retake owed after a judged reading: its own point when it was gated, else none."""
    if told.retake_next:
        return Retake(told.x_mm, told.y_mm, told.z_mm, told.height_mm)
    return None
