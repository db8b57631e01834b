"""The ``robot.robodk`` block: motion through the RoboDK API."""
from __future__ import annotations

from pydantic import Field, field_validator

from adaptive_cal.hardware.config import Strict, check_host


class RobodkConfig(Strict):
    """Motion through the RoboDK API."""

    host: str = Field("127.0.0.1", description="the computer RoboDK runs on ('localhost' is "
                      "sent as 127.0.0.1)")
    port: int = Field(20500, ge=1, le=65535, description="RoboDK's API port")
    robot_name: str = Field(description="the station's robot, by its exact name (required: an "
                            "empty name takes the first item of robot type, which may be a "
                            "turntable or another arm)")
    tool_name: str = Field(description="the probe tip's tool in the station, by its exact name: "
                           "set as the robot's active tool before any move (required: targets "
                           "and the position read are of the active tool's centre point)")
    frame_name: str = Field(description="the RoboDK reference frame on the workplane, by its "
                            "exact name: every target is a pose in it (required: an empty "
                            "name would leave RoboDK's active frame)")
    run_on_robot: bool = Field(False, description="true: RUNMODE_RUN_ROBOT, the robot driver "
                               "moves the real robot; false: RoboDK only simulates")
    orientation_deg: tuple[float, float, float] = Field(
        (180.0, 0.0, 0.0), description="Rx Ry Rz of the tool held during every move")
    speed_mm_per_s: float = Field(50.0, gt=0, le=1000, description="the linear speed RoboDK "
                                  "moves at, also into contact (robot.speed_mm_per_s only "
                                  "estimates robot time)")

    @field_validator("frame_name", "robot_name", "tool_name")
    @classmethod
    def _named(cls, v, info):
        what = {"frame_name": "the RoboDK reference frame on the workplane (targets in whatever "
                              "frame is active would make the workspace check meaningless)",
                "robot_name": "the station's robot (an empty name takes the first robot-type "
                              "item: a turntable, or the other arm)",
                "tool_name": "the probe tip's tool (targets go to the active tool's centre "
                             "point: with the flange active every touch lands a tool length "
                             "lower than the workspace check assumes)"}[info.field_name]
        if not v.strip():
            raise ValueError(f"{info.field_name} is empty: name {what}")
        return v

    @field_validator("host")
    @classmethod
    def _check_host(cls, v):
        return check_host(v)
