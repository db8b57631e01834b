"""Synthetic plates: each drawn from its own seed, so a study can grow or resume and plate i is
always the same plate. A plate is a variation of the base cell: its simulation block (tilt,
form, noise; or a height map of plate.surface_files) and the study's bound and keep-outs."""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from adaptive_cal.simulation.cell import SimulatedCell, gross_error_mm, reading_noise_mm
from adaptive_cal.cell.schema import Cell, parse_cell
from adaptive_cal.study.config import Study, surface_files


@dataclass(frozen=True)
class Plate:
    """One synthetic plate: index, seed, effects (effect-table names), noise (mm)."""

    index: int
    seed: int
    effects: dict
    noise_std_mm: float
    repeatability_mm: float
    surface_file: str | None = None  # a height map (plate.surface_files), under the base's effects


def sample_plate(study: Study, index: int) -> Plate:
    """Plate ``index`` of the study: drawn from default_rng([study.seed, index])."""
    p = study.plate
    rng = np.random.default_rng([study.seed, index])
    slope = math.tan(math.radians(p.tilt_deg))
    a, b = rng.uniform(-slope, slope, 2)
    c = rng.uniform(-p.offset_mm, p.offset_mm)
    pv = rng.uniform(*p.form_pv_mm)
    weights = {k: 0.0 for k in ("bow_x", "bow_y", "twist", "warp")}
    for k in p.form_shapes:
        weights[k] = float(rng.uniform(-1.0, 1.0))
    noise = float(rng.uniform(*p.noise_std_mm))
    effects = {"tilt": {"a": float(a), "b": float(b), "c": float(c)}}
    if pv > 0 and any(weights.values()):
        effects["form"] = {"pv_mm": float(pv), **weights}
    seed = int(rng.integers(2**31))
    files = surface_files(study)
    if files:  # the map is the plate; the draws above keep the noise as without maps
        return Plate(index, seed, {}, noise, p.repeatability_mm, files[index % len(files)])
    return Plate(index, seed, effects, noise, p.repeatability_mm)


def plate_cell(study: Study, base: dict, plate: Plate) -> Cell:
    """The base cell with this plate's truth, the study's bound and keep-outs."""
    data = copy.deepcopy(base)
    sim = dict(data.get("simulation") or {})
    effects = plate.effects  # a drawn plate's tilt and form take the base cell's place
    if plate.surface_file is not None:
        # the map is the plate; the base cell's effects add on top, as on a cell's own map
        # (DESIGN.md "Height maps")
        sim["surface_file"] = plate.surface_file
        effects = {**(sim.get("effects") or {}), **plate.effects}
    sim.update(seed=plate.seed, effects=effects, noise_std_mm=plate.noise_std_mm,
               repeatability_mm=plate.repeatability_mm)
    data["simulation"] = sim
    if study.plate.noise_range_known:
        # the reading noise the planner sees: probe noise and z repeatability together; a
        # single value is told as [0.8, 1.25] x (a datasheet figure is not exact)
        lo, hi = (math.hypot(n, plate.repeatability_mm) for n in study.plate.noise_std_mm)
        lo, hi = (0.8 * lo, 1.25 * hi) if hi <= lo else (lo, hi)
        probe = dict(data.get("probe") or {})
        probe.pop("noise_std_mm", None)
        probe["noise_range_mm"] = [lo, hi]
        data["probe"] = probe
    plan = dict(data.get("plan") or {})
    stop = dict(plan.get("stop") or {})
    stop.update(mean_std_mm=study.bound.mean_std_mm, max_std_mm=None,
                max_touches=study.bound.max_touches)
    plan["stop"] = stop
    data["plan"] = plan
    if study.plate.keep_outs is not None:
        wp = dict(data["workplane"])
        wp["keep_outs"] = [k.model_dump() for k in study.plate.keep_outs]
        data["workplane"] = wp
    return parse_cell(data, f"plate {plate.index}")


def truth(cell: Cell):
    """The plate's true height function (mm) of (x_mm, y_mm)."""
    return SimulatedCell.from_cell(cell).surface_mm


def heights_at(cell: Cell, xy: np.ndarray, first_touch: int = 0) -> np.ndarray:
    """Surface heights implied by touches at ``xy`` taken as touch numbers first_touch, ...:
    the simulated cell's draws (xy and z repeatability, reading noise) for each touch, so a
    design sees the same noise the probe cycle would give it."""
    sim = cell.simulation
    f = truth(cell)
    out = np.empty(len(xy))
    for k, (x, y) in enumerate(np.asarray(xy, float)):
        rng = np.random.default_rng([sim.seed, first_touch + k])
        e = rng.standard_normal(3)
        surface = float(f(x + sim.xy_repeatability_mm * e[0], y + sim.xy_repeatability_mm * e[1]))
        out[k] = (surface - sim.repeatability_mm * e[2] + reading_noise_mm(sim, rng)
                  + gross_error_mm(sim, rng))
    return out
