"""When a run stops (the cell file's ``plan.stop``): its bounds, touch budget and floor."""
from __future__ import annotations

from pydantic import Field, model_validator

from adaptive_cal.cell.block import Block


class Stop(Block):
    """When to stop: every bound set met, or the touch budget spent. `run` warns about a bound
    of a tenth of the probe's usable stroke or more (at least 0.1 mm): um typed as mm?"""

    mean_std_mm: float | None = Field(0.01, gt=0, description="RMS posterior std over the "
                                      "plate; its default holds only where max_std_mm is unset")
    max_std_mm: float | None = Field(None, gt=0, description="largest posterior std on the plate")
    max_touches: int = Field(200, ge=1, le=100_000, description="touch budget")
    min_touches: int | None = Field(
        None, ge=0, description="no variance bound stops the run before this many touches; "
        "default: the number of spline coefficients while hyper-parameters are learned from "
        "scratch (warned about where above max_touches); 0 with probe.noise_range_mm, a prior "
        "from an earlier run (--prior-from) or learn_hyper: false")
    max_gap_mm: float | None = Field(
        None, gt=0, description="no variance bound stops the run while a disc of this radius "
        "(mm) on the reachable plate holds no touch; the planner then touches the largest gap. "
        "A dent or bump of radius R is then touched within this distance of its centre: at most "
        "R / 2 sees at least half its depth (a smooth bowl). It costs at least area / (2.6 r^2) "
        "touches; measured: 178-189 for r = 24 mm, 102 for 40 mm on a 430 x 350 mm plate")

    @model_validator(mode="before")
    @classmethod
    def _max_alone(cls, data):  # max_std_mm alone: the default mean bound would stop the run
        if isinstance(data, dict) and data.get("max_std_mm") is not None and \
                "mean_std_mm" not in data:  # first, and the max bound never be met (an audit)
            data = {**data, "mean_std_mm": None}
        return data

    @model_validator(mode="after")
    def _floor_within_budget(self):
        if self.min_touches is not None and self.min_touches > self.max_touches:
            raise ValueError(f"min_touches={self.min_touches} is above max_touches="
                             f"{self.max_touches}: no variance bound could stop the run")
        return self
