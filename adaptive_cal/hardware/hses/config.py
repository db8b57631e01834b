"""The ``robot.hses`` block: a Yaskawa controller over the High Speed Ethernet Server."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from adaptive_cal.hardware.config import Strict, check_host


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
        return check_host(v)
