"""The ``probe.serial`` block: a digital indicator on a serial port or a pyserial URL."""
from __future__ import annotations

import math
import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal.hardware.config import Strict, check_baud, check_scale


PRESETS = ("mitutoyo", "sylvac", "keyence", "custom")


class SerialConfig(Strict):
    """A digital indicator on a serial port (a device path or a pyserial URL like
    ``socket://127.0.0.1:5020``). Preset values fill what is not given."""

    port: str = Field(description="the serial device (/dev/ttyUSB0, COM3) or a pyserial URL")
    preset: Literal["mitutoyo", "sylvac", "keyence", "custom"] = Field(
        "mitutoyo", description="the gauge's protocol: its request, answer pattern and line "
        "settings (docs/adapters/serial.md); custom: give pattern (and request, scale)")
    baudrate: int | None = Field(None, description="line speed; left out: the preset's")
    bytesize: Literal[7, 8] | None = Field(None, description="data bits; left out: the preset's")
    parity: Literal["N", "E", "O"] | None = Field(None, description="parity; left out: the "
                                                  "preset's")
    stopbits: Literal[1, 2] | None = Field(None, description="stop bits; left out: the "
                                           "preset's")
    request: str | None = Field(None, description="bytes sent per sample; \\r \\n escapes")
    pattern: str | None = Field(None, description="regex; group 'value' or group 1 is the number")
    scale: float = Field(1.0, description="mm per unit of the parsed number")
    timeout_s: float = Field(1.0, gt=0, description="wait for one answer")
    dtr: bool | None = Field(None, description="DTR line state (a Sylvac cable is powered from "
                             "DTR / RTS); left out: the preset's")
    rts: bool | None = Field(None, description="RTS line state; left out: the preset's")
    range_mm: tuple[float, float] | None = Field(None, description="values outside are rejected")
    decimals: int | None = Field(None, ge=0, le=9, description="the digits after the decimal "
                                 "point the gauge sends (3 for a 0.001 mm Mitutoyo); an answer "
                                 "with another count is rejected: a gauge switched to inches "
                                 "(5 decimals, a value 25.4 x too small) or a line with digits "
                                 "lost; left out: not checked")

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):  # 0 read every sample as 0.0 mm: each touch rejected as a stroke end
        return check_scale(v, "mm per unit of the parsed number")

    @field_validator("range_mm")
    @classmethod
    def _range(cls, v):
        if v is not None and not (math.isfinite(v[0]) and math.isfinite(v[1]) and v[0] < v[1]):
            raise ValueError(f"range_mm {list(v)} must be [low, high], finite, low below high")
        return v

    @field_validator("baudrate")
    @classmethod
    def _check_baud(cls, v):
        return check_baud(v)

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
