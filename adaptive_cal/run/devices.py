"""Open the probe cycle a cell file asks for: the adapters selected by ``robot.adapter`` and
``probe.adapter``, wrapped in the safety check (workplane, keep-outs, workspace box)."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from adaptive_cal.cell.build import readout_frozen_after, workspace
from adaptive_cal.cell.schema import Cell
from adaptive_cal.hardware.base import AdapterError, Motion, ProbeDevice
from adaptive_cal.hardware.cycle import ProbeCycle


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
    outside every keep-out; with a ``workspace`` box (the cell file's, or the one derived for
    a simulated cell, ``cell.build.workspace``) the target must also lie inside it.
    """
    wp, ws = cell.workplane, workspace(cell)

    def allowed(x: float, y: float, z: float) -> bool:
        if not wp.allows(x, y):
            return False
        return ws is None or ws.contains(x, y, z)

    return allowed


def box_check(cell: Cell) -> Callable[[float, float, float], bool]:
    """The workspace box alone (every point without one): a lift straight up where the probe
    stands adds no x, y, so the workplane's margin and keep-outs, about touches, do not apply."""
    ws = workspace(cell)
    return lambda x, y, z: ws is None or ws.contains(x, y, z)


LINE_KEYS = ("transport", "baudrate", "parity", "bytesize", "stopbits", "timeout_s", "retries")


def _modbus_links(cell: Cell, opened: list) -> dict:
    """One ModbusLink per endpoint; robot and probe share it when they name the same PLC. Two
    devices on one serial line (other device ids) share its port and client: Modbus over
    Serial Line allows one master per line, and two clients would interleave their frames."""
    from adaptive_cal.hardware.modbus.adapter import ModbusLink

    links, by_end, by_line = {}, {}, {}
    for role, block in (("robot", cell.robot), ("probe", cell.probe)):
        if block.adapter != "modbus":
            continue
        cfg = block.modbus
        end = (cfg.transport, cfg.host, cfg.port, cfg.serial_port, cfg.device_id)
        if end in by_end:
            if by_end[end][0] != cfg:
                raise AdapterError(f"robot.modbus and probe.modbus name the same PLC {end[1:]} "
                                   "with different settings; make the two blocks identical")
            links[role] = by_end[end][1]
            continue
        line = by_line.get(cfg.serial_port) if cfg.transport != "tcp" else None
        if line is not None:
            differ = [k for k in LINE_KEYS if getattr(line.cfg, k) != getattr(cfg, k)]
            if differ:
                raise AdapterError(
                    f"robot.modbus and probe.modbus share the serial line {cfg.serial_port} "
                    f"with different line settings ({', '.join(differ)}); one line has one "
                    "set: make them equal")
        link = ModbusLink(cfg, line=line)
        opened.append(link)
        by_end[end] = (cfg, link)
        if cfg.transport != "tcp":
            by_line.setdefault(cfg.serial_port, link)
        links[role] = link
    return links


def _require(module: str, what: str) -> None:
    """An optional device library (only RoboDK's client is optional): a missing one is a
    message naming the extra that installs it, not a ModuleNotFoundError."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise AdapterError(f"{what} needs the '{module}' package, which is not installed: "
                           'pip install "adaptive-cal[hw]"')


def _motion(cell: Cell, links: dict, manual) -> Motion:
    r = cell.robot
    if r.adapter == "manual":
        return manual
    if r.adapter == "hses":
        from adaptive_cal.hardware.hses.adapter import HsesMotion

        return HsesMotion(r.hses)
    if r.adapter == "modbus":
        from adaptive_cal.hardware.modbus.adapter import ModbusMotion

        return ModbusMotion(links["robot"])
    if r.adapter == "robodk":
        _require("robodk", "robot.adapter: robodk")
        from adaptive_cal.hardware.robodk.adapter import RobodkMotion

        return RobodkMotion(r.robodk)
    raise AdapterError(f"robot.adapter={r.adapter!r} cannot be combined with "
                       f"probe.adapter={cell.probe.adapter!r}")


def _probe(cell: Cell, links: dict, manual) -> ProbeDevice:
    p = cell.probe
    if p.adapter == "manual":
        return manual
    if p.adapter == "serial":
        from adaptive_cal.hardware.serial.adapter import SerialProbe

        return SerialProbe(p.serial)
    if p.adapter == "modbus":
        from adaptive_cal.hardware.modbus.adapter import ModbusProbe

        return ModbusProbe(links["probe"])
    raise AdapterError(f"probe.adapter={p.adapter!r} needs robot.adapter 'sim' (the simulated "
                       "probe only exists in the simulated cell)")


def open_cell(cell: Cell, *, start_t_s: float = 0.0, start_touch: int = 0,
              manual=None, start_arrival: tuple[float, float] | None = None) -> OpenCell:
    """Connect to the cell named by the cell file. ``manual`` replaces the operator console
    (a ManualCell with injected streams, for notebooks and tests). ``cell``: a Cell, or a cell
    file's path or dict (``cell.schema.as_cell``)."""
    from adaptive_cal.cell.schema import as_cell

    cell = as_cell(cell)
    allowed = safety_check(cell)
    p = cell.probe
    if cell.robot.adapter == "sim":
        from adaptive_cal.simulation.cell import SimulatedCell

        sim = SimulatedCell.from_cell(cell, start_t_s=start_t_s, start_touch=start_touch,
                                      start_arrival=start_arrival)
        cycle = ProbeCycle(sim, sim, allowed, cell.robot.safe_height_mm, p.usable_mm, p.samples,
                           p.samples_tolerance_mm, p.retries, 0.0, clock=lambda: sim.t_s,
                           sleep=lambda s: None, reach_mm=p.zero_mm - p.rest_mm,
                           lift_allowed=box_check(cell))
        return OpenCell(cycle, lambda: sim.t_s, sim.close, sim)
    if "manual" in (cell.robot.adapter, p.adapter) and manual is None:
        from adaptive_cal.hardware.manual.adapter import ManualCell

        m = cell.robot.manual
        manual = ManualCell(prompt=m.prompt if m else "", attempts=m.attempts if m else 3,
                            range_mm=(p.rest_mm, p.rest_mm + p.stroke_mm))
    opened: list = []
    try:
        links = _modbus_links(cell, opened)
        motion = _motion(cell, links, manual)
        opened.append(motion)
        probe = _probe(cell, links, manual)
        opened.append(probe)
    except BaseException:
        for dev in reversed(opened):
            dev.close()
        raise
    t0 = time.monotonic() - start_t_s
    clock = lambda: time.monotonic() - t0  # noqa: E731

    def close() -> None:
        seen = set()
        for dev in reversed(opened):
            if id(dev) not in seen:
                seen.add(id(dev))
                dev.close()

    # a device can freeze (the simulated probe cannot: a noise-free one repeats honestly)
    cycle = ProbeCycle(motion, probe, allowed, cell.robot.safe_height_mm, p.usable_mm,
                       p.samples, p.samples_tolerance_mm, p.retries, p.settle_s, clock=clock,
                       frozen_after=readout_frozen_after(cell), reach_mm=p.zero_mm - p.rest_mm,
                       lift_allowed=box_check(cell))
    return OpenCell(cycle, clock, close, None)
