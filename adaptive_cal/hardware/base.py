"""Small protocols for motion and probe, and the probe cycle that owns the touch sequence.

The cycle: check every target -> lift to the safe height -> travel -> approach -> settle -> read N
samples -> median -> reject when the spread exceeds the tolerance (bounded retries) -> retract.
Readings near the ends of the usable stroke are rejected. Each ``Sample`` carries its timestamp
and the raw bytes the device sent; they stay in memory on the ``Touch`` (and a bad sample's bytes
go to the log) -- the recording keeps the reading and its time, not the bytes. A sample the device
could not give (timeout, garbage, stale, out of range) is logged and retried within the same
bound; it is never fused.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, runtime_checkable

import numpy as np

log = logging.getLogger(__name__)


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


@dataclass
class ProbeCycle:
    """The touch sequence above a Motion and a ProbeDevice (see module docstring).

    ``allowed(x, y, z)`` is the safety check: a target it refuses is never sent.
    ``clock()`` gives the run time in seconds (simulated cells pass their own clock).
    ``retries`` bounds the extra reading attempts after a spread or bad sample.
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
    #: touches in a row with the very same reading that mark the readout frozen (a stale serial
    #: value, a PLC register not updated): that touch is rejected ``frozen`` (``frozen_after``)
    frozen_after: int | None = None
    #: how far below the commanded height the free tip reaches (probe.zero_mm - probe.rest_mm):
    #: a travel clears a plate only where it stands lower than that below it
    reach_mm: float = 0.0
    #: the check of a lift straight up where the probe stands (no new x, y): the workspace box
    #: alone, not the workplane's edge margin or keep-outs (places never touched); None: allowed.
    #: A probe parked beside the plate at the safe height must rise when the travel needs more
    lift_allowed: Callable[[float, float, float], bool] | None = None
    _same: list = field(default_factory=lambda: [math.nan, 0], init=False, repr=False)
    #: (x, y, z) of the last touch whose reading passed the usable stroke's top: the plate there
    #: stands higher than its approach allowed, and the same approach would overrun it again
    _overran: tuple | None = field(default=None, init=False, repr=False)

    def seed_repeats(self, readings) -> None:
        """Count the repeats at the end of ``readings`` (a resumed recording's, in order) as
        this cycle's own: a readout frozen before a stop is caught at the first touch after
        the resume, not after ``frozen_after`` more fused repeats (an outside audit)."""
        values = [float(v) for v in readings]
        n = 0
        while n < len(values) and values[-1 - n] == values[-1]:
            n += 1
        self._same[:] = [values[-1], n] if values else [math.nan, 0]

    def _check(self, path: list[tuple[float, float, float]], allowed=None) -> None:
        for x, y, z in path:
            if not all(map(math.isfinite, (x, y, z))) or not (allowed or self.allowed)(x, y, z):
                raise UnsafeTarget(f"target x={x:.3f} y={y:.3f} z={z:.3f} mm is outside the "
                                   "workplane, a keep-out or the workspace box; nothing was sent")

    def touch(self, x_mm: float, y_mm: float, z_mm: float,
              plate_top: Callable[[tuple], float] | None = None) -> Touch:
        """Touch at (x, y) with the reference height z; returns the median reading.
        ``plate_top(from_xy)``: the highest the plate may stand under the travel from where
        the probe is (``planning.clearance``): the lift and travel go at least ``reach_mm`` +
        ``CLEARANCE_MM`` above it, higher than the safe height where need be."""
        o = self._overran
        if o is not None and math.hypot(x_mm - o[0], y_mm - o[1]) < 1e-3 and z_mm <= o[2] + 1e-9:
            raise UnsafeTarget(  # a second audit: the same target three times, 1.5 mm past each
                f"the last touch at x={o[0]:.3f} y={o[1]:.3f} mm read past the usable stroke's "
                f"top from z={o[2]:.3f} mm: the plate stands higher there than the belief allowed, "
                f"and the approach to z={z_mm:.3f} mm would run the probe past its stroke's end "
                "again; nothing was sent. Check the plate's height in the cell file (workplane, "
                "model's offset prior) and the probe's zero")
        safe = max(self.safe_height_mm, z_mm)
        cx, cy, cz = self.motion.position()
        if plate_top is not None:
            plate_top_mm = plate_top((cx, cy))
            need = plate_top_mm + self.reach_mm + CLEARANCE_MM
            if need > safe and not self.allowed(x_mm, y_mm, need):
                raise UnsafeTarget(
                    f"the plate may stand up to {plate_top_mm:.3f} mm under the travel to x="
                    f"{x_mm:.3f} y={y_mm:.3f} mm, and the free probe tip reaches "
                    f"{self.reach_mm:g} mm below the commanded height: travel at "
                    f"robot.safe_height_mm={self.safe_height_mm:g} would drag it over the plate, "
                    f"and the {need:.3f} mm it needs is outside the workspace box; nothing was "
                    "sent. Raise robot.safe_height_mm and workspace.z_mm's top, or level the "
                    "plate (before the first touches only the prior bounds the plate: a probe "
                    "parked above the workplane's middle travels over less of it)")
            safe = max(safe, need)
        if all(map(math.isfinite, (cx, cy, cz))):
            below = cz < safe - 1e-9  # the tip may be down until this lift is done
            path = [(cx, cy, safe)] if below else []  # lift before travelling
        else:  # no absolute move is safer than the safe height above the target: say so
            path, below = [], False
            log.warning("the probe position is unknown (the adapter reports %s): the first move "
                        "goes straight to the safe height z=%.3f mm above x=%.3f y=%.3f mm, "
                        "with no lift first; make sure the probe is clear of the plate",
                        tuple(round(v, 3) for v in (cx, cy, cz)), safe, x_mm, y_mm)
        lifts = len(path)
        path += [(x_mm, y_mm, safe), (x_mm, y_mm, z_mm)]
        self._check(path[:lifts], self.lift_allowed)  # every target before any is sent
        self._check(path[lifts:])
        approached = False
        try:
            for k, target in enumerate(path[:-1]):
                try:
                    self.motion.move_to(*target)
                except BaseException as lift:  # a first lift that failed: the tip may be down
                    if k or not below:
                        raise
                    raise _left_down(cx, cy, cz, safe, lift, "The probe was below the safe "
                                     "height when this touch began (an earlier stop, a resume); "
                                     "no touch was made", z_is="last known") from lift
            approached = True  # from here on the tip may be down: always retract
            self.motion.move_to(*path[-1])
            touch = self._read(x_mm, y_mm, z_mm)
        except BaseException as err:
            if approached:
                try:
                    self.motion.move_to(x_mm, y_mm, safe)
                except BaseException as lift:  # the danger first (a Ctrl-C too), then the cause
                    why = (interrupted_by(err) if isinstance(err, KeyboardInterrupt)
                           else f"{type(err).__name__}: {err}")
                    raise _left_down(x_mm, y_mm, z_mm, safe, lift,
                                     f"What stopped the touch: {why}", err=err) from err
            raise
        try:
            self.motion.move_to(x_mm, y_mm, safe)  # retract
        except BaseException as lift:  # a Ctrl-C during the retract too: the warning first
            raise _left_down(x_mm, y_mm, z_mm, safe, lift, f"The reading {touch.reading_mm:.4f} "
                             "mm was taken and is kept", touch) from lift
        return touch

    def _read(self, x_mm: float, y_mm: float, z_mm: float) -> Touch:
        if self.settle_s:
            self.sleep(self.settle_s)
        kept: list[Sample] = []
        problems: list[str] = []
        values = np.array([np.nan])
        for attempt in range(self.retries + 1):
            try:
                got = tuple(self.probe.read() for _ in range(self.samples))
            except BadSample as e:
                log.warning("touch at x=%.3f y=%.3f: bad sample rejected (%s) raw=%r",
                            x_mm, y_mm, e, e.raw)
                problems.append(str(e))
                if attempt == self.retries:
                    raise BadSample(f"no usable probe sample after {attempt + 1} attempt(s); "
                                    f"last: {e}. Check the probe cable, port and preset",
                                    e.raw) from e
                self.sleep(self.settle_s)
                continue
            kept.extend(got)
            values = np.array([s.reading_mm for s in got], float)
            if not np.all(np.isfinite(values)):
                problems.append("non-finite sample")
                continue
            spread = float(values.max() - values.min())
            if spread <= self.samples_tolerance_mm or self.samples == 1:
                break
            problems.append(f"spread {spread * 1000:.1f} um")
            log.warning("touch at x=%.3f y=%.3f: samples spread %.1f um > %.1f um (attempt %d)",
                        x_mm, y_mm, spread * 1000, self.samples_tolerance_mm * 1000, attempt + 1)
            self.sleep(self.settle_s)
        else:
            raise TouchRejected(
                f"probe samples unusable after {self.retries + 1} attempt(s) "
                f"({'; '.join(problems)}); tolerance {self.samples_tolerance_mm * 1000:.1f} um",
                float(np.median(values)), ("rejected",) + tuple(  # what the attempts saw
                    f for f, seen in (("spread", any(p.startswith("spread") for p in problems)),
                                      ("nonfinite", "non-finite sample" in problems)) if seen),
                tuple(kept))
        reading = float(np.median(values))
        t_s = float(self.clock())
        lo, hi = self.usable_mm
        if not lo <= reading <= hi:
            self._overran = (x_mm, y_mm, z_mm) if reading > hi else None
            raise TouchRejected(f"reading {reading:.4f} mm outside the usable stroke "
                                f"[{lo}, {hi}] mm: the approach height is off the plate's "
                                "height; the touch was not fused", reading,
                                ("rejected", "stroke_end"), tuple(kept))
        same = self._same
        same[:] = [reading, same[1] + 1 if reading == same[0] else 1]
        if self.frozen_after is not None and same[1] >= self.frozen_after:
            raise TouchRejected(f"reading {reading:.4f} mm, the very same value for {same[1]} "
                                "touches in a row, which the stated noise and readout step make "
                                "all but impossible: is the readout frozen (a stale value, a "
                                "register not updated)? The touch was not fused", reading,
                                ("rejected", "frozen"), tuple(kept))
        return Touch(x_mm, y_mm, z_mm, reading, t_s, tuple(kept[-self.samples:]),
                     {"spread_mm": float(values.max() - values.min()),
                      "attempts": len(problems) + 1, "problems": problems,
                      "all_samples": tuple(kept)})


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
