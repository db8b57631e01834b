"""The ``robot.robodk`` block: motion through the RoboDK API."""
from __future__ import annotations

from pydantic import Field, field_validator

from adaptive_cal.hardware.config import Strict, check_host


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
        return check_host(v)
