"""Small protocols for motion and probe, what a touch produces, and the errors that stop a run.

The probe cycle that owns the touch sequence is ``hardware.cycle.ProbeCycle``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable


class AdapterError(RuntimeError):
    """A device problem that stops the run; the message says what to do."""


class OperatorStop(AdapterError):
    """The operator asked to stop (the manual adapter's ``q``): the run ends as interrupted,
    as after Ctrl-C (exit status 130, no ``error``), and ``--resume`` continues it."""


class Interrupted(KeyboardInterrupt):
    """A stop signal that interrupts at once (the second Ctrl-C or SIGTERM of a run): ``by``
    names it for the messages -- a SIGTERM comes from a service manager or a timeout, not from
    someone at the keyboard."""

    def __init__(self, by: str = "Ctrl-C"):
        super().__init__(by)
        self.by = by


def interrupted_by(e: BaseException) -> str:
    """What interrupted: "Ctrl-C" for a plain KeyboardInterrupt, else ``Interrupted.by``."""
    return getattr(e, "by", "Ctrl-C")


CLEARANCE_MM = 0.5  # the least gap kept between the free tip and the plate under a travel


class UnsafeTarget(AdapterError):
    """A target outside the workplane, a keep-out or the workspace box; it was not sent."""


class StrokeOverrun(UnsafeTarget):
    """The approach at a place where the last touch read past the usable stroke's top: the
    plate stands higher than the approach allows, and it was not sent again. The run stops as
    ``touches_rejected`` (the plate is not where the cell file puts it): --resume would only
    ask the same approach again."""


class ProbeLeftDown(AdapterError):
    """The retract after a touch failed: the tip may still be down. The message says so first,
    then what to do, then what went wrong (``__cause__``). ``touch`` is the reading taken before
    the retract failed, if one was (the loop records it before it stops)."""

    def __init__(self, message: str, touch: "Touch | None" = None):
        super().__init__(message)
        self.touch = touch
        self.interrupted = False  # a Ctrl-C or SIGTERM stopped the touch or retract (exit 130)


def _left_down(x_mm, y_mm, z_mm, safe_mm, lift: BaseException, then: str,
               touch: "Touch | None" = None, z_is: str = "approach",
               err: BaseException | None = None) -> ProbeLeftDown:
    said = f"interrupted: {interrupted_by(lift)}" if isinstance(lift, KeyboardInterrupt) else lift
    out = ProbeLeftDown(
        f"THE PROBE MAY BE DOWN at x={x_mm:.3f} y={y_mm:.3f} mm ({z_is} z={z_mm:.3f} mm): the "
        f"retract to z={safe_mm:.3f} mm failed ({said}). Hold the robot (pendant hold or servo "
        f"off: a command in flight may still run), then jog the probe clear by hand before "
        f"anything moves again. {then}", touch)
    out.interrupted = any(isinstance(e, KeyboardInterrupt) for e in (lift, err))
    return out


class BadSample(AdapterError):
    """One probe sample that cannot be used: timeout, garbage, stale or out of range.

    ``raw`` holds the bytes received (if any) so the log shows what the device sent."""

    def __init__(self, message: str, raw: bytes = b""):
        super().__init__(message)
        self.raw = raw


class TouchRejected(AdapterError):
    """A touch whose reading cannot be used (stroke end, spread). Carries what was read."""

    def __init__(self, message: str, reading_mm: float = float("nan"), flags: tuple[str, ...] = (),
                 samples: tuple["Sample", ...] = ()):
        super().__init__(message)
        self.reading_mm = reading_mm
        self.flags = flags
        self.samples = samples
        self.z_mm: float | None = None  # the approach it was read at (None: the target's)


@dataclass(frozen=True)
class Sample:
    """One probe sample: the reading (mm), the time it was taken (device clock, s), the raw bytes
    the device sent (for the log; not recorded)."""

    reading_mm: float
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
    """Moves the probe tip to a position in the workplane frame (mm); returns when it is there."""

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None: ...

    def position(self) -> tuple[float, float, float]: ...

    def close(self) -> None: ...


@runtime_checkable
class ProbeDevice(Protocol):
    """Reads one probe sample (its ``reading_mm``) at the current pose."""

    def read(self) -> Sample: ...

    def close(self) -> None: ...


def frozen_after(resolution_mm: float, noise_mm: float, touches: int) -> int | None:
    """Touches in a row with one reading that mark a readout frozen: the fewest k >= 3 such
    that a live probe, its readings quantised to ``resolution_mm`` with a noise of at least
    ``noise_mm`` (the lower end of what the cell states), repeats one reading k times in a row
    somewhere in ``touches`` touches with probability below 1e-3. Two readings differing by
    N(0, 2 noise^2) round to the same step with probability about p = step / (2 sqrt(pi) noise)
    (the innovations' own spread only lowers it). None where p >= 0.5 or k would exceed 10: a
    readout that coarse repeats itself honestly. A false alarm costs one touch (recorded
    ``frozen;rejected``): the next one reads another value."""
    p = resolution_mm / (2.0 * math.sqrt(math.pi) * noise_mm)
    if not 0 < p < 0.5:
        return None
    k = 1 + math.ceil(math.log(1e-3 / max(touches, 1)) / math.log(p))
    return max(k, 3) if k <= 10 else None
