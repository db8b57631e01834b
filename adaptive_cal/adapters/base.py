"""Small protocols for motion and probe, and the probe cycle that owns the touch sequence.

The cycle: check the target -> travel at the safe height -> approach -> settle -> read N samples
-> median -> reject when the spread exceeds the tolerance (bounded retries) -> retract.
Readings near the ends of the usable stroke are rejected; raw bytes and timestamps are kept.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, runtime_checkable

import numpy as np


class AdapterError(RuntimeError):
    """A device problem that stops the run; the message says what to do."""


class UnsafeTarget(AdapterError):
    """A target outside the workplane, a keep-out or the workspace box; it was not sent."""


class TouchRejected(AdapterError):
    """A touch whose reading cannot be used (stroke end, spread). Carries what was read."""

    def __init__(self, message: str, reading_mm: float = float("nan"), flags: tuple[str, ...] = ()):
        super().__init__(message)
        self.reading_mm = reading_mm
        self.flags = flags


@dataclass(frozen=True)
class Sample:
    """One raw probe indication."""

    value_mm: float
    t_s: float
    raw: bytes = b""


@dataclass(frozen=True)
class Touch:
    """What one probe touch produced: the reading fused into the belief and where it was taken."""

    x_mm: float
    y_mm: float
    z_mm: float  # commanded approach (reference) height
    reading_mm: float
    t_s: float
    samples: tuple[Sample, ...] = ()
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Motion(Protocol):
    """Moves the probe tip to a position in the workplane frame (mm)."""

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None: ...

    def position(self) -> tuple[float, float, float]: ...

    def close(self) -> None: ...


@runtime_checkable
class ProbeDevice(Protocol):
    """Reads the probe indication (mm) at the current pose."""

    def read(self) -> Sample: ...

    def close(self) -> None: ...


@dataclass
class ProbeCycle:
    """The touch sequence above a Motion and a ProbeDevice (see module docstring).

    ``allowed(x, y, z)`` is the safety check: a target it refuses is never sent.
    ``clock()`` gives the run time in seconds (simulated cells pass their own clock).
    """

    motion: Motion
    probe: ProbeDevice
    allowed: Callable[[float, float, float], bool]
    safe_height_mm: float
    usable_mm: tuple[float, float]
    samples: int = 1
    samples_tolerance_mm: float = 0.005
    retries: int = 2
    settle_s: float = 0.0
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep

    def _send(self, x: float, y: float, z: float) -> None:
        if not self.allowed(x, y, z):
            raise UnsafeTarget(f"target x={x:.3f} y={y:.3f} z={z:.3f} mm is outside the allowed "
                               "workplane/workspace; it was not sent")
        self.motion.move_to(x, y, z)

    def touch(self, x_mm: float, y_mm: float, z_mm: float) -> Touch:
        """Touch at (x, y) with the reference height z; returns the median reading."""
        safe = max(self.safe_height_mm, z_mm)
        for target in ((x_mm, y_mm, safe), (x_mm, y_mm, z_mm)):
            if not self.allowed(*target):
                raise UnsafeTarget(f"target x={target[0]:.3f} y={target[1]:.3f} "
                                   f"z={target[2]:.3f} mm is outside the allowed workplane/"
                                   "workspace; nothing was sent")
        cx, cy, cz = self.motion.position()
        if cz < safe - 1e-9:
            self._send(cx, cy, safe)  # lift before travelling
        self._send(x_mm, y_mm, safe)
        self._send(x_mm, y_mm, z_mm)
        try:
            if self.settle_s:
                self.sleep(self.settle_s)
            last_spread = np.nan
            for _attempt in range(self.retries + 1):
                got = tuple(self.probe.read() for _ in range(self.samples))
                values = np.array([s.value_mm for s in got])
                last_spread = float(values.max() - values.min())
                if last_spread <= self.samples_tolerance_mm or self.samples == 1:
                    break
            else:
                raise TouchRejected(
                    f"probe samples spread {last_spread * 1000:.1f} um > tolerance "
                    f"{self.samples_tolerance_mm * 1000:.1f} um after {self.retries + 1} tries",
                    float(np.median(values)), ("rejected", "spread"))
            reading = float(np.median(values))
            lo, hi = self.usable_mm
            if not lo <= reading <= hi:
                raise TouchRejected(f"reading {reading:.4f} mm outside the usable stroke "
                                    f"[{lo}, {hi}] mm", reading, ("rejected", "stroke_end"))
            return Touch(x_mm, y_mm, z_mm, reading, got[-1].t_s, got)
        finally:
            self.motion.move_to(x_mm, y_mm, safe)  # retract, also after a rejected reading
