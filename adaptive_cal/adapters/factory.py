"""Open the probe cycle a cell file asks for: the adapters selected by ``robot.adapter`` and
``probe.adapter``, wrapped in the safety check (workplane, keep-outs, workspace box)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..config import Cell
from .base import ProbeCycle


@dataclass
class OpenCell:
    """A connected cell: the probe cycle, a clock (s since the run start) and a closer."""

    cycle: ProbeCycle
    clock: Callable[[], float]
    close: Callable[[], None]
    simulated: object | None = None  # the SimulatedCell when the truth is known


def safety_check(cell: Cell) -> Callable[[float, float, float], bool]:
    """The one function that decides whether a target may be sent.

    x, y must lie inside the workplane less its edge margin and
    outside every keep-out; with a ``workspace`` box the target must also lie inside it.
    """
    wp, ws = cell.workplane, cell.workspace

    def allowed(x: float, y: float, z: float) -> bool:
        if not wp.allows(x, y):
            return False
        return ws is None or ws.contains(x, y, z)

    return allowed


def open_cell(cell: Cell, *, start_t_s: float = 0.0, start_touch: int = 0) -> OpenCell:
    """Connect to the cell named by the cell file."""
    allowed = safety_check(cell)
    if cell.robot.adapter == "sim":
        from .sim import SimulatedCell

        sim = SimulatedCell.from_cell(cell, start_t_s=start_t_s, start_touch=start_touch)
        p = cell.probe
        cycle = ProbeCycle(sim, sim, allowed, cell.robot.safe_height_mm, p.usable_mm, p.samples,
                           p.samples_tolerance_mm, p.retries, 0.0, clock=lambda: sim.t_s,
                           sleep=lambda s: None)
        return OpenCell(cycle, lambda: sim.t_s, sim.close, sim)
    raise NotImplementedError(f"robot.adapter '{cell.robot.adapter}' is not wired yet")
