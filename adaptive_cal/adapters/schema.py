"""Config blocks of the hardware adapters (validated, unknown keys refused).

Each adapter's block sits under ``robot.<adapter>`` or ``probe.<adapter>`` in the cell file.
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class Strict(BaseModel):
    """Base for config blocks: immutable, unknown keys are an error (a typo must fail)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class ManualConfig(Strict):
    """The operator moves the robot and types the reading."""

    prompt: str = Field("", description="extra text shown with each point")


class HsesConfig(Strict):
    """Yaskawa High Speed Ethernet Server (UDP)."""

    host: str
    port: int = Field(10040, ge=1, le=65535)
    timeout_s: float = Field(0.5, gt=0)
    retries: int = Field(3, ge=0)
    user_frame: int = Field(1, ge=0, le=63)
    speed_mm_per_s: float = Field(50.0, gt=0)


class ModbusConfig(Strict):
    """A PLC or HMI over Modbus TCP."""

    host: str
    port: int = Field(502, ge=1, le=65535)
    device_id: int = Field(1, ge=0, le=247)
    timeout_s: float = Field(1.0, gt=0)


class SerialConfig(Strict):
    """A digital indicator on a serial port."""

    port: str
    preset: str = "mitutoyo"
    baudrate: int = 9600
    timeout_s: float = Field(1.0, gt=0)


class RobodkConfig(Strict):
    """Motion through the RoboDK API."""

    host: str = "127.0.0.1"
    port: int = Field(20500, ge=1, le=65535)
    robot_name: str = ""
    frame_name: str = ""
    run_on_robot: bool = False
