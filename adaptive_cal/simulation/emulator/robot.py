"""The emulated robot: a SimulatedCell's physics behind a motion that takes time.

The HSES server and the PLC command it; the gauge reads the plate at the pose the robot actually
reached (a move counts as reached only when its time is over). Thread-safe.
"""
from __future__ import annotations

import threading
import time

from adaptive_cal.hardware.base import Sample
from adaptive_cal.simulation.cell import SimulatedCell
from adaptive_cal.cell.schema import Cell


class EmulatedRobot:
    """Robot state shared by the emulated controllers. ``move_s`` is the time of every move."""

    def __init__(self, sim: SimulatedCell, move_s: float = 0.02, clock=time.monotonic):
        self.sim, self.move_s, self.clock = sim, move_s, clock
        self.lock = threading.RLock()
        self._target: tuple[float, float, float] | None = None
        self._until = 0.0
        self.moves = 0
        self.readings = 0
        self.alarm = False

    @classmethod
    def from_cell(cls, cell: Cell, move_s: float = 0.02) -> "EmulatedRobot":
        return cls(SimulatedCell.from_cell(cell), move_s)

    def _settle(self) -> None:
        if self._target is not None and self.clock() >= self._until:
            self.sim.move_to(*self._target)
            self._target = None

    def command(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        """Start a move (workplane frame); it is reached after ``move_s``."""
        with self.lock:
            self._settle()
            self._target = (x_mm, y_mm, z_mm)
            self._until = self.clock() + self.move_s
            self.moves += 1

    def stop(self) -> None:
        """Stop where the robot is (an alarm): the running move is abandoned."""
        with self.lock:
            self._target = None

    def moving(self) -> bool:
        with self.lock:
            self._settle()
            return self._target is not None

    def pose(self) -> tuple[float, float, float]:
        with self.lock:
            self._settle()
            return tuple(self.sim.pose)

    def read(self) -> Sample:
        """One gauge sample at the reached pose (simulated plate, noise, stroke, resolution)."""
        with self.lock:
            self._settle()
            self.readings += 1
            return self.sim.read()
