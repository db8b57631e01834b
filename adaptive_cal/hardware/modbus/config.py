"""The ``robot.modbus`` / ``probe.modbus`` block: a PLC or HMI over Modbus TCP, RTU or ASCII,
and where its handshake registers live."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal.hardware.config import Strict, check_baud, check_host
from adaptive_cal.hardware.modbus.registers import check_map


class ModbusRegisters(Strict):
    """Where the handshake lives in the PLC. Names: Delta D/M/X/Y (X, Y octal), DOP HMI $n/$Mn,
    or raw ``hr:N`` (holding register), ``coil:N``, ``di:N`` (discrete input)."""

    start: str = Field("M10", description="PC sets: go to the target")
    done: str = Field("M11", description="PLC sets: target reached")
    fault: str = Field("M12", description="PLC sets: stop (e-stop, door, watchdog)")
    probe_trigger: str = Field("M13", description="PC sets: take one probe sample")
    target_x: str = "D100"
    target_y: str = "D102"
    target_z: str = "D104"
    probe_value: str = Field("D110", description="last probe sample")
    probe_count: str = Field("D112", description="16-bit counter, +1 per sample (staleness)")
    watchdog: str = Field("D120", description="PC increments it at least every watchdog_s")

    def roles(self) -> dict[str, str]:
        return self.model_dump()


class ModbusConfig(Strict):
    """A PLC or HMI over Modbus TCP, or RTU/ASCII on a serial line (pyserial URL allowed)."""

    transport: Literal["tcp", "rtu", "ascii"] = "tcp"
    host: str | None = None
    port: int | None = Field(None, ge=1, le=65535)
    serial_port: str | None = None
    baudrate: int = 9600
    parity: Literal["N", "E", "O"] = "E"
    bytesize: Literal[7, 8] = 7
    stopbits: Literal[1, 2] = 1
    device_id: int = Field(1, ge=0, le=247)
    timeout_s: float = Field(1.0, gt=0)
    retries: int = Field(1, ge=0)
    word_order: Literal["big", "little"] = Field(
        "little", description="order of the two words of a 32-bit value (Delta: little, verify)")
    number: Literal["int32", "float32", "int16"] = "int32"
    scale: float = Field(1000.0, description="register value per mm (1000: um as integers)")
    registers: ModbusRegisters = ModbusRegisters()
    watchdog_s: float = Field(1.0, gt=0, description="the PLC faults when the watchdog is older")
    move_timeout_s: float = Field(60.0, gt=0)
    probe_timeout_s: float = Field(2.0, gt=0)
    poll_s: float = Field(0.02, gt=0)

    @field_validator("baudrate")
    @classmethod
    def _check_baud(cls, v):
        return check_baud(v)

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        if not v or v != v:
            raise ValueError(f"scale must be a non-zero number, got {v}")
        return v

    @model_validator(mode="after")
    def _link(self):
        if self.transport == "tcp":
            missing = [k for k in ("host", "port") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"transport 'tcp' needs {' and '.join(missing)}")
            check_host(self.host)
        elif self.serial_port is None:
            raise ValueError(f"transport '{self.transport}' needs serial_port")
        check_map(self.registers.roles(), 1 if self.number == "int16" else 2)
        return self
