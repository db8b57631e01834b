"""A validated cell file, turned once, at the edge, into the engine's plain values: the prior
model (knots, prior) and the survey plan (``planning.plan.SurveyPlan``). Nothing below this
module reads a ``Cell``.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from adaptive_cal.cell.consistency import check_knots, derived_box_mm, doubts
from adaptive_cal.cell.files import ConfigError
from adaptive_cal.cell.schema import Cell, Workspace
from adaptive_cal.gaussian.prior import Hyper, PriorModel
from adaptive_cal.gaussian.spline import Surface, default_knots, embedding, refined
from adaptive_cal.hardware.base import frozen_after
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.scoring import candidate_grid
from adaptive_cal.planning.stopping import (AtLeast, GapBelow, MaxStdBelow, MeanStdBelow, StopRule,
                                            TouchBudget)

EVAL_POINTS = 41  # the evaluation grid over the plate is EVAL_POINTS x EVAL_POINTS
GROW_CAP = 160  # a model grows (knots refined once) only up to this many coefficients
# spline coefficients the coarse model may have: at 24 x 24 = 576 a decision took 0.55 s on one
# core and every fourth (a hyper-parameter refit) 3.1 s, about a touch's time; 32 x 32: 1.4 and
# 8.9 s, and a 64 x 64 dry run did not finish in a minute (2026-11-24)
MAX_COEFFICIENTS = 576
MAX_CANDIDATE_ENTRIES = 200_000_000  # candidates x coefficients: the basis rows scored each
# decision (and a product as large) at 8 bytes an entry, 1.6 GB each; 10^6 candidates pass at
# the grown model's 160 coefficients


def workspace(cell: Cell) -> Workspace | None:
    """The box every target must lie in: the cell file's ``workspace``, or for a simulated
    cell without one the box derived from its workplane and stroke
    (``cell.consistency.derived_box_mm``). The planner (z range) and the probe cycle's safety
    check both read it from here."""
    if cell.workspace is not None or cell.robot.adapter != "sim":
        return cell.workspace
    x, y, z = derived_box_mm(cell)
    return Workspace(x_mm=x, y_mm=y, z_mm=z)


def knots_for(cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """Knots from the cell file (on the workplane's edges: ``check_knots`` again, for a cell
    changed by ``model_copy``), or evenly spaced by Brunn eq. 15."""
    m, wp = cell.model, cell.workplane
    check_knots(cell)
    out = []
    for spec, (lo, hi) in ((m.knots_x, wp.x_mm), (m.knots_y, wp.y_mm)):
        if isinstance(spec, list):
            k = np.asarray(spec, float)
        elif isinstance(spec, int):
            k = np.linspace(lo, hi, spec)
        else:
            k = default_knots(lo, hi, m.form_tolerance_mm, m.max_curvature_per_mm)
        out.append(k)
    nx, ny = len(out[0]), len(out[1])
    if nx * ny > MAX_COEFFICIENTS:
        raise ConfigError(
            f"model.knots_x x knots_y = {nx} x {ny} = {nx * ny} spline coefficients: at most "
            f"{MAX_COEFFICIENTS} (24 x 24; a decision then takes about a touch's time, 0.5-3 s "
            "on one core, the covariance being coefficients x coefficients): give fewer knots")
    return out[0], out[1]


def pivot(cell: Cell) -> tuple[float, float]:
    """Where the prior knows the plate's height to model.offset_std_mm: model.pivot_mm, else the
    workplane's centre. A frame taught with its origin at a corner of the plate has its z set
    there (an audit: x 0..600 mm, 1 deg both ways -- the plate 7 mm high at the centre, past the
    stroke at the first touch), one whose z was set at the centre does not (a second audit, when
    the origin was the default for a day): the cell file says which, ``pivot_doubt`` asks."""
    given = cell.model.pivot_mm
    if given is not None:
        return float(given[0]), float(given[1])
    wp = cell.workplane
    return 0.5 * (wp.x_mm[0] + wp.x_mm[1]), 0.5 * (wp.y_mm[0] + wp.y_mm[1])


def pivot_doubt(cell: Cell) -> str | None:
    """Where model.pivot_mm is not given and the frame's origin lies on the workplane so far
    from its centre that a tilt of tilt_std_deg puts the two more than offset_std_mm apart: which
    of them the frame's z was set at decides where the first touches can go."""
    wp, m = cell.workplane, cell.model
    if m.pivot_mm is not None or not (wp.x_mm[0] <= 0 <= wp.x_mm[1]
                                      and wp.y_mm[0] <= 0 <= wp.y_mm[1]):
        return None
    cx, cy = pivot(cell)
    apart_mm = float(np.hypot(cx, cy))
    dz = apart_mm * float(np.tan(np.radians(m.tilt_std_deg)))
    if dz <= m.offset_std_mm:
        return None
    return (f"model.pivot_mm is not given: the prior knows the plate's height to "
            f"{m.offset_std_mm:g} mm (model.offset_std_mm) at the workplane's centre ({cx:g}, "
            f"{cy:g}) mm; the frame's origin (0, 0) lies on the plate {apart_mm:.0f} mm from it, "
            f"where a tilt of {m.tilt_std_deg:g} deg (model.tilt_std_deg) puts the plate "
            f"{dz:.2g} mm off. If the frame's z was set at its origin (a frame taught at the "
            "plate's corner), say model.pivot_mm: [0, 0]; if at the centre, say "
            f"model.pivot_mm: [{cx:g}, {cy:g}]")


def prior_model(cell: Cell) -> PriorModel:
    """The spline over the workplane and its prior (tilt + form, the reading noise's prior)."""
    wp, m = cell.workplane, cell.model
    surface = Surface.create(*knots_for(cell), ends=m.ends)
    span = min(wp.x_mm[1] - wp.x_mm[0], wp.y_mm[1] - wp.y_mm[0])
    noise, noise_log_std = cell.probe.noise_prior()
    hyper0 = Hyper(m.form_std_mm, m.length_scale_mm or 0.5 * span, noise, m.form_kernels[0])
    log_std = PriorModel.hyper_log_std
    if noise_log_std is not None:
        log_std = log_std[:2] + (noise_log_std,)
    span_mm = cell.probe.noise_range_mm
    return PriorModel(surface, float(np.tan(np.radians(m.tilt_std_deg))), m.offset_std_mm,
                      pivot(cell), hyper0, log_std,
                      noise_span_mm=tuple(map(float, span_mm)) if span_mm else None,
                      kernels=tuple(dict.fromkeys(m.form_kernels)))


def grown_model(model: PriorModel, cap: int = GROW_CAP
                ) -> tuple[PriorModel, np.ndarray] | tuple[None, None]:
    """The model on refined knots (every interval halved) whose form stays on the coarse knots
    (exactly the same prior and posterior until it grows), and the unit covariance of the finer
    structure on the refined knots: squared-exponential at the refined spacing. (None, None)
    when the refined spline would have more than ``cap`` coefficients."""
    s = model.surface
    fine = Surface.create(refined(s.sx.knots), refined(s.sy.knots), ends=s.sx.ends)
    if fine.size > cap:
        return None, None
    length = fine.knot_interval_mm
    gx, gy = fine.knot_grid()
    d2 = (gx[:, None] - gx[None, :]) ** 2 + (gy[:, None] - gy[None, :]) ** 2
    unit = np.exp(-0.5 * d2 / length**2)
    return replace(model, surface=fine, embed=embedding(s, fine), coarse=s), unit


def plan_model(cell: Cell) -> PriorModel:
    """The model a survey of ``cell`` plans with (its belief.npz has these knots): the prior
    model, on the refined knots of ``grown_model`` when ``model.grow`` (and within the cap)."""
    model = prior_model(cell)
    if cell.model.grow:
        big, _ = grown_model(model)
        return big or model
    return model


def stop_rule(cell: Cell, coefficients: int, *, informed_prior: bool = False) -> StopRule:
    """(every variance bound set, after at least min_touches touches) | touch budget.

    By default a bound may stop the run only after as many touches as the spline has
    coefficients: before that the hyper-parameters rest on too few readings, and runs that
    stopped at 10-14 touches were over-confident -- the learned noise collapsed to 2-4 um on
    plates read with 8-18 um (study plates: coverage 0.908 -> 0.934 with the rule, about 5 %
    more touches). A noise range from the probe's datasheet (``probe.noise_range_mm``) keeps
    the noise from collapsing, a prior from an earlier run (``informed_prior``) already
    carries the hyper-parameters, and with ``model.learn_hyper: false`` nothing is learned:
    then a bound may stop the run at once."""
    s = cell.plan.stop
    bounds = [MeanStdBelow(s.mean_std_mm)] if s.mean_std_mm is not None else []
    bounds += [MaxStdBelow(s.max_std_mm)] if s.max_std_mm is not None else []
    rule: StopRule = TouchBudget(s.max_touches)
    if bounds:
        bound = bounds[0] if len(bounds) == 1 else bounds[0] & bounds[1]  # every one set
        bound = bound & AtLeast(touch_floor(cell, coefficients, informed_prior=informed_prior))
        if s.max_gap_mm is not None:
            bound = bound & GapBelow(s.max_gap_mm)
        rule = bound | rule
    return rule


def touch_floor(cell: Cell, coefficients: int, *, informed_prior: bool = False) -> int:
    """Touches before a bound may stop the run (``stop_rule``): plan.stop.min_touches, else the
    number of coefficients while the hyper-parameters are learned without a stated noise range
    and without an earlier belief, else 0."""
    s = cell.plan.stop
    guard = cell.model.learn_hyper and not informed_prior and cell.probe.noise_range_mm is None
    return s.min_touches if s.min_touches is not None else (coefficients if guard else 0)


def cell_doubts(cell: Cell, *, informed_prior: bool = False) -> list[str]:
    """``consistency.doubts``, ``pivot_doubt`` and the touch floor's: a floor the cell file left
    to its default (the spline's coefficients, ``touch_floor``) above the touch budget -- no
    variance bound could stop the run, which would spend its budget and end with no result (an
    audit: a 3 x 2 m plate's 256 coefficients against the default budget of 200, said only at
    the end). An explicit plan.stop.min_touches above max_touches is refused at load."""
    out = doubts(cell) + [line for line in [pivot_doubt(cell)] if line]
    s = cell.plan.stop
    if s.min_touches is None and (s.mean_std_mm is not None or s.max_std_mm is not None):
        kx, ky = knots_for(cell)
        floor = touch_floor(cell, len(kx) * len(ky), informed_prior=informed_prior)
        if floor > s.max_touches:
            out.append(f"plan.stop.max_touches: {s.max_touches} touches is below the touch floor "
                       f"of {floor} (the spline's {len(kx)} x {len(ky)} coefficients, learned "
                       "from scratch: plan.stop.min_touches' default), so no variance bound can "
                       "stop the run and it will spend its budget and end with no result: raise "
                       f"max_touches to {floor} or more, give fewer knots (model.knots_x/y), "
                       "or state the probe's noise span (probe.noise_range_mm: no floor)")
    return out


def criterion(cell: Cell) -> str:
    """``plan.criterion``, with ``auto`` resolved: ``max`` for a max-std bound alone, else
    ``integrated``."""
    if cell.plan.criterion != "auto":
        return cell.plan.criterion
    s = cell.plan.stop
    return "max" if s.max_std_mm is not None and s.mean_std_mm is None else "integrated"


def survey_plan(cell: Cell, *, informed_prior: bool = False, model: PriorModel | None = None,
                eval_points: int = EVAL_POINTS, grow: bool | None = None) -> SurveyPlan:
    """Everything the planner reads from the cell file, read once. ``informed_prior``: the
    survey starts from an earlier run's belief (``--prior-from``): no touch floor in the stop
    rule (learning is off for such a survey anyway, see ``planning.survey.learns``).
    ``grow``: a model that grows where its self-checks find structure finer than the knots
    (``grown_model``; planning runs on the refined knots from the start; default
    ``model.grow``). A survey from an earlier belief plans on the same knots but does not grow."""
    grow = cell.model.grow if grow is None else grow
    model = model or prior_model(cell)
    coarse_size = model.surface.size
    growth = None
    if grow and model.coarse is None:
        big, unit = grown_model(model)
        model = big or model
        growth = unit if big is not None and not informed_prior else None
    k, n = model.surface.size, cell.plan.candidates
    if n * k > MAX_CANDIDATE_ENTRIES:  # refused before anything is allocated or moved
        raise ConfigError(
            f"plan.candidates={n} with {k} spline coefficients (model.knots_x x knots_y"
            f"{', refined where the model grows' if k > coarse_size else ''}) scores "
            f"{n * k * 8 / 1e9:.1f} GB of basis rows each decision: give at most "
            f"{MAX_CANDIDATE_ENTRIES // k} candidates, or fewer knots")
    wp = cell.workplane
    inner = wp.reach_mm
    cand = candidate_grid(model.surface, wp.allows, *inner, cell.plan.candidates)
    gx, gy = np.meshgrid(np.linspace(*wp.x_mm, eval_points), np.linspace(*wp.y_mm, eval_points),
                         indexing="ij")
    exy = np.stack([gx.ravel(), gy.ravel()], 1)
    plan, box = cell.plan, workspace(cell)
    return SurveyPlan(
        model=model, candidates=cand, gram=model.surface.gram(), eval_xy=exy,
        eval_rows=model.surface.basis(exy[:, 0], exy[:, 1]),
        usable_mm=tuple(cell.probe.usable_mm), zero_mm=cell.probe.zero_mm,
        z_range_mm=tuple(box.z_mm) if box is not None else None,
        allows=wp.allows, bounds_mm=inner, plate_mm=(tuple(wp.x_mm), tuple(wp.y_mm)),
        gate_sigma=cell.model.gate_sigma, learn=cell.model.learn_hyper,
        hyper_after=plan.hyper_after, hyper_every=plan.hyper_every, criterion=criterion(cell),
        refine=plan.refine, batch=plan.batch,
        stop=stop_rule(cell, coarse_size, informed_prior=informed_prior), growth=growth,
        noise_range_mm=(tuple(cell.probe.noise_range_mm)
                        if cell.probe.noise_range_mm is not None else None),
        speed_mm_per_s=cell.robot.speed_mm_per_s, touch_time_s=cell.robot.touch_time_s,
        start_xy_mm=(0.5 * sum(wp.x_mm), 0.5 * sum(wp.y_mm)),
        min_spacing_mm=min_spacing(cell, model.surface), max_gap_mm=plan.stop.max_gap_mm,
        closure=plan.closure and not informed_prior,  # a re-check: a few touches, a warm cell
        frozen_after=readout_frozen_after(cell), kept_out=wp.kept_out)


def readout_frozen_after(cell: Cell) -> int | None:
    """Touches in a row with one reading that mark the cell's probe readout frozen
    (``hardware.base.frozen_after``): its readout step against the least noise the cell states
    (``probe.noise_range_mm``'s low end, else ``probe.noise_std_mm``), over the touch budget."""
    p = cell.probe
    noise = p.noise_range_mm[0] if p.noise_range_mm else p.noise_std_mm
    return frozen_after(p.resolution_mm, noise, cell.plan.stop.max_touches)


def min_spacing(cell: Cell, surface) -> float:
    """``plan.min_spacing_mm``, by default half the largest knot interval of the spline the
    planner plans on: the spacing touches keep once the self-checks found structure finer than
    the knots (``planning.ask.kept_apart``). Two touches closer than that inform nearly the same
    coefficients; where the learned reading noise holds plate structure finer than the knots, a
    second touch there looks like averaging noise down, but the structure it shares with the
    first stays (a model that may be inadequate wants spread designs: Box & Draper 1959). On
    rough plates the planner had put touches in pairs 4-16 mm apart (median nearest neighbour
    15.6 mm, the serpentine grid's 29 mm) and its bands covered 0.87 of the plate against the
    grid's 0.97 at the same 200 touches; kept apart, 0.92 (benchmarks/bench_plates.py, 20
    plates). Kept apart from the first touch, the runs on smooth and noisy plates stopped
    earlier and their coverage fell (0.93 -> 0.90-0.92, 0.91 -> 0.87-0.88) and the in-family
    study made 8 % more touches at 22.5 mm; hence only once finer structure is found."""
    if cell.plan.min_spacing_mm is not None:
        return float(cell.plan.min_spacing_mm)
    return 0.5 * surface.knot_interval_mm
