"""The ``robot.robodk`` block: motion through the RoboDK API."""
from __future__ import annotations

from pydantic import Field, field_validator

from adaptive_cal.hardware.config import Strict, check_host


class RobodkConfig(Strict):
    """Motion through the RoboDK API."""

    host: str = Field("127.0.0.1", description="the computer RoboDK runs on ('localhost' is "
                      "sent as 127.0.0.1)")
    port: int = Field(20500, ge=1, le=65535, description="RoboDK's API port")
    robot_name: str = Field("", description="the station's robot, by its exact name; empty: "
                            "the first robot of the station")
    frame_name: str = Field(description="the RoboDK reference frame on the workplane, by its "
                            "exact name: every target is a pose in it (required: an empty "
                            "name would leave RoboDK's active frame)")
    run_on_robot: bool = Field(False, description="true: RUNMODE_RUN_ROBOT, the robot driver "
                               "moves the real robot; false: RoboDK only simulates")
    orientation_deg: tuple[float, float, float] = Field(
        (180.0, 0.0, 0.0), description="Rx Ry Rz of the tool held during every move")
    speed_mm_per_s: float = Field(50.0, gt=0, description="the linear speed RoboDK moves at "
                                  "(robot.speed_mm_per_s only estimates robot time)")

    @field_validator("frame_name")
    @classmethod
    def _frame_named(cls, v):
        if not v.strip():
            raise ValueError("frame_name is empty: name the RoboDK reference frame on the "
                             "workplane (targets in whatever frame is active would make the "
                             "workspace check meaningless)")
        return v

    @field_validator("host")
    @classmethod
    def _check_host(cls, v):
        return check_host(v)
