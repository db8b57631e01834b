"""The ``simulation:`` block of the cell file: the simulated truth (effects, noise, gross errors,
a height map, a user-frame correction applied to the simulated robot)."""
from __future__ import annotations

from pydantic import Field, field_validator, model_validator

from adaptive_cal import effects as effect_library
from adaptive_cal.cell.block import Block


class FrameCorrection(Block):
    """A user-frame correction applied to the simulated robot (deg): frame * rotx(rx) * roty(ry)."""

    rx_deg: float = Field(0.0, ge=-10, le=10, description="rotation about the user frame's x axis")
    ry_deg: float = Field(0.0, ge=-10, le=10, description="then about its y axis (RoboDK order)")


class Simulation(Block):
    """The simulated cell's truth: effects from the effect table and the noise it adds."""

    seed: int = Field(0, ge=0, description="seed of the simulated noise; 0 or above")
    effects: dict[str, dict[str, float]] = Field(
        {}, description="effect name -> parameters (DESIGN.md effect table)")
    unknown: list[str] = Field(["tilt"], description="effects explain calibrates from a recording")
    noise_std_mm: float = Field(0.002, ge=0, description="probe noise (standard deviation)")
    noise_dof: float | None = Field(
        None, gt=2, description="Student-t reading noise with this many degrees of freedom (heavy "
        "tails: dust, a chip, a sticking stylus), its standard deviation noise_std_mm; more than 2 "
        "(at 2 or fewer the variance is infinite); none: Gaussian")
    repeatability_mm: float = Field(0.005, ge=0, description="robot z repeatability (1 sigma)")
    xy_repeatability_mm: float = Field(0.01, ge=0, description="robot x/y repeatability (1 sigma)")
    frame_correction_deg: FrameCorrection | None = Field(
        None, description="the tilt correction applied to the robot's user frame (e.g. the one a "
        "run proposed, result.json tilt): the robot then moves and probes in the rotated frame, "
        "about the frame's origin; see run --correction-applied")
    surface_file: str | None = Field(
        None, min_length=1, description="true plate from a height map, relative to the cell file; "
        "effects add on top. The map: UTF-8 CSV, header x_mm,y_mm,height_mm, one row per node of "
        "a regular grid covering the workplane, any row order (a writer's round-off, quoted "
        "fields, a BOM, CRLF taken); heights in mm, bilinear between nodes (DESIGN.md 'Height "
        "maps'). Refused at load, naming the file, line and value: a map that is not that, or "
        "whose plane at the plate centre (the tilt effect's c added) stands beyond half "
        "probe.usable_mm from 0, or whose form exceeds 20 times that (heights in um?)")
    outlier_rate: float = Field(0.0, ge=0, lt=0.5, description="share of readings replaced by a "
                                "gross error, 0 to below 0.5")
    outlier_mm: float = Field(0.1, ge=0, description="standard deviation of that gross error; "
                              "above 0 where outlier_rate is")

    @field_validator("effects")
    @classmethod
    def _effects(cls, v):
        for name, params in v.items():
            try:
                effect_library.complete_params(name, params or {})
            except KeyError as e:
                raise ValueError(e.args[0]) from None
        return v

    @field_validator("unknown")
    @classmethod
    def _unknown(cls, v):
        names = effect_library.EFFECT_NAMES
        bad = [n for n in v if n.split(".")[0] not in names]
        if bad:
            raise ValueError(f"unknown effect(s) {bad}; known: {', '.join(names)}")
        return v

    @model_validator(mode="after")
    def _outliers(self):
        if self.outlier_rate > 0 and self.outlier_mm <= 0:
            raise ValueError(f"outlier_mm: {self.outlier_mm:g} with outlier_rate "
                             f"{self.outlier_rate:g}: a gross error of standard deviation 0 is "
                             "no error; give outlier_mm > 0 (mm), or outlier_rate 0")
        return self
