"""The ``robot.modbus`` / ``probe.modbus`` block: a PLC or HMI over Modbus TCP, RTU or ASCII,
and where its handshake registers live."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal.hardware.config import Strict, check_baud, check_host, check_scale
from adaptive_cal.hardware.modbus.registers import check_map


class ModbusRegisters(Strict):
    """Where the handshake lives in the PLC. Names: Delta D/M/X/Y (X, Y octal), DOP HMI $n/$Mn,
    or raw ``hr:N`` (holding register), ``coil:N``, ``di:N`` (discrete input), ``ir:N`` (input
    register): N is the protocol address, counted from 0 (hr:100 is Modicon's 40101)."""

    start: str = Field("M10", description="PC sets: go to the target")
    done: str = Field("M11", description="PLC sets: target reached")
    fault: str = Field("M12", description="PLC sets: stop (e-stop, door, watchdog)")
    probe_trigger: str = Field("M13", description="PC sets: take one probe sample")
    target_x: str = Field("D100", description="PC writes: target x (mm x scale, workplane "
                          "frame)")
    target_y: str = Field("D102", description="PC writes: target y")
    target_z: str = Field("D104", description="PC writes: target z")
    probe_value: str = Field("D110", description="last probe sample")
    probe_count: str = Field("D112", description="16-bit counter, +1 per sample (staleness)")
    watchdog: str = Field("D120", description="PC increments it at least every watchdog_s")
    actual_x: str | None = Field(None, description="PLC writes: where the tip is now (the job "
                                 "writes its current position, as the targets: mm x scale, "
                                 "workplane frame); the first move then lifts straight up first. "
                                 "All three or none")
    actual_y: str | None = Field(None, description="PLC writes: where the tip is now, y")
    actual_z: str | None = Field(None, description="PLC writes: where the tip is now, z")

    @model_validator(mode="after")
    def _all_three_or_none(self):
        given = [r for r in ("actual_x", "actual_y", "actual_z") if getattr(self, r) is not None]
        if given and len(given) < 3:
            missing = sorted({"actual_x", "actual_y", "actual_z"} - set(given))
            raise ValueError(f"registers.{given[0]}={getattr(self, given[0])!r} needs "
                             f"{' and '.join('registers.' + m for m in missing)} too: the "
                             "position is read whole or not at all")
        return self

    def roles(self) -> dict[str, str]:
        return self.model_dump(exclude_none=True)


class ModbusConfig(Strict):
    """A PLC or HMI over Modbus TCP, or RTU/ASCII on a serial line (pyserial URL allowed)."""

    transport: Literal["tcp", "rtu", "ascii"] = Field(
        "tcp", description="Modbus TCP, or RTU / ASCII framing on a serial line")
    host: str | None = Field(None, description="tcp: the PLC's (or gateway's) IP address")
    port: int | None = Field(None, ge=1, le=65535, description="tcp: its port (502 on most PLCs)")
    serial_port: str | None = Field(None, description="rtu / ascii: the serial device "
                                    "(/dev/ttyUSB0, COM3) or a pyserial URL")
    baudrate: int = Field(9600, description="rtu / ascii: line speed")
    parity: Literal["N", "E", "O"] = Field("E", description="serial parity (Modbus: even by "
                                           "default)")
    bytesize: Literal[7, 8] | None = Field(
        None, description="serial data bits; left out: 8 for rtu (Modbus RTU is 8 data bits, "
        "Modbus over Serial Line V1.02 s.2.5.1), 7 for ascii (Delta DVP's 9600 7E1); rtu with 7 "
        "is refused")
    stopbits: Literal[1, 2] = Field(1, description="rtu / ascii: stop bits")
    device_id: int = Field(1, ge=0, le=247, description="the PLC's station number (unit id; "
                           "behind a gateway, the unit it forwards to)")
    timeout_s: float = Field(1.0, gt=0, description="wait for one answer")
    retries: int = Field(1, ge=0, description="re-sends after an unanswered request (pymodbus)")
    word_order: Literal["big", "little"] = Field(
        "little", description="order of the two words of a 32-bit value (Delta: little, verify)")
    number: Literal["int32", "float32", "int16"] = Field(
        "int32", description="how a length is held in the registers (x scale)")
    scale: float = Field(10000.0, description="register counts per mm (10000: 0.1 um, as "
                         "hw/plc-register-map.md and hw/ACAL_TOUCH.JBI expect)")
    registers: ModbusRegisters = Field(ModbusRegisters(), description="where the handshake "
                                       "lives in the PLC (hw/plc-register-map.md)")
    watchdog_s: float = Field(1.0, gt=0, description="the PLC faults when the watchdog is older")
    move_timeout_s: float = Field(60.0, gt=0, description="the longest from start to done "
                                  "before the run stops")
    probe_timeout_s: float = Field(2.0, gt=0, description="the longest from the trigger to a "
                                   "new probe_count before the sample is rejected as stale")
    poll_s: float = Field(0.02, gt=0, description="polling period for done and probe_count")
    parked_at_safe_height: bool = Field(
        False, description="where registers.actual_x/y/z are not mapped the PC cannot know where "
        "the robot stands, and the first move goes straight to the safe height above the first "
        "target: true states that every run starts with the robot parked at or above "
        "robot.safe_height_mm, clear of the plate and fixtures; false (the default) refuses "
        "such a cell file at load, before any move")
    scan_s: float = Field(
        0.05, gt=0, le=5, description="the PLC's longest program scan (with an HMI or gateway in "
        "between, its update period): the PC sets a rising-edge flag (start, probe_trigger) only "
        "after it has been off this long -- since the PLC cleared it or the PC wrote it off -- so "
        "that a scan sees it off (an edge is what one scan sees against the one before)")
    done_settle_s: float = Field(
        0.05, gt=0, le=5, description="after the PC clears done, it must stay off this long "
        "(several PLC scans) before start is set; a PLC that copies the robot's done output "
        "into the done flag is refused")

    @model_validator(mode="before")
    @classmethod
    def _bytesize_of_the_transport(cls, data):
        if isinstance(data, dict) and data.get("bytesize") is None:
            data = {**data, "bytesize": 7 if data.get("transport") == "ascii" else 8}
        return data

    @field_validator("baudrate")
    @classmethod
    def _check_baud(cls, v):
        return check_baud(v)

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        return check_scale(v, "register counts per mm")

    @model_validator(mode="after")
    def _link(self):
        if self.transport == "tcp":
            missing = [k for k in ("host", "port") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"transport 'tcp' needs {' and '.join(missing)}")
            check_host(self.host)
        elif self.serial_port is None:
            raise ValueError(f"transport '{self.transport}' needs serial_port")
        elif self.device_id == 0:
            raise ValueError(f"device_id 0 with transport '{self.transport}': 0 is the broadcast "
                             "address on a serial line (Modbus over Serial Line V1.02 s.2.2): no "
                             "device answers, and every write reaches every device; give the "
                             "PLC's station number, 1-247")
        if self.transport == "rtu" and self.bytesize == 7:
            raise ValueError("bytesize 7 with transport 'rtu': Modbus RTU frames are 8 data bits "
                             "(Modbus over Serial Line V1.02 s.2.5.1); use bytesize 8, or "
                             "transport 'ascii' for a 7-bit line (Delta DVP default 9600 7E1)")
        check_map(self.registers.roles(), 1 if self.number == "int16" else 2)
        return self

    def reach_mm(self) -> float:
        """The largest |value| in mm that ``number`` carries at ``scale`` (float32: while one
        count stays exact, 2**24 counts)."""
        counts = {"int16": 2 ** 15 - 1, "int32": 2 ** 31 - 1, "float32": 2 ** 24}[self.number]
        return counts / abs(self.scale)

    def check_reach(self, box: dict[str, tuple[float, float]], key: str,
                    what: str = "the workspace") -> None:
        """ValueError naming ``key``.scale/number when a corner of ``box`` (axis -> (lo, hi), mm:
        the workspace, every target that can be sent; or the probe's stroke, every reading that
        can come) does not fit the registers."""
        reach = self.reach_mm()
        for axis, (lo, hi) in box.items():
            worst = max(abs(lo), abs(hi))
            if not worst <= reach:
                raise ValueError(
                    f"{key}.scale={self.scale:g} with {key}.number={self.number!r} carries at "
                    f"most {reach:g} mm, but {what} {axis}={[lo, hi]} reaches {worst:g} "
                    f"mm: lower {key}.scale or use a wider number (int32)")
