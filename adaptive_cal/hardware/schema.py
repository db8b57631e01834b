"""Config blocks of the hardware adapters (validated, unknown keys refused).

Each adapter's block sits under ``robot.<adapter>`` or ``probe.<adapter>`` in the cell file.
Everything that HARDWARE.md marks "(verify)" is a field here, not a constant in the code.
"""
from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

# the rates a UART and pyserial both accept; anything else is a typo
BAUD_RATES = (300, 600, 1200, 2400, 4800, 9600, 14400, 19200, 38400, 57600, 115200, 230400)


class Strict(BaseModel):
    """Base for config blocks: immutable, unknown keys are an error (a typo must fail)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def _host(v: str) -> str:
    if not v or not v.strip():
        raise ValueError("host must be an IP address or a host name, got an empty string")
    return v.strip()


def _baud(v: int | None) -> int | None:
    if v is not None and v not in BAUD_RATES:
        raise ValueError(f"baud rate {v} does not exist; use one of {list(BAUD_RATES)}")
    return v


class ManualConfig(Strict):
    """The operator moves the robot and types the reading."""

    prompt: str = Field("", description="extra text shown with each point")
    attempts: int = Field(3, ge=1, description="non-numeric answers tolerated per reading")


class HsesConfig(Strict):
    """Yaskawa High Speed Ethernet Server (UDP). Host and port are required (10040 on a real
    controller; the emulator uses the one given here)."""

    host: str
    port: int = Field(ge=1, le=65535)
    timeout_s: float = Field(0.5, gt=0, description="wait for one answer")
    retries: int = Field(3, ge=0, description="re-sends after an unanswered request")
    frame: Literal["user", "base"] = "user"
    user_frame: int = Field(1, ge=1, le=63, description="user frame taught on the plate")
    tool: int = Field(0, ge=0, le=63)
    speed_mm_per_s: float = Field(50.0, gt=0, le=1000)
    orientation_deg: tuple[float, float, float] = Field(
        (180.0, 0.0, 0.0), description="Rx Ry Rz of the tool held during every move")
    offset_mm: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="workplane origin in the robot frame")
    check_position: bool = Field(True, description="compare the reported position to the target "
                                 "(verify: the controller may report another frame)")
    position_tolerance_mm: float = Field(0.1, gt=0)
    move_timeout_s: float = Field(60.0, gt=0)
    poll_s: float = Field(0.02, gt=0)
    reset_alarms: bool = Field(False, description="reset a controller alarm once and retry")

    @field_validator("host")
    @classmethod
    def _check_host(cls, v):
        return _host(v)


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


FLAG_ROLES = ("start", "done", "fault", "probe_trigger")
WRITTEN_FLAGS = ("start", "probe_trigger")


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
        return _baud(v)

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        if not v or v != v:
            raise ValueError(f"scale must be a non-zero number, got {v}")
        return v

    @model_validator(mode="after")
    def _link(self):
        from adaptive_cal.hardware.modbus_map import check_map  # the map parser lives with the adapter

        if self.transport == "tcp":
            missing = [k for k in ("host", "port") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"transport 'tcp' needs {' and '.join(missing)}")
            _host(self.host)
        elif self.serial_port is None:
            raise ValueError(f"transport '{self.transport}' needs serial_port")
        check_map(self.registers.roles(), 1 if self.number == "int16" else 2)
        return self


PRESETS = ("mitutoyo", "sylvac", "keyence", "custom")


class SerialConfig(Strict):
    """A digital indicator on a serial port (a device path or a pyserial URL like
    ``socket://127.0.0.1:5020``). Preset values fill what is not given."""

    port: str
    preset: Literal["mitutoyo", "sylvac", "keyence", "custom"] = "mitutoyo"
    baudrate: int | None = None
    bytesize: Literal[7, 8] | None = None
    parity: Literal["N", "E", "O"] | None = None
    stopbits: Literal[1, 2] | None = None
    request: str | None = Field(None, description="bytes sent per sample; \\r \\n escapes")
    pattern: str | None = Field(None, description="regex; group 'value' or group 1 is the number")
    scale: float = Field(1.0, description="mm per unit of the parsed number")
    timeout_s: float = Field(1.0, gt=0)
    dtr: bool | None = None
    rts: bool | None = None
    range_mm: tuple[float, float] | None = Field(None, description="values outside are rejected")

    @field_validator("baudrate")
    @classmethod
    def _check_baud(cls, v):
        return _baud(v)

    @field_validator("pattern")
    @classmethod
    def _pattern(cls, v):
        if v is None:
            return v
        try:
            rx = re.compile(v)
        except re.error as e:
            raise ValueError(f"pattern {v!r} is not a regular expression: {e}") from None
        if rx.groups < 1:
            raise ValueError(f"pattern {v!r} needs a group around the number, e.g. ([-+]?[0-9.]+)")
        return v

    @model_validator(mode="after")
    def _custom(self):
        if self.preset == "custom" and self.pattern is None:
            raise ValueError("preset 'custom' needs a pattern (and usually request and scale)")
        return self


class RobodkConfig(Strict):
    """Motion through the RoboDK API."""

    host: str = "127.0.0.1"
    port: int = Field(20500, ge=1, le=65535)
    robot_name: str = ""
    frame_name: str = ""
    run_on_robot: bool = False
    orientation_deg: tuple[float, float, float] = (180.0, 0.0, 0.0)
    speed_mm_per_s: float = Field(50.0, gt=0)

    @field_validator("host")
    @classmethod
    def _check_host(cls, v):
        return _host(v)
