"""The ``robot.manual`` block: the operator moves the robot and types the reading."""
from __future__ import annotations

from pydantic import Field

from adaptive_cal.hardware.config import Strict


class ManualConfig(Strict):
    """The operator moves the robot and types the reading."""

    prompt: str = Field("", description="extra text shown with each point")
    attempts: int = Field(3, ge=1, description="non-numeric answers tolerated per reading")
