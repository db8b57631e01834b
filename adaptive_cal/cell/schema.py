"""The cell file (cell.yaml): schema, validation with messages that name the key, loading.

Everything is in mm, seconds and degrees, in the workplane frame. Unknown keys are refused.
See docs/config.md for the reference; ``configs/sim-cell.yaml`` is the built-in simulated cell.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal import effects as effect_library
from adaptive_cal.cell.files import ConfigError, load_yaml, validate  # noqa: F401 (re-exported)
from adaptive_cal.gaussian.belief import Z95
from adaptive_cal.hardware.config import Strict
from adaptive_cal.hardware.hses.config import HsesConfig
from adaptive_cal.hardware.manual.config import ManualConfig
from adaptive_cal.hardware.modbus.config import ModbusConfig
from adaptive_cal.hardware.robodk.config import RobodkConfig
from adaptive_cal.hardware.serial.config import SerialConfig

Interval = tuple[float, float]


def _interval(v: Interval, what: str) -> Interval:
    lo, hi = v
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        raise ValueError(f"{what} must be [low, high] with low < high, got [{lo}, {hi}]")
    return v


class Rect(Strict):
    """An axis-aligned rectangle in the workplane (mm)."""

    x_mm: Interval
    y_mm: Interval

    @field_validator("x_mm", "y_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    def contains(self, x: float, y: float) -> bool:
        return self.x_mm[0] <= x <= self.x_mm[1] and self.y_mm[0] <= y <= self.y_mm[1]


class Workplane(Strict):
    """The plate to map: its extent, an edge margin no touch goes inside, and keep-outs."""

    x_mm: Interval
    y_mm: Interval
    edge_margin_mm: float = Field(5.0, ge=0, description="no touch closer than this to the plate edge")
    keep_outs: list[Rect] = Field([], description="rectangles never touched (clamps, holes)")

    @field_validator("x_mm", "y_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    @model_validator(mode="after")
    def _usable(self):
        m = self.edge_margin_mm
        if 2 * m >= self.x_mm[1] - self.x_mm[0] or 2 * m >= self.y_mm[1] - self.y_mm[0]:
            raise ValueError(f"edge_margin_mm={m} leaves no plate to touch inside "
                             f"x_mm={list(self.x_mm)}, y_mm={list(self.y_mm)}")
        inner = Rect(x_mm=(self.x_mm[0] + m, self.x_mm[1] - m),
                     y_mm=(self.y_mm[0] + m, self.y_mm[1] - m))
        for i, k in enumerate(self.keep_outs):
            if (k.x_mm[0] <= inner.x_mm[0] and k.x_mm[1] >= inner.x_mm[1]
                    and k.y_mm[0] <= inner.y_mm[0] and k.y_mm[1] >= inner.y_mm[1]):
                raise ValueError(f"keep_outs[{i}] x_mm={list(k.x_mm)} y_mm={list(k.y_mm)} covers "
                                 "the whole plate: nothing is left to touch")
        return self

    @property
    def area_mm2(self) -> float:
        return (self.x_mm[1] - self.x_mm[0]) * (self.y_mm[1] - self.y_mm[0])

    def allows(self, x: float, y: float) -> bool:
        """True if (x, y) lies inside the margin and outside every keep-out."""
        m = self.edge_margin_mm
        inside = (self.x_mm[0] + m <= x <= self.x_mm[1] - m
                  and self.y_mm[0] + m <= y <= self.y_mm[1] - m)
        return inside and not any(k.contains(x, y) for k in self.keep_outs)


class Workspace(Strict):
    """The box the probe tip may be sent to (workplane frame, mm). Nothing outside is sent."""

    x_mm: Interval
    y_mm: Interval
    z_mm: Interval

    @field_validator("x_mm", "y_mm", "z_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    def contains(self, x: float, y: float, z: float) -> bool:
        return (self.x_mm[0] <= x <= self.x_mm[1] and self.y_mm[0] <= y <= self.y_mm[1]
                and self.z_mm[0] <= z <= self.z_mm[1])


class Robot(Strict):
    """Motion: which adapter moves the probe, where the robot stands, how fast it travels."""

    adapter: Literal["sim", "manual", "hses", "modbus", "robodk"] = Field(
        "sim", description="what moves the probe: see docs/adapters/")
    base_xy_mm: tuple[float, float] | None = Field(
        None, description="robot base in the workplane frame (arm_sag, reach)")
    speed_mm_per_s: float = Field(100.0, gt=0, description="travel speed (robot time estimates)")
    safe_height_mm: float = Field(15.0, description="travel height (workplane z) between touches")
    touch_time_s: float = Field(3.0, ge=0, description="approach, settle, read and retract")
    manual: ManualConfig | None = None
    hses: HsesConfig | None = None
    modbus: ModbusConfig | None = None
    robodk: RobodkConfig | None = None

    @model_validator(mode="after")
    def _block(self):
        if self.adapter in ("hses", "modbus", "robodk") and getattr(self, self.adapter) is None:
            raise ValueError(f"adapter '{self.adapter}' needs a robot.{self.adapter} block "
                             "(host, port, ...)")
        return self


class Probe(Strict):
    """The contact probe: stroke, the usable part of it, its zero, noise and the probe cycle."""

    adapter: Literal["sim", "manual", "serial", "modbus"] = Field(
        "sim", description="what reads the probe: see docs/adapters/")
    stroke_mm: float = Field(10.0, gt=0, description="full probe stroke")
    usable_mm: Interval = Field((0.5, 9.5), description="indications accepted; others are rejected")
    zero_mm: float = Field(5.0, description="indication with the tip at the commanded height")
    resolution_mm: float = Field(1e-4, gt=0, description="readout step")
    noise_std_mm: float = Field(0.005, gt=0, description="first guess of the reading noise "
                                "(a weak prior: the noise is learned from the readings)")
    noise_range_mm: Interval | None = Field(
        None, description="[low, high] the reading noise is known to lie in (datasheet, a gauge "
        "study): a log-normal prior with 95 % inside, centred at sqrt(low * high); it replaces "
        "noise_std_mm and keeps the learned noise from collapsing on few readings")
    samples: int = Field(1, ge=1, description="samples per touch (median taken)")
    samples_tolerance_mm: float = Field(0.005, gt=0, description="largest spread of the samples")
    retries: int = Field(2, ge=0, description="re-samplings when the spread is too large")
    settle_s: float = Field(0.2, ge=0, description="wait after the approach before reading")
    serial: SerialConfig | None = None
    modbus: ModbusConfig | None = None

    @model_validator(mode="after")
    def _stroke(self):
        lo, hi = _interval(self.usable_mm, "usable_mm")
        if lo < 0 or hi > self.stroke_mm:
            raise ValueError(f"usable_mm={[lo, hi]} must lie inside the stroke [0, {self.stroke_mm}]")
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
        if self.noise_range_mm is None:
            return self.noise_std_mm, None
        lo, hi = self.noise_range_mm
        return math.sqrt(lo * hi), math.log(hi / lo) / (2 * Z95)


class Model(Strict):
    """The stochastic spline and its prior."""

    knots_x: int | list[float] | None = Field(None, description="count or positions (mm); "
                                               "default from Brunn eq. 15")
    knots_y: int | list[float] | None = Field(None, description="as knots_x, along y")
    ends: Literal["not_a_knot", "natural"] = Field(
        "not_a_knot", description="spline end conditions; not_a_knot reproduces a bow at the edge")
    tilt_std_deg: float = Field(1.0, gt=0, le=30, description="prior std of the tilt about x and y")
    offset_std_mm: float = Field(0.5, gt=0, description="prior std of the height at the plate centre")
    form_std_mm: float = Field(0.05, gt=0, description="prior form amplitude (learned)")
    length_scale_mm: float | None = Field(
        None, gt=0, description="prior form length scale (learned); default half the shorter side")
    form_tolerance_mm: float = Field(0.1, gt=0, description="S_u - S_l of Brunn eq. 15")
    max_curvature_per_mm: float = Field(5e-5, gt=0, description="k_max of Brunn eq. 15")
    learn_hyper: bool = Field(True, description="refit form amplitude, length scale and noise")
    gate_sigma: float = Field(4.0, gt=0, description="Mahalanobis gate; a failing reading is retaken")

    @field_validator("knots_x", "knots_y")
    @classmethod
    def _knots(cls, v, info):
        if isinstance(v, int) and v < 2:
            raise ValueError(f"{info.field_name} needs at least 2 knots, got {v}")
        if isinstance(v, list) and (len(v) < 2 or any(b <= a for a, b in zip(v, v[1:]))):
            raise ValueError(f"{info.field_name} must be at least 2 increasing positions, got {v}")
        return v


class Stop(Strict):
    """When to stop: any bound met, or the touch budget spent."""

    mean_std_mm: float | None = Field(0.01, gt=0, description="RMS posterior std over the plate")
    max_std_mm: float | None = Field(None, gt=0, description="largest posterior std on the plate")
    max_touches: int = Field(200, ge=1, description="touch budget")
    min_touches: int | None = Field(
        None, ge=0, description="no variance bound stops the run before this many touches; "
        "default: the number of spline coefficients while hyper-parameters are learned from "
        "scratch; 0 with probe.noise_range_mm, a prior from an earlier run (--prior-from) or "
        "learn_hyper: false")


class Plan(Strict):
    """The planner: candidates, refinement, batches, hyper-parameter learning."""

    stop: Stop = Field(Stop(), description="stopping rules (any one stops)")
    candidates: int = Field(10000, ge=16, description="grid points scored per decision")
    refine: int = Field(3, ge=0, description="best candidates refined by gradient steps")
    batch: int = Field(1, ge=1, description="touches planned ahead and ordered for travel")
    criterion: Literal["auto", "integrated", "max"] = Field(
        "auto", description="auto: the worst-point criterion when only max_std_mm bounds the "
        "run, else the integrated variance")
    hyper_every: int = Field(4, ge=1, description="refit hyper-parameters every N readings")
    hyper_after: int = Field(8, ge=3, description="first refit after N readings")
    drift_std_mm: float = Field(0.01, ge=0, description="widening for --prior-from")


class Simulation(Strict):
    """The simulated cell's truth: effects from the effect table and the noise it adds."""

    seed: int = Field(0, description="seed of the simulated noise")
    effects: dict[str, dict[str, float]] = Field(
        {}, description="effect name -> parameters (DESIGN.md effect table)")
    unknown: list[str] = Field(["tilt"], description="effects explain calibrates from a recording")
    noise_std_mm: float = Field(0.002, ge=0, description="probe noise")
    repeatability_mm: float = Field(0.005, ge=0, description="robot z repeatability (1 sigma)")
    xy_repeatability_mm: float = Field(0.01, ge=0, description="robot x/y repeatability (1 sigma)")

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


class Cell(Strict):
    """A whole cell file."""

    name: str = Field("cell", description="shown in reports and figures")
    workplane: Workplane
    workspace: Workspace | None = Field(
        None, description="box the probe tip may be sent to; none: the workplane only")
    robot: Robot = Robot()
    probe: Probe = Probe()
    model: Model = Model()
    plan: Plan = Plan()
    simulation: Simulation | None = Field(
        None, description="the simulated truth (robot.adapter sim, emulate, explain)")

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
        r, p = self.robot, self.probe
        if (r.adapter == "sim") != (p.adapter == "sim"):
            raise ValueError(f"robot.adapter={r.adapter!r} with probe.adapter={p.adapter!r}: the "
                             "simulated robot and probe only exist together; set both to 'sim'")
        if r.adapter == "modbus" and p.adapter == "modbus":
            a, b = r.modbus, p.modbus
            same = all(getattr(a, k, None) == getattr(b, k, None)
                       for k in ("transport", "host", "port", "serial_port", "device_id"))
            if same and a != b:
                raise ValueError("robot.modbus and probe.modbus name the same PLC with different "
                                 "settings; make the two blocks identical")
        return self

    @property
    def geometry(self) -> effect_library.Geometry:
        return effect_library.Geometry(self.workplane.x_mm, self.workplane.y_mm, self.robot.base_xy_mm)


def parse_cell(data: dict, source: str = "cell") -> Cell:
    """Validate a cell given as a dict; raise ConfigError naming each bad key and value."""
    return validate(Cell, data, source)


def load_cell(path: str | Path) -> Cell:
    """Read and validate a cell file."""
    return parse_cell(load_yaml(path), str(path))
