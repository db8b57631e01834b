"""The cell file (cell.yaml): schema, validation with messages that name the key, loading.

Everything is in mm, seconds and degrees, in the workplane frame. Unknown keys are refused.
See docs/config.md for the reference; ``configs/sim-cell.yaml`` is the built-in simulated cell.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal import effects as effect_library
from adaptive_cal.cell.block import Block
from adaptive_cal.cell.consistency import check_cell, um_as_mm
from adaptive_cal.cell.plate import (REACH_MM, Interval, Rect, Workplane,  # noqa: F401
                                     _interval)  # (re-exported)
from adaptive_cal.cell.files import ConfigError, load_yaml, validate  # noqa: F401 (re-exported)
from adaptive_cal.cell.simulation import FrameCorrection, Simulation  # noqa: F401 (re-exported)
from adaptive_cal.cell.stop import Stop
from adaptive_cal.formats.mapfiles import beside
from adaptive_cal.hardware.hses.config import HsesConfig
from adaptive_cal.hardware.manual.config import ManualConfig
from adaptive_cal.hardware.modbus.config import ModbusConfig
from adaptive_cal.hardware.robodk.config import RobodkConfig
from adaptive_cal.hardware.serial.config import SerialConfig

MAX_KNOTS = 64  # control points per axis (K = knots_x * knots_y coefficients, C is K x K)


class Workspace(Block):
    """The box the probe tip may be sent to (workplane frame, mm). Nothing outside is sent."""

    x_mm: Interval = Field(description="[low, high] the tip may be sent to in x")
    y_mm: Interval = Field(description="[low, high] in y")
    z_mm: Interval = Field(description="[low, high] in z (the safe height and every approach "
                           "inside)")

    @field_validator("x_mm", "y_mm", "z_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    def contains(self, x: float, y: float, z: float) -> bool:
        return (self.x_mm[0] <= x <= self.x_mm[1] and self.y_mm[0] <= y <= self.y_mm[1]
                and self.z_mm[0] <= z <= self.z_mm[1])


class Robot(Block):
    """Motion: which adapter moves the probe, where the robot stands, how fast it travels."""

    adapter: Literal["sim", "manual", "hses", "modbus", "robodk"] = Field(
        "sim", description="what moves the probe: see docs/adapters/")
    base_xy_mm: tuple[float, float] | None = Field(
        None, description="robot base in the workplane frame (arm_sag, reach)")
    speed_mm_per_s: float = Field(100.0, gt=0, le=10000, description="travel speed (robot time estimates)")
    safe_height_mm: float = Field(15.0, gt=0, le=1000, description="travel height (workplane "
                                  "z) between touches, above probe.zero_mm (the tip's free reach); "
                                  "higher (0.5 mm clear) where the plate may stand within that "
                                  "reach (1 in 10^6), or a stop if workspace.z_mm cannot hold it")
    touch_time_s: float = Field(3.0, le=3600, description="approach, settle, read and retract; "
                                "above 0 (the planner weighs travel against it)")
    manual: ManualConfig | None = None
    hses: HsesConfig | None = None
    modbus: ModbusConfig | None = None
    robodk: RobodkConfig | None = None

    @field_validator("touch_time_s")
    @classmethod
    def _touch_takes_time(cls, v):
        if not v > 0:
            # the time-aware planner prices a touch at touch_time_s + travel / speed: at 0 a
            # repeat touch where the probe stands costs nothing (an infinite rate) and the
            # whole budget goes to one point
            raise ValueError(f"must be above 0 s, got {v}: a touch takes time (approach, settle, "
                             "read, retract) and the planner weighs travel against it; at 0 a "
                             "touch where the probe already stands would cost nothing")
        return v

    @model_validator(mode="after")
    def _block(self):
        if self.adapter in ("hses", "modbus", "robodk") and getattr(self, self.adapter) is None:
            raise ValueError(f"adapter '{self.adapter}' needs a robot.{self.adapter} block "
                             "(host, port, ...)")
        m = self.modbus if self.adapter == "modbus" else None
        if m is not None and m.registers.actual_x is None and not m.parked_at_safe_height:
            # said at load, before a run folder is made or anything moves (the adapter refuses
            # that first move too: hardware.modbus.motion)
            raise ValueError("robot.modbus: the robot's position cannot be read (no registers."
                             "actual_x/y/z), so the first move would go straight to the safe "
                             "height from wherever it stands; map them (hw/plc-register-map.md) "
                             "or state robot.modbus.parked_at_safe_height: true")
        return self


class Probe(Block):
    """The contact probe: stroke, the usable part of it, its zero, noise and the probe cycle."""

    adapter: Literal["sim", "manual", "serial", "modbus"] = Field(
        "sim", description="what reads the probe: see docs/adapters/")
    stroke_mm: float = Field(10.0, gt=0, le=1000, description="full probe stroke")
    rest_mm: float = Field(0.0, ge=-1000, le=0, description="indication with the tip free (the "
                           "start of the stroke): 0 for a gauge that counts from its rest, -p for "
                           "one zeroed p mm into its stroke (signed relative indications); the "
                           "stroke's indications are [rest_mm, rest_mm + stroke_mm]")
    usable_mm: Interval = Field((0.5, 9.5), description="indications accepted; others are "
                                "rejected; inside the stroke's indications")
    zero_mm: float = Field(5.0, description="indication with the tip at the commanded "
                           "height; inside the stroke's indications")
    resolution_mm: float = Field(1e-4, gt=0, description="readout step; below the stroke")
    noise_std_mm: float = Field(0.005, gt=0, description="first guess of the reading noise "
                                "(a weak prior: the noise is learned from the readings; learned "
                                "1.5 x this or more, a bound waits for 12 repeat readings that "
                                "measure the probe's own)")
    noise_range_mm: Interval | None = Field(
        None, description="[low, high] the reading noise is known to lie in (datasheet, a gauge "
        "study): the prior is flat from the span's middle sqrt(low * high) up to high, with "
        "log-normal shoulders (95 % of the old log-normal inside the span); it replaces "
        "noise_std_mm and keeps the learned noise from collapsing on few readings")
    samples: int = Field(1, ge=1, le=1000, description="samples per touch (median taken)")
    samples_tolerance_mm: float = Field(0.005, gt=0, description="largest spread of the samples")
    retries: int = Field(2, ge=0, le=100, description="re-samplings when the spread is too large")
    settle_s: float = Field(0.2, ge=0, le=600, description="wait after the approach before reading")
    serial: SerialConfig | None = None
    modbus: ModbusConfig | None = None

    @field_validator("usable_mm", "zero_mm")
    @classmethod
    def _inside_stroke(cls, v, info):
        """usable_mm and zero_mm are indications: inside [rest_mm, rest_mm + stroke_mm]."""
        if "rest_mm" not in info.data or "stroke_mm" not in info.data:
            return v  # refused already, naming its own key
        start = info.data["rest_mm"]
        end = start + info.data["stroke_mm"]
        lo, hi = _interval(v, info.field_name) if info.field_name == "usable_mm" else (v, v)
        if lo < start or hi > end:
            raise ValueError(f"{info.field_name}={[lo, hi] if hi > lo else v} must lie inside the "
                             f"stroke [{start:g}, {end:g}] mm (rest_mm {start:g} + stroke_mm "
                             f"{end - start:g})")
        return v

    @model_validator(mode="after")
    def _stroke(self):
        lo, hi = _interval(self.usable_mm, "usable_mm")
        for key in ("resolution_mm", "noise_std_mm", "samples_tolerance_mm"):
            if getattr(self, key) >= self.stroke_mm:
                raise ValueError(f"{key}={getattr(self, key)} must be below the stroke {self.stroke_mm} mm")
        span = hi - lo  # 0.1 mm of noise or more, a tenth of the usable stroke: um for mm?
        noise = [("noise_std_mm", self.noise_std_mm)] + (
            [("noise_range_mm", self.noise_range_mm[1])] if self.noise_range_mm else [])
        for key, value in noise:
            if um_as_mm(value, span):
                raise ValueError(f"{key}: {value} mm is {value / span:.0%} of the usable stroke "
                                 f"{span:g} mm (usable_mm): a probe that noisy cannot keep a "
                                 f"touch inside it -- um given as mm? ({value:g} um is {value / 1000:g})")
        if self.noise_range_mm is not None:
            n_lo, n_hi = _interval(self.noise_range_mm, "noise_range_mm")
            if n_lo <= 0:
                raise ValueError(f"noise_range_mm={[n_lo, n_hi]} must be above 0 mm")
            if "noise_std_mm" in self.model_fields_set and not n_lo <= self.noise_std_mm <= n_hi:
                raise ValueError(f"noise_std_mm={self.noise_std_mm} lies outside "
                                 f"noise_range_mm={[n_lo, n_hi]}: give one or make them agree")
        if self.adapter in ("serial", "modbus") and getattr(self, self.adapter) is None:
            raise ValueError(f"adapter '{self.adapter}' needs a probe.{self.adapter} block")
        return self

    def noise_prior(self) -> tuple[float, float | None]:
        """(centre mm, log-std) of the prior on the reading noise; log-std None: the weak default."""
        from adaptive_cal.gaussian.belief import Z95  # here: belief loads filterpy and scipy.stats

        if self.noise_range_mm is None:
            return self.noise_std_mm, None
        lo, hi = self.noise_range_mm
        return math.sqrt(lo * hi), math.log(hi / lo) / (2 * Z95)


Within10m = Annotated[float, Field(ge=-10_000, le=10_000)]  # mm


class Model(Block):
    """The stochastic spline and its prior."""

    knots_x: int | list[float] | None = Field(None, description="count or positions (mm; the "
                                               "first and last on the workplane's edges); "
                                               "default from Brunn eq. 15")
    knots_y: int | list[float] | None = Field(None, description="as knots_x, along y")
    ends: Literal["not_a_knot", "natural"] = Field(
        "not_a_knot", description="spline end conditions; not_a_knot reproduces a bow at the edge")
    tilt_std_deg: float = Field(1.0, gt=0, le=30, description="prior std of the tilt about x and y")
    offset_std_mm: float = Field(0.5, gt=0, description="prior std of the height at pivot_mm")
    pivot_mm: tuple[Within10m, Within10m] | None = Field(
        None, description="where the plate's height is known to offset_std_mm, the tilt turning "
        "about it: where the frame's z was set (a frame taught on the plate: its origin). "
        "Default: the workplane's centre (an origin on the plate far from it is warned about)")
    form_std_mm: float = Field(0.05, gt=0, description="prior form amplitude (learned)")
    length_scale_mm: float | None = Field(
        None, gt=0, description="prior form length scale (learned); default half the shorter side")
    form_tolerance_mm: float = Field(0.1, gt=0, description="S_u - S_l of Brunn eq. 15")
    max_curvature_per_mm: float = Field(5e-5, gt=0, description="k_max of Brunn eq. 15")
    learn_hyper: bool = Field(True, description="refit form amplitude, length scale and noise")
    form_kernels: list[Literal["se", "m52"]] = Field(
        ["se", "m52"], min_length=1, description="the form's correlations a refit weighs by "
        "their evidence: se squared exponential (smooth), m52 Matern-5/2 (rougher); the first "
        "is the prior's before any refit")
    gate_sigma: float = Field(4.0, gt=0, description="Mahalanobis gate; a failing reading is retaken")
    grow: bool = Field(True, description="plan on knots refined once (every interval halved, up "
                       "to 160 coefficients) whose finer structure the prior takes where the "
                       "self-checks find the plate rougher than the knots (the same posterior "
                       "until then); false: the knots as given")

    @field_validator("knots_x", "knots_y")
    @classmethod
    def _knots(cls, v, info):
        if isinstance(v, int) and not 2 <= v <= MAX_KNOTS:
            raise ValueError(f"{info.field_name} needs 2 to {MAX_KNOTS} knots, got {v}")
        if isinstance(v, list) and (not 2 <= len(v) <= MAX_KNOTS
                                    or any(b <= a for a, b in zip(v, v[1:]))):
            raise ValueError(f"{info.field_name} must be 2 to {MAX_KNOTS} increasing positions "
                             f"(mm), got {len(v)}")
        return v


class Plan(Block):
    """The planner: candidates, refinement, batches, hyper-parameter learning."""

    stop: Stop = Field(Stop(), description="stopping rules: every bound set met, or the budget")
    candidates: int = Field(10000, ge=16, le=1_000_000, description="grid points scored per decision")
    refine: int = Field(3, ge=0, description="best candidates refined by gradient steps")
    batch: int = Field(1, ge=1, le=1000, description="touches planned ahead and ordered for travel")
    criterion: Literal["auto", "integrated", "max"] = Field(
        "auto", description="auto: the worst-point criterion when only max_std_mm bounds the "
        "run, else the integrated variance")
    hyper_every: int = Field(4, ge=1, description="refit hyper-parameters every N readings")
    hyper_after: int = Field(8, ge=3, description="first refit after N readings")
    drift_std_mm: float = Field(0.01, ge=0, description="widening for --prior-from")
    min_spacing_mm: float | None = Field(
        None, ge=0, description="once the self-checks found structure finer than the knots, no "
        "touch is planned closer than this to an earlier one while points further away are "
        "allowed; default half the planning knot spacing (0: off)")
    closure: bool = Field(
        True, description="when a variance bound stops the run, touch the first place again: a "
        "difference beyond the probe's noise (1 % level) means the cell drifted during the run; "
        "the run then stops with `drift`, says so and widens the bands (one touch more, two when "
        "a one-reading alarm is confirmed; with two touches of the budget left where no bound "
        "stopped the run, the last for its retake or confirmation; none in a re-check from "
        "--prior-from)")


class Cell(Block):
    """A whole cell file."""

    name: str = Field("cell", min_length=1, max_length=200,
                      description="shown in reports and figures; one line of printable text")
    workplane: Workplane
    workspace: Workspace | None = Field(
        None, description="box the probe tip may be sent to (nothing outside is sent); required "
        "for every adapter but sim; must hold the touchable plate and the travel height")
    robot: Robot = Robot()
    probe: Probe = Probe()
    model: Model = Model()
    plan: Plan = Plan()
    simulation: Simulation | None = Field(
        None, description="the simulated truth (robot.adapter sim, emulate, explain)")

    @field_validator("name")
    @classmethod
    def _printable(cls, v):
        if not v.isprintable():
            raise ValueError("must be one line of printable text (no newline, tab or control "
                             "character: the name goes into the recording's header)")
        return v

    @model_validator(mode="before")
    @classmethod
    def _default_simulation(cls, data):
        """A simulated robot gets the default simulated truth when the file gives none."""
        if not isinstance(data, dict) or data.get("simulation") is not None:
            return data
        robot = data.get("robot")  # a mapping from the file, or a Robot given in code
        adapter = robot.get("adapter", "sim") if isinstance(robot, dict) else getattr(robot, "adapter", "sim")
        return {**data, "simulation": {}} if adapter == "sim" else data

    @model_validator(mode="after")
    def _consistent(self):
        check_cell(self)  # the simulated plate's height map too
        return self

    @property
    def geometry(self) -> effect_library.Geometry:
        return effect_library.Geometry(self.workplane.x_mm, self.workplane.y_mm, self.robot.base_xy_mm)


def parse_cell(data: dict, source: str = "cell") -> Cell:
    """Validate a cell given as a dict; raise ConfigError naming each bad key and value."""
    return validate(Cell, data, source)


def resolve_files(data: dict, path: str | Path) -> dict:
    """``data`` read from ``path`` with simulation.surface_file relative to the file's folder."""
    sim = data.get("simulation") if isinstance(data, dict) else None
    if isinstance(sim, dict) and isinstance(sim.get("surface_file"), str) and sim["surface_file"]:
        data = {**data, "simulation": {**sim, "surface_file": beside(sim["surface_file"], path)}}
    return data


def load_cell(path: str | Path) -> Cell:
    """Read and validate a cell file."""
    return parse_cell(resolve_files(load_yaml(path), path), str(path))


def as_cell(cell, name: str = "cell") -> Cell:
    """A Cell as given, read from a cell file's path or validated from a dict (``parse_cell``);
    else a TypeError naming the argument (for the API: a path where a Cell is meant)."""
    import os

    if isinstance(cell, Cell):
        return cell
    if isinstance(cell, (str, os.PathLike)):
        return load_cell(cell)
    if isinstance(cell, dict):
        return parse_cell(cell)
    raise TypeError(f"{name} = {cell!r:.60}: give a Cell (adaptive_cal.load_cell), a cell file's "
                    "path or a dict of its keys")
