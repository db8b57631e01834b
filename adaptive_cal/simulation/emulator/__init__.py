"""An emulated cell for bench tests and demos: HSES controller (UDP), Modbus PLC (TCP) and a
serial gauge (``socket://``) on loopback, all backed by one SimulatedCell's physics.

``start_emulator(cell)`` serves what the cell file names: ``robot.hses`` when the robot adapter
is ``hses``, one PLC per Modbus endpoint named by ``robot.modbus`` / ``probe.modbus``, and the
gauge of ``probe.serial`` when its port is ``socket://127.0.0.1:PORT``. With ``ephemeral=True``
every server takes a free port and ``client_cell()`` returns the cell file pointing at them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import urlparse

from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.cell.schema import Cell
from adaptive_cal.simulation.emulator.gauge import GaugeServer
from adaptive_cal.simulation.emulator.hses_server import HsesServer
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot

LOOPBACK = ("127.0.0.1", "localhost")


def _loopback(host: str, key: str) -> str:
    if host not in LOOPBACK:
        raise AdapterError(f"{key}={host!r}: the emulator serves on 127.0.0.1 only; point the "
                           "cell file at 127.0.0.1 to use it")
    return "127.0.0.1"


@dataclass
class Emulator:
    """The running servers; ``close()`` stops them all."""

    cell: Cell
    robot: EmulatedRobot
    hses: HsesServer | None = None
    plcs: dict[str, PlcServer] = field(default_factory=dict)  # by "robot"/"probe"
    gauge: GaugeServer | None = None

    @property
    def plc(self) -> PlcServer | None:
        return self.plcs.get("robot") or self.plcs.get("probe")

    def ports(self) -> dict[str, int]:
        out = {"hses": self.hses.port} if self.hses else {}
        out.update({f"modbus_{k}": p.port for k, p in self.plcs.items()})
        if self.gauge:
            out["gauge"] = self.gauge.port
        return out

    def client_cell(self) -> Cell:
        """The cell with its ports replaced by the ones the servers listen on."""
        d = self.cell.model_dump()
        if self.hses:
            d["robot"]["hses"]["port"] = self.hses.port
        for role, plc in self.plcs.items():
            d[role]["modbus"]["port"] = plc.port
        if self.gauge:
            d["probe"]["serial"]["port"] = f"socket://127.0.0.1:{self.gauge.port}"
        return Cell.model_validate(d)

    def close(self) -> None:
        for s in (self.hses, self.gauge, *{id(p): p for p in self.plcs.values()}.values()):
            if s is not None:
                s.close()


def start_emulator(cell: Cell, *, ephemeral: bool = False, move_s: float = 0.02) -> Emulator:
    """Start the servers the cell file names (see module docstring)."""
    emu = Emulator(cell, EmulatedRobot.from_cell(cell, move_s))
    try:
        r, p = cell.robot, cell.probe
        if r.adapter == "hses":
            host = _loopback(r.hses.host, "robot.hses.host")
            u = r.hses.user_frame_in_base
            frame = (u.origin_mm, u.rotation_deg) if u else ((0.0,) * 3, (0.0,) * 3)
            emu.hses = HsesServer(emu.robot, host, 0 if ephemeral else r.hses.port,
                                  r.hses.offset_mm, frame, r.hses.frame,
                                  user_frame_no=r.hses.user_frame).start()
        ends = {}
        for role, block in (("robot", r), ("probe", p)):
            if block.adapter == "modbus":
                cfg = block.modbus
                if role == "robot" and cell.workspace is not None:
                    ws = cell.workspace
                    try:
                        cfg.check_reach({"x_mm": ws.x_mm, "y_mm": ws.y_mm, "z_mm": ws.z_mm},
                                        "robot.modbus")
                    except ValueError as e:
                        raise AdapterError(str(e)) from None
                if cfg.transport != "tcp":
                    raise AdapterError(f"{role}.modbus.transport={cfg.transport!r}: the emulator "
                                       "serves Modbus TCP only")
                key = (cfg.host, cfg.port, cfg.device_id)
                if key not in ends:
                    host = _loopback(cfg.host, f"{role}.modbus.host")
                    box = None if cell.workspace is None or role != "robot" else (
                        cell.workspace.x_mm, cell.workspace.y_mm, cell.workspace.z_mm)
                    ends[key] = PlcServer(emu.robot, cfg, host, 0 if ephemeral else cfg.port,
                                          box=box).start()
                emu.plcs[role] = ends[key]
        if p.adapter == "serial":
            url = urlparse(p.serial.port)
            if url.scheme != "socket":
                raise AdapterError(f"probe.serial.port={p.serial.port!r}: the emulator serves "
                                   "a gauge on socket://127.0.0.1:PORT only")
            host = _loopback(url.hostname or "", "probe.serial.port")
            emu.gauge = GaugeServer(p.serial, lambda: emu.robot.read().reading_mm, host,
                                    0 if ephemeral else url.port).start()
    except BaseException:
        emu.close()
        raise
    return emu
