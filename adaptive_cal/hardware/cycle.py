"""The probe cycle that owns the touch sequence above a Motion and a ProbeDevice.

The cycle: check every target -> lift to the safe height (higher where the plate may stand within
the free tip's reach, ``planning.clearance``) -> travel -> approach (in steps from above where a
re-check's guard says the plate may stand higher) -> settle -> read N samples -> median -> reject
when the spread exceeds the tolerance (bounded retries) -> retract.
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
from typing import Callable

import numpy as np

from adaptive_cal.hardware.base import (CLEARANCE_MM, BadSample, Motion, ProbeDevice, Sample,
                                        StrokeOverrun, Touch, TouchRejected, UnsafeTarget,
                                        _left_down, interrupted_by)

log = logging.getLogger(__name__)


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
    #: where else the plate may stand (``planning.clearance.Guard``: a re-check's frames not
    #: assumed, and the cell's own prior): travels clear it too and approaches step down from
    #: above it; None: no other
    guard: object | None = None
    _same: list = field(default_factory=lambda: [math.nan, 0], init=False, repr=False)
    #: (x, y, z) of the last touch whose reading passed the usable stroke's top: the plate there
    #: stands higher than its approach allowed, and the same approach would overrun it again
    _overran: tuple | None = field(default=None, init=False, repr=False)
    _sent_z: float = field(default=math.nan, init=False, repr=False)  # the last approach sent

    def seed_repeats(self, readings) -> None:
        """Count the repeats at the end of ``readings`` (a resumed recording's, in order) as
        this cycle's own: a readout frozen before a stop is caught at the first touch after
        the resume, not after ``frozen_after`` more fused repeats (an outside audit)."""
        values = [float(v) for v in readings]
        n = 0
        while n < len(values) and values[-1 - n] == values[-1]:
            n += 1
        self._same[:] = [values[-1], n] if values else [math.nan, 0]

    def seed_overrun(self, rec) -> None:
        """A resumed recording whose last row read past the usable stroke's top: that approach
        is not sent again after the resume either (an outside audit: each --resume the stop
        advised overran the stroke once more)."""
        if len(rec) and "stroke_end" in rec.flags[-1] and rec.reading_mm[-1] > self.usable_mm[1]:
            self._overran = (float(rec.x_mm[-1]), float(rec.y_mm[-1]), float(rec.z_mm[-1]))

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
        zs = self.guard.approaches(x_mm, y_mm, z_mm) if self.guard is not None else [z_mm]
        o = self._overran
        if o is not None and math.hypot(x_mm - o[0], y_mm - o[1]) < 1e-3 and zs[0] <= o[2] + 1e-9:
            raise StrokeOverrun(  # a second audit: the same target three times, 1.5 mm past each
                f"the last touch at x={o[0]:.3f} y={o[1]:.3f} mm read past the usable stroke's "
                f"top from z={o[2]:.3f} mm: the plate stands higher there than the belief allowed, "
                f"and the approach to z={z_mm:.3f} mm would run the probe past its stroke's end "
                "again; nothing was sent. Check the plate's height in the cell file (workplane, "
                "model's offset prior and model.pivot_mm, where the frame's z was set) and the "
                "probe's zero")
        safe = max(self.safe_height_mm, zs[0])
        cx, cy, cz = self.motion.position()
        mine = plate_top((cx, cy)) if plate_top is not None else -math.inf
        other = self.guard.top_mm((cx, cy), (x_mm, y_mm)) if self.guard is not None else -math.inf
        if max(mine, other) > -math.inf:
            plate_top_mm = max(mine, other)
            need = plate_top_mm + self.reach_mm + CLEARANCE_MM
            if need > safe and not self.allowed(x_mm, y_mm, need):
                raise UnsafeTarget(
                    f"the plate may stand up to {plate_top_mm:.3f} mm under the travel to x="
                    f"{x_mm:.3f} y={y_mm:.3f} mm, and the free probe tip reaches "
                    f"{self.reach_mm:g} mm below the commanded height{self._where(mine, other)}: "
                    "travel at "
                    f"robot.safe_height_mm={self.safe_height_mm:g} would drag it over the plate, "
                    f"and the {need:.3f} mm it needs is outside the workspace box; nothing was "
                    "sent. Raise robot.safe_height_mm and workspace.z_mm's top, or level the "
                    "plate (before the first touches only the prior bounds the plate: a probe "
                    "parked above the workplane's middle travels over less of it)")
            safe = max(safe, need)
        if self.guard is not None:  # the cell's own prior: cleared as far as the box reaches
            soft = self.guard.soft_top_mm((cx, cy), (x_mm, y_mm)) + self.reach_mm + CLEARANCE_MM
            safe = max(safe, min(soft, self.guard.z_cap_mm))
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
        path.append((x_mm, y_mm, safe))
        self._check(path[:lifts], self.lift_allowed)  # every target before any is sent
        self._check(path[lifts:] + [(x_mm, y_mm, z) for z in zs])
        approached = False
        try:
            for k, target in enumerate(path):
                try:
                    self.motion.move_to(*target)
                except BaseException as lift:  # a first lift that failed: the tip may be down
                    if k or not below:
                        raise
                    raise _left_down(cx, cy, cz, safe, lift, "The probe was below the safe "
                                     "height when this touch began (an earlier stop, a resume); "
                                     "no touch was made", z_is="last known") from lift
            approached = True  # from here on the tip may be down: always retract
            touch = self._approach(x_mm, y_mm, zs)
        except BaseException as err:
            if approached:
                try:
                    self.motion.move_to(x_mm, y_mm, safe)
                except BaseException as lift:  # the danger first (a Ctrl-C too), then the cause
                    why = (interrupted_by(err) if isinstance(err, KeyboardInterrupt)
                           else f"{type(err).__name__}: {err}")
                    raise _left_down(x_mm, y_mm, self._sent_z, safe, lift,  # the step sent
                                     f"What stopped the touch: {why}", err=err) from err
            raise
        try:
            self.motion.move_to(x_mm, y_mm, safe)  # retract
        except BaseException as lift:  # a Ctrl-C during the retract too: the warning first
            raise _left_down(x_mm, y_mm, touch.z_mm, safe, lift, f"The reading "
                             f"{touch.reading_mm:.4f} mm was taken and is kept", touch) from lift
        return touch

    def _where(self, mine: float, other: float) -> str:
        """Why the plate may stand that high, where a guard's frame is the higher."""
        if other <= mine:
            return ""
        return (f" (the plate as it stands in {self.guard.said}; a map from scratch, without "
                "--prior-from, does not keep clear of it)")

    def _approach(self, x_mm: float, y_mm: float, zs: list[float]) -> Touch:
        """Approach down ``zs`` (one height; a guard's steps, highest first) and read; a step
        that reads below the usable stroke (no contact yet) goes on to the next, a lower one."""
        for k, z in enumerate(zs):
            self._sent_z = z  # a stop from here on names the height sent, not the target's
            self.motion.move_to(x_mm, y_mm, z)
            try:
                touch = self._read(x_mm, y_mm, z)
            except TouchRejected as e:
                e.z_mm = z
                if k + 1 == len(zs) or not e.reading_mm < self.usable_mm[0] \
                        or "stroke_end" not in e.flags:
                    raise
                log.info("guarded approach at x=%.3f y=%.3f: no contact at z=%.3f mm (read "
                         "%.4f mm); down to z=%.3f mm", x_mm, y_mm, z, e.reading_mm, zs[k + 1])
                continue
            if self.guard is not None:
                self.guard.seen(x_mm, y_mm, z, touch.reading_mm)
            return touch
        raise AssertionError("no approach height")  # zs is never empty

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
