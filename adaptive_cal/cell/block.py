"""The base of every block of the cell file: strict (unknown keys refused), every number finite."""
from __future__ import annotations

from pydantic import ConfigDict

from adaptive_cal.hardware.config import Strict


class Block(Strict):
    """A block of the cell file: strict, and every number finite (NaN and inf are refused)."""
    model_config = ConfigDict(allow_inf_nan=False)
