"""The ``manual`` adapter: the tool shows the next point, the operator jogs the probe there and
types the reading. For cells with no data path yet, and for notebooks.

Implements Motion (it only remembers the commanded pose) and ProbeDevice (it asks). The streams
are injectable so tests and notebooks can drive it; ``q`` or end of input stops the run.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Callable, TextIO

from adaptive_cal.hardware.base import AdapterError, BadSample, OperatorStop, Sample


@dataclass
class ManualCell:
    """Operator-driven motion and probe (both protocols).

    ``ask(prompt) -> str`` returns the typed line (default: reads ``stdin``); ``out`` gets the
    instructions. Non-numeric answers are asked again up to ``attempts`` times.
    """

    out: TextIO = field(default_factory=lambda: sys.stdout)
    inp: TextIO | None = None
    ask: Callable[[str], str] | None = None
    prompt: str = ""
    attempts: int = 3
    range_mm: tuple[float, float] | None = None
    pose: tuple[float, float, float] = (float("nan"),) * 3
    before: tuple[float, float, float] = (float("nan"),) * 3  # the move before: the travel
    clock: Callable[[], float] = time.monotonic

    def _ask(self, text: str) -> str:
        if self.ask is not None:
            return self.ask(text)
        self.out.write(text)
        self.out.flush()
        line = (self.inp or sys.stdin).readline()
        if line == "":
            raise AdapterError("manual adapter: input ended (no reading typed); the run stops "
                               "here; type the readings, then continue with --resume")
        return line

    # -- Motion -----------------------------------------------------------------------
    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        self.before, self.pose = self.pose, (x_mm, y_mm, z_mm)

    def position(self) -> tuple[float, float, float]:
        return self.pose

    # -- Probe --------------------------------------------------------------------------
    def read(self) -> Sample:
        x, y, z = self.pose
        extra = f" {self.prompt}" if self.prompt else ""
        bx, by, bz = self.before  # above the point: the height the probe travelled there at
        over = f" (travel there at z={bz:.3f} mm)" if (bx, by) == (x, y) and bz > z else ""
        self.out.write(f"next point: x={x:.3f} y={y:.3f} mm, probe reference z={z:.3f} mm"
                       f"{over}{extra}\n")
        answers = []
        for _ in range(self.attempts):
            line = self._ask("reading in mm (q to stop): ").strip()
            answers.append(line)
            if line.lower() in ("q", "quit", "stop"):
                raise OperatorStop("manual adapter: stopped by the operator; continue the run "
                                   "later with --resume")
            try:
                value = float(line.replace(",", "."))
            except ValueError:
                self.out.write(f"  {line!r} is not a number in mm; type e.g. 5.0123\n")
                continue
            if value != value or value in (float("inf"), float("-inf")):
                self.out.write(f"  {line!r} is not a finite number\n")
                continue
            if self.range_mm and not self.range_mm[0] <= value <= self.range_mm[1]:
                self.out.write(f"  {value} mm is outside the probe range {list(self.range_mm)}\n")
                continue
            return Sample(value, self.clock(), line.encode())
        raise BadSample(f"manual adapter: no valid reading in {self.attempts} answers "
                        f"({', '.join(map(repr, answers))})", " | ".join(answers).encode())

    def close(self) -> None:
        pass
