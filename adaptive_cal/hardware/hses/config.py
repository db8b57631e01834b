"""The ``robot.hses`` block: a Yaskawa controller over the High Speed Ethernet Server."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal.hardware.config import Strict, check_host


def _angles_deg(v, key: str):
    """Rx Ry Rz each in [-180, 180] (NaN fails too; sent as i32 in 0.0001 deg)."""
    if not all(abs(c) <= 180 for c in v):
        raise ValueError(f"{key} {list(v)}: each angle must lie in [-180, 180]")
    return v


def _within_10_m(v, key: str, said: str):
    """A position (mm) at most 10 m out on each axis (NaN fails too; sent as i32 um)."""
    if not all(abs(c) <= 10000 for c in v):
        raise ValueError(f"{key} {list(v)} {said}")
    return v


class UserFrameInBase(Strict):
    """The user frame as the pendant shows it: origin in the base frame and Rx Ry Rz, composed
    R = Rz Ry Rx (verify on the controller: docs/adapters/hses.md)."""

    origin_mm: tuple[float, float, float] = Field(description="the user frame's origin in the "
                                                  "base frame, as the pendant shows it")
    rotation_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="its Rx Ry Rz, composed R = Rz Ry Rx")

    @field_validator("origin_mm")
    @classmethod
    def _origin(cls, v):
        return _within_10_m(v, "origin_mm", "is more than 10 m from the robot base")

    @field_validator("rotation_deg")
    @classmethod
    def _rotation(cls, v):
        return _angles_deg(v, "rotation_deg")


class HsesConfig(Strict):
    """Yaskawa High Speed Ethernet Server (UDP). Host and port are required (10040 on a real
    controller; the emulator uses the one given here)."""

    host: str = Field(description="the controller's IP address")
    port: int = Field(ge=1, le=65535, description="HSES UDP port: 10040 on a controller")
    timeout_s: float = Field(0.5, gt=0, description="wait for one answer")
    retries: int = Field(3, ge=0, description="re-sends after an unanswered request")
    frame: Literal["user", "base"] = Field(
        "user", description="coordinate system of the moves: 'user' (user_frame, taught on the "
        "plate) or 'base' (the robot base)")
    user_frame: int = Field(1, ge=1, le=63, description="user frame taught on the plate")
    tool: int = Field(0, ge=0, le=63, description="tool number sent with every move; the "
                      "position answer must be of it")
    speed_mm_per_s: float = Field(50.0, gt=0, le=1000, description="the linear speed sent with "
                                  "every move (V, in 0.1 mm/s); robot.speed_mm_per_s only "
                                  "estimates robot time")
    orientation_deg: tuple[float, float, float] = Field(
        (180.0, 0.0, 0.0), description="Rx Ry Rz of the tool held during every move")
    form: int | Literal["current"] = Field(
        "current", description="the type word sent with every move (the arm's configuration "
        "bits: front / back, upper / lower arm, flip); 'current': the form the controller "
        "reports for the robot's pose at connect (0x75 word 1), so no move asks for another "
        "configuration; a number 0-255 sends that")

    @field_validator("form")
    @classmethod
    def _form(cls, v):
        if v != "current" and not 0 <= v <= 255:
            raise ValueError(f"form {v}: 'current' or a type word 0-255")
        return v
    offset_mm: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="workplane origin in the frame of the moves (the user "
        "frame user_frame with frame user, the default; the base frame with frame base), "
        "added to every target")
    user_frame_in_base: UserFrameInBase | None = Field(
        None, description="the user frame's origin_mm and rotation_deg in the base frame, as the "
        "pendant shows them; needed by check_position with frame user, because the position "
        "read (0x75) answers in the base frame only; also where the robot stands before the "
        "first move is read through it (without it: parked_at_safe_height)")
    check_position: bool = Field(True, description="compare the position the controller reports "
                                 "(base frame) with the target converted to the base frame; "
                                 "false: a move is done once the running bit came and went, or "
                                 "the straight-line travel time at speed_mm_per_s (+0.5 s) passed")
    parked_at_safe_height: bool = Field(
        False, description="with frame user, no user_frame_in_base and check_position false the "
        "PC cannot turn the position the controller reports (base frame) into the workplane's, "
        "so the first move of a run goes straight to the safe height from wherever the robot "
        "stands: true states that every run starts with the robot parked at or above "
        "robot.safe_height_mm, clear of the plate and fixtures; false (the default) refuses that "
        "cell file at load")
    position_tolerance_mm: float = Field(0.1, gt=0, description="with check_position: how far "
                                         "the reported position may lie from the target")
    move_timeout_s: float = Field(60.0, gt=0, description="the longest a move (or a busy "
                                  "controller) may take before the run stops")
    servo_timeout_s: float = Field(5.0, gt=0, le=600, description="after switching servo power "
                                   "on (at connect, after an alarm reset), wait this long for "
                                   "status data 2 to show it before the run stops")
    poll_s: float = Field(0.02, gt=0, description="status polling period during a move")
    reset_alarms: bool = Field(False, description="once per move, reset a controller alarm "
                               "(0x82 instance 1) or cancel an error (instance 2) and retry; "
                               "never one during a move down (a collision?), a hold or servo "
                               "power off: those stop the run")

    @field_validator("host")
    @classmethod
    def _check_host(cls, v):
        return check_host(v)

    @field_validator("orientation_deg")
    @classmethod
    def _orientation(cls, v):  # a wild angle failed as a bare struct.error at the first move
        return _angles_deg(v, "orientation_deg")

    @field_validator("offset_mm")
    @classmethod
    def _offset(cls, v):  # added to every target
        return _within_10_m(v, "offset_mm",
                            "puts the workplane more than 10 m from the robot frame's origin")

    @model_validator(mode="after")
    def _frame_for_the_check(self):
        if self.frame == "user" and self.check_position and self.user_frame_in_base is None:
            raise ValueError("check_position with frame 'user' needs user_frame_in_base "
                             "(origin_mm, rotation_deg of user frame "
                             f"{self.user_frame} from the pendant): the controller reports "
                             "positions in the base frame only; or set check_position: false")
        if not self.can_locate and not self.parked_at_safe_height:
            raise ValueError("the robot's position cannot be turned into the workplane's (frame "
                             "user without user_frame_in_base), so the first move of a run would "
                             "go straight to the safe height from wherever the robot stands, "
                             "perhaps with the probe down; give user_frame_in_base (origin_mm, "
                             f"rotation_deg of user frame {self.user_frame} from the pendant), "
                             "or park the robot at or above robot.safe_height_mm before every "
                             "run and state parked_at_safe_height: true")
        return self

    @property
    def can_locate(self) -> bool:
        """Whether the position the controller reports (base frame) can be turned into the
        frame of the moves: frame base, or the user frame's place in the base frame given."""
        return self.frame == "base" or self.user_frame_in_base is not None
