"""The study file (study.yaml): what plates to draw, which strategies to run, the bound.

Everything in mm, s, deg. Unknown keys are refused; every error names its key and value.
Physical checks that need the cell (tilt against the probe stroke, the bound against the noise
floor) run in ``check_feasible`` once the base cell is known.
"""
from __future__ import annotations

import glob
import math
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from adaptive_cal.gaussian.belief import rms_std_from_integrated_variance
from adaptive_cal.hardware.config import Strict
from adaptive_cal.cell.schema import (Cell, ConfigError, Rect, load_yaml, parse_cell, resolve_files,
                                     validate)
from adaptive_cal.formats.heightmap import HeightMapError
from adaptive_cal.formats.mapfiles import beside_glob, check_map

STRATEGIES = ("adaptive", "greedy_fixed", "paper", "grid", "random")
SHAPES = ("bow_x", "bow_y", "twist", "warp")
Span = tuple[float, float]


def _span(v: Span, name: str, *, lower: float = 0.0) -> Span:
    lo, hi = v
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo < lower or hi < lo:
        raise ValueError(f"{name} must be [low, high] with {lower} <= low <= high, got {list(v)}")
    return v


class PlateDistribution(Strict):
    """How synthetic plates are drawn (each plate: its own seed)."""

    tilt_deg: float = Field(1.0, ge=0, description="tilt about each axis uniform in +-tilt_deg")
    offset_mm: float = Field(0.2, ge=0, description="height at the centre uniform in +-offset_mm")
    form_pv_mm: Span = Field((0.02, 0.3), description="the form's peak to valley, uniform in "
                             "[lo, hi] (lo = hi: fixed)")
    form_shapes: list[Literal["bow_x", "bow_y", "twist", "warp"]] = Field(
        list(SHAPES), description="the form: these shapes with random weights, scaled to its "
        "peak to valley")
    noise_std_mm: Span = Field((0.005, 0.02), description="reading noise (1 sigma), uniform in "
                               "[lo, hi] per plate (lo = hi: fixed)")
    repeatability_mm: float = Field(0.0, ge=0, le=1.0, description="robot z repeatability (1 "
                                    "sigma)")
    noise_range_known: bool = Field(True, description="tell the planner the span of the reading "
                                    "noise (probe.noise_range_mm), as a user quotes the probe's "
                                    "datasheet; false: only the cell's first guess")
    keep_outs: list[Rect] | None = Field(None, description="replace the cell's keep-outs")
    surface_files: str | None = Field(
        None, min_length=1,
        description="glob of height maps (DESIGN.md format; relative to the study file; "
        "** matches any depth of folders): "
        "plate i is the i-th file in sorted order (cycling), its truth that map with the base "
        "cell's simulation.effects on top (tilt, offset and form above are not drawn); noise "
        "drawn as before")

    @field_validator("form_pv_mm", "noise_std_mm")
    @classmethod
    def _spans(cls, v, info):
        return _span(v, info.field_name)

    @field_validator("tilt_deg")
    @classmethod
    def _tilt(cls, v):
        if v >= 45:
            raise ValueError(f"tilt_deg={v} is not a workplane tilt (must be < 45)")
        return v


class Bound(Strict):
    """The target: posterior stop and the bound on the true error, and the touch budget."""

    mean_std_mm: float = Field(0.005, gt=0, description="stop at this RMS posterior std")
    true_rms_mm: float | None = Field(None, gt=0, description="bound on the TRUE RMS error; "
                                      "default: mean_std_mm")
    max_touches: int = Field(200, ge=1, le=100_000, description="touch budget of each run")

    @property
    def true_mm(self) -> float:
        return self.true_rms_mm if self.true_rms_mm is not None else self.mean_std_mm


class Paper(Strict):
    """The reference procedure (Cheng, Chang & Weng 2025): 5-point levelling, then rounds of the
    10 x 4 S-shaped path until the levelling check passes."""

    nx: int = Field(10, ge=2, description="points of the S path along x")
    ny: int = Field(4, ge=2, description="rows of the S path along y")
    level_tolerance_mm: float = Field(0.02, gt=0, description="stop when the tilt of the round's "
                                      "least-squares plane changes the height by at most this "
                                      "across the plate")
    max_rounds: int = Field(3, ge=1, description="rounds of the S path at most")


class LowerBound(Strict):
    """Lower bound on touches: relaxed optimal design; exhaustive integer search if small."""

    plates: int = Field(20, ge=0, description="computed on the first N plates")
    candidates: int = Field(1000, ge=16, description="candidate points of the design")
    exhaustive_limit: int = Field(200000, ge=0, description="largest number of designs "
                                  "enumerated by the exhaustive search")


class Study(Strict):
    """A whole study file."""

    name: str = Field("study", description="a label in the outputs")
    seed: int = Field(0, ge=0, description="seed of every plate's draws")
    plates: int = Field(ge=1, description="plates drawn (or maps taken), each run by every "
                        "strategy")
    cell: str | dict = Field("sim-cell.yaml", description="cell file (relative to the study "
                             "file) or an inline cell mapping")
    plate: PlateDistribution = PlateDistribution()
    bound: Bound = Bound()
    strategies: list[Literal["adaptive", "greedy_fixed", "paper", "grid", "random"]] = Field(
        list(STRATEGIES), description="what runs on each plate (docs/study.md)")
    estimator: Literal["learned", "fixed"] = Field(
        "learned", description="paper/grid/random: fit hyper-parameters like the adaptive "
        "planner (learned), or keep the cell's (fixed; vectorised over plates with jax.vmap)")
    paper: Paper = Paper()
    lower_bound: LowerBound = LowerBound()
    example_plate: int = Field(0, ge=0, description="the plate drawn in the figures")

    @field_validator("strategies")
    @classmethod
    def _strategies(cls, v):
        if not v or len(set(v)) != len(v):
            raise ValueError(f"strategies must be a non-empty list without repeats, got {v}")
        return v

    @model_validator(mode="after")
    def _example(self):
        if self.example_plate >= self.plates:
            raise ValueError(f"example_plate={self.example_plate} must be below plates={self.plates}")
        return self


def parse_study(data: dict, source: str = "study") -> Study:
    """Validate a study given as a dict; raise ConfigError naming each bad key and value."""
    return validate(Study, data, source)


def base_cell_dict(study: Study, study_path: str | Path | None) -> dict:
    """The base cell as a plain mapping (plates are variations of it)."""
    if isinstance(study.cell, dict):  # its files are relative to the study file, as a cell's
        return dict(study.cell) if study_path is None else resolve_files(dict(study.cell),
                                                                         study_path)
    path = cell_path(study.cell, study_path)
    return resolve_files(load_yaml(path), path)


def cell_path(cell: str, study_path: str | Path | None) -> Path:
    """The cell file a study names, relative to the study file."""
    path = Path(cell)
    if not path.is_absolute() and study_path is not None:
        path = Path(study_path).resolve().parent / path
    return path


def load_study(path: str | Path, edit=None) -> tuple[Study, dict]:
    """Read a study file and its base cell; raise ConfigError naming each bad key. ``edit``:
    called with the file's mapping, returns it changed (the command line's overrides)."""
    data = load_yaml(path)
    if edit is not None and isinstance(data, dict):
        data = edit(data)
    plate = data.get("plate") if isinstance(data, dict) else None
    if isinstance(plate, dict) and isinstance(plate.get("surface_files"), str) \
            and plate["surface_files"]:
        data = {**data, "plate": {**plate, "surface_files": beside_glob(plate["surface_files"], path)}}
    study = parse_study(data, str(path))
    cell_dict = base_cell_dict(study, path)
    # an error names the file it is in: the cell file's own, where the study names one
    source = (f"{path}: cell" if isinstance(study.cell, dict) else
              f"{cell_path(study.cell, path)} (the cell of {path})")
    cell = parse_cell(cell_dict, source)
    check_feasible(study, cell, str(path))
    return study, cell_dict


def surface_files(study: Study) -> list[str]:
    """The height maps of plate.surface_files, sorted (empty when the key is not given). ``**``
    matches any depth of folders, none included (``glob``'s recursive form: a study's maps in
    nested folders are all found, not only those exactly one level down)."""
    pattern = study.plate.surface_files
    return sorted(glob.glob(pattern, recursive=True)) if pattern is not None else []


def check_surface_files(study: Study, cell: Cell, source: str) -> None:
    """Every map of plate.surface_files must load and cover the cell's workplane."""
    if study.plate.surface_files is None:
        return
    files = surface_files(study)
    if not files:
        raise ConfigError(f"{source}: plate.surface_files={study.plate.surface_files!r} "
                          "matches no file (benchmarks/plates/generate.py writes the realistic "
                          "plates' maps)")
    for f in files:
        try:
            check_map(f, cell.workplane, "plate.surface_files")
        except HeightMapError as e:
            raise ConfigError(f"{source}: {e}") from None
        map_in_reach(f, cell, source)


def map_in_reach(path: str, cell: Cell, source: str) -> None:
    """A map as ``check_feasible`` holds a drawn plate: its least-squares plane (nodes on the
    workplane) no steeper than the planner serves, its height at the plate centre within the
    prior's reach, and its form within half the usable stroke -- else every touch lands at the
    stroke's end and the study measures nothing (a map 6 mm high ran its whole budget)."""
    from adaptive_cal.formats.heightmap import load_heightmap
    from adaptive_cal.formats.mapfiles import plane_of

    wp, probe = cell.workplane, cell.probe
    a, b, c, form = plane_of(load_heightmap(path), wp.x_mm, wp.y_mm)
    allowed, offset, half = reach(cell)
    if math.hypot(a, b) > allowed or abs(c) > offset or abs(c) + form > half:
        raise ConfigError(
            f"{source}: plate.surface_files: {path} is beyond the probe's reach: its plane has a "
            f"slope of {math.hypot(a, b):.4f} mm/mm (the planner serves up to {allowed:.4f}), a "
            f"height of {c:+.3f} mm at the plate centre (the prior reaches +-{offset:.3f} mm, "
            f"model.offset_std_mm) and {form:.3f} mm of form about it; the usable stroke "
            f"{list(probe.usable_mm)} mm holds +-{half:.3f} mm" + (
                " -- heights in um? a map's heights are mm" if abs(c) + form > 20 * half
                else ""))


def reach(cell: Cell) -> tuple[float, float, float]:
    """What the planner serves on ``cell`` (``check_feasible``): the steepest slope (mm/mm,
    STROKE_Z x tan(model.tilt_std_deg)), the largest offset at the plate centre (mm, STROKE_Z x
    model.offset_std_mm) and half the usable stroke (mm)."""
    from adaptive_cal.planning.scoring import STROKE_Z

    m, usable = cell.model, cell.probe.usable_mm
    return (STROKE_Z * math.tan(math.radians(m.tilt_std_deg)), STROKE_Z * m.offset_std_mm,
            0.5 * (usable[1] - usable[0]))


def check_feasible(study: Study, cell: Cell, source: str = "study") -> None:
    """Refuse distributions no planner can serve (ConfigError naming the key).

    * plate.noise_std_mm: with plate.noise_range_known its low end (with the repeatability) is
      the low end of the probe.noise_range_mm the planner is told, which must be above 0.
    * plate.tilt_deg: the planner only sends the probe where a reading lands in the usable
      stroke with probability 1 - 1e-6 under the cell's prior (model.tilt_std_deg); it steps out
      from a touch by at most half the usable stroke / (z* tan(tilt_std)). A plate whose steepest
      slope, sqrt(2) tan(tilt_deg), exceeds z* tan(tilt_std) sends readings past the stroke end.
      The heights must also fit the workspace box's z range.
    * bound.mean_std_mm / true_rms_mm: below the noise floor -- the relaxed optimal design with
      bound.max_touches touches at the largest noise cannot reach it, so no design can.
    """
    from adaptive_cal.planning.scoring import STROKE_Z

    check_surface_files(study, cell, source)
    p, m, probe = study.plate, cell.model, cell.probe
    first_round = 5 + study.paper.nx * study.paper.ny  # levelling, then one S path
    if "paper" in study.strategies and study.bound.max_touches < first_round:
        raise ConfigError(
            f"{source}: bound.max_touches={study.bound.max_touches} is less than the paper's "
            f"first round, {first_round} touches (5 levelling points and the paper.nx x paper.ny "
            f"= {study.paper.nx} x {study.paper.ny} path): the paper strategy would run past the "
            "budget; raise bound.max_touches or leave 'paper' out of strategies")
    told = math.hypot(p.noise_std_mm[0], p.repeatability_mm)
    if p.noise_range_known and not told > 0:
        # the planner is told probe.noise_range_mm from these: its low end must be above 0 (a
        # log-normal prior); the cell check would name a key the study file never gave
        raise ConfigError(
            f"{source}: plate.noise_std_mm={list(p.noise_std_mm)} starts at 0 (with "
            f"plate.repeatability_mm={p.repeatability_mm}): with plate.noise_range_known the "
            "planner is told the noise span as probe.noise_range_mm, whose low end must be "
            "above 0 mm; give a low end above 0, or plate.noise_range_known: false")
    steepest = math.sqrt(2.0) * math.tan(math.radians(p.tilt_deg))
    allowed, offset, half = reach(cell)
    if steepest > allowed:
        raise ConfigError(
            f"{source}: plate.tilt_deg={p.tilt_deg} is beyond what the probe stroke allows: the "
            f"planner steps out so that readings stay inside the usable stroke "
            f"{list(probe.usable_mm)} mm for slopes up to {allowed:.4f} mm/mm "
            f"({STROKE_Z:.1f} x tan(model.tilt_std_deg={m.tilt_std_deg})); this plate's steepest "
            f"slope is {steepest:.4f}. Lower plate.tilt_deg or widen the cell's model.tilt_std_deg")
    if p.offset_mm > offset or p.offset_mm + p.form_pv_mm[1] > half:
        raise ConfigError(
            f"{source}: plate.offset_mm={p.offset_mm} with form up to {p.form_pv_mm[1]} mm puts "
            f"the first reading outside the usable stroke {list(probe.usable_mm)} mm "
            f"(model.offset_std_mm={m.offset_std_mm})")
    ws = cell.workspace
    if ws is not None:
        wp = cell.workplane
        rise = (math.tan(math.radians(p.tilt_deg)) * 0.5 * (wp.x_mm[1] - wp.x_mm[0] + wp.y_mm[1]
                                                            - wp.y_mm[0]) + p.offset_mm
                + p.form_pv_mm[1])
        mid = probe.zero_mm - 0.5 * (probe.usable_mm[0] + probe.usable_mm[1])
        if rise + mid > ws.z_mm[1] or -rise + mid < ws.z_mm[0]:
            raise ConfigError(
                f"{source}: plate.tilt_deg={p.tilt_deg} needs approach heights over "
                f"+-{rise:.2f} mm, outside the cell's workspace z_mm={list(ws.z_mm)}")
    _unit_slips(study, cell, source)
    floor = noise_floor_mm(study, cell)
    repeat = (f" and the robot's z repeatability {p.repeatability_mm} mm"
              if p.repeatability_mm else "")
    for key, value in (("bound.mean_std_mm", study.bound.mean_std_mm),
                       ("bound.true_rms_mm", study.bound.true_rms_mm)):
        if value is not None and value < floor:
            raise ConfigError(
                f"{source}: {key}={value} is below the noise floor: with reading noise up to "
                f"{p.noise_std_mm[1]} mm{repeat} and at most bound.max_touches={study.bound.max_touches} "
                f"touches no design brings the RMS posterior std below {floor:.5f} mm "
                "(relaxed optimal design); raise the bound or the touch budget")


def _unit_slips(study: Study, cell: Cell, source: str) -> None:
    """Um typed as mm: a noise a tenth of the usable stroke (the probe's own check), or a bound
    the prior meets before a touch: refused naming the key (a noise was blamed on the bound)."""
    from adaptive_cal.cell.build import prior_model
    from adaptive_cal.cell.consistency import um_as_mm
    from adaptive_cal.study.bound import design_problem

    p, (lo, hi) = study.plate, cell.probe.usable_mm
    for key, value in (("plate.noise_std_mm", p.noise_std_mm[1]),
                       ("plate.repeatability_mm", p.repeatability_mm)):
        if um_as_mm(value, hi - lo):
            raise ConfigError(f"{source}: {key} up to {value:g} mm is {value / (hi - lo):.0%} of "
                              f"the probe's usable stroke {hi - lo:g} mm: um given as mm? "
                              f"({value:g} um is {value / 1000:g} mm)")
    prob = design_problem(cell, model := prior_model(cell), model.hyper0, candidates=16)
    prior = float(rms_std_from_integrated_variance(prob.prior_integrated_variance, prob.area_mm2))
    for key, value in (("bound.mean_std_mm", study.bound.mean_std_mm),
                       ("bound.true_rms_mm", study.bound.true_rms_mm)):
        if value is not None and value >= prior:
            raise ConfigError(f"{source}: {key}={value:g} mm is above the RMS std of the cell's "
                              f"prior before any touch, {prior:.3g} mm: the prior alone meets "
                              f"it -- um given as mm? ({value:g} um is "
                              f"{value / 1000:g} mm)")


def noise_floor_mm(study: Study, cell: Cell) -> float:
    """Smallest RMS posterior std any design of bound.max_touches touches reaches at the largest
    noise of the distribution (relaxed optimal design, a lower bound)."""
    from adaptive_cal.cell.build import prior_model
    from adaptive_cal.study.bound import design_problem, relaxed_integrated_variance

    model = prior_model(cell)
    noise = math.hypot(study.plate.noise_std_mm[1], study.plate.repeatability_mm)
    prob = design_problem(cell, model, model.hyper0._replace(noise_std_mm=max(noise, 1e-6)),
                          candidates=400)
    j = relaxed_integrated_variance(prob, study.bound.max_touches, iterations=60)
    return float(rms_std_from_integrated_variance(j, prob.area_mm2))
