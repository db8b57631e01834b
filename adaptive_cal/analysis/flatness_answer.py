"""The one flatness answer of a map, used by ``run`` (summary, result.json), ``flatness`` and the
report, with the same words and numbers in all three:

- of the touched points: the paper's figures (Cheng et al. eqs. 1-6, and the ISO 1101 minimum
  zone) of the measured heights; interval: the same figures over predicted repeat measurements at
  the same touches, z* = B m* + e*, m* drawn from the belief, e* ~ N(0, sigma^2 I);
- of the whole plate: the figures of the posterior mean map on the plan's evaluation grid;
  interval: the same figures over surfaces sampled from the belief, plus a draw of the
  structure the spline cannot represent (s_u^2, ``planning.survey.unresolved_var_mm2``: the
  learned form's part finer than the knots, the readings' excess where the self-checks failed,
  a drift the closure found) -- the same variance the bands carry, as a Gaussian field of that
  pointwise variance with a squared-exponential correlation of half the knot spacing
  (``unresolved_draws``). Flatness is a max - min statistic, so that structure widens it more
  than its RMS suggests: left out, the intervals held the true plate's minimum-zone flatness on
  11 of 20 rough plates (Matern-3/2, 60 mm), with it on 18 (benchmarks/bench_flatness.py,
  docs/flatness.md). A feature between the touches is in no interval: ``largest_gap`` says
  where the widest untouched disc is;
- within reach of the touches (where the workplane has an edge margin no touch enters): the
  same figures and coefficient draws on a grid spanning the reachable box (``analysis.reach``).
  Beyond it the map is an extrapolation no reading tested: on plates whose edges roll off, the
  whole plate's minimum-zone interval held the truth on 12 of 20, within reach on 18.

Both figures remove the tilt (the least-squares or minimum-zone plane); the raw height spread
(max - min, tilt included) is kept as ``range`` and labelled as such, never called flatness.

Flatness is a max - min statistic: under noise the figure of the measured heights is biased up,
and the figure of the mean map (smoother than any sample) down, so either can fall outside its own
sampled interval: the map's is then replaced by the posterior median, the measured heights' is
kept and said (``OUTSIDE``); ``value_is`` says which. Randomness is passed in: one generator,
plate draws first, then touched ones: the same seed, the same digits wherever computed.
"""
from __future__ import annotations

import numpy as np
from scipy import special  # ndtr, stdtrit: scipy.stats's norm.cdf and t.ppf, bit for bit,
# without loading scipy.stats (about 1-3 s of `report` and `flatness` start-up)

from adaptive_cal.analysis import flatness as fl
from adaptive_cal.analysis.reach import (GAP_MEANS, gap_line, largest_gap,  # noqa: F401
                                        on_grid, reach_grid)  # (largest_gap: its home before)
from adaptive_cal.analysis.tails import tail_dof_of, unit_noise
from adaptive_cal.gaussian import belief as bl

SAMPLES = 200  # posterior samples behind every interval (run, flatness and report alike)
SEED = 0  # the seed of those samples
FIGURES = (("least_squares", "least squares (Cheng eq. 5)"),
           ("minimum_zone", "minimum zone (ISO 1101)"))
PLATE = "of the whole plate (from the map)"
SPREAD = "height spread, max - min with the tilt included (not flatness)"
#: what a result's flatness_mm is (a bare recording's is of its touched points instead)
PLATE_IS = "the whole plate, from the map; touched_flatness_mm: the touched points as measured"
#: under the whole plate's figures: what their intervals held on plates the prior did not make
PLATE_CALIBRATION = ("the whole plate's 95 % intervals are the map's belief: on plates the prior "
                     "did not make they held the true flatness 70-80 % of the time (edge roll-off "
                     "41-80 %; docs/flatness.md)")
MEDIAN = "posterior median"
MEDIAN_NOTE = ("* posterior median of the samples: the figure itself lay outside its 95 % interval "
               "(flatness is a max - min statistic, biased by noise and by smoothing)")
MEASURED, OUTSIDE_MARK = "figure of the measured heights", "**"  # ASCII, as every line printed
OUTSIDE = "figure of the measured heights, outside the interval of a repeat"  # kept, marked
OUTSIDE_NOTE = (f"{OUTSIDE_MARK} the figure of the measured heights lies outside the 95 % interval "
                "of a repeat: by chance one time in twenty, or because the map does not "
                "reproduce these readings (a bump or dent narrower than the touch spacing, a "
                "misreading); the figure is the readings' own")


def touched_what(points: int) -> str:
    # the interval holds a repeat's figure, and noise raises a max - min: an outside audit read
    # "95 %" as the plate's flatness there, which lay below it 50 times in 84 (least squares)
    return (f"of the {points} touched points as measured (Cheng eqs. 1-6; the 95 % intervals: "
            "a repeat measurement's figure, which the noise raises above the plate's own)")


def within_what(within: dict) -> str:
    (x0, x1), (y0, y1) = within["box_mm"]
    return (f"within reach of the touches (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm; beyond, the "
            "map is extrapolated)")


def entry(value: float, samples: np.ndarray, figure_is: str) -> dict:
    """{"value", "ci95", "value_is"}: the figure when it lies in its 95 % interval, else the
    posterior median of the samples -- but a figure of the measured heights is kept (OUTSIDE):
    a level plate with readings +50 and -30 um has a minimum zone of 68 um, the map's median
    said 37.7 (JSON-ready; non-finite as None)."""
    samples = np.asarray(samples, dtype=np.float64)
    lo, hi = fl._ci95(samples)
    if lo is not None and not lo <= value <= hi and figure_is != MEASURED:
        return {"value": float(np.median(samples)), "ci95": [lo, hi], "value_is": MEDIAN}
    outside = lo is not None and not lo <= value <= hi
    return {"value": fl.finite_or_none(value), "ci95": [lo, hi],
            "value_is": OUTSIDE if outside else figure_is}


def _figures(x, y, z, draws, figure_is: str) -> dict:
    values = {"least_squares": fl.ls_flatness_mm(x, y, z),
              "minimum_zone": fl.minimum_zone_mm(x, y, z).value_mm, "range": fl.range_mm(z)}
    sampled = {"least_squares": fl.ls_flatness_samples_mm(x, y, draws),
               "minimum_zone": np.array([fl.minimum_zone_mm(x, y, d).value_mm for d in draws]),
               "range": np.ptp(draws, axis=1)}
    return {k: entry(values[k], sampled[k], figure_is) for k in values}


def correlation_length_mm(surface) -> float:
    """Half the spline's mean knot spacing along its finer axis: the scale the structure it
    cannot represent is drawn at (``unresolved_draws``)."""
    return 0.5 * min(float(np.mean(np.diff(surface.sx.knots))),
                     float(np.mean(np.diff(surface.sy.knots))))


def unresolved_draws(xy, var_mm2, length_mm: float, rng: np.random.Generator,
                     samples: int) -> np.ndarray:
    """(samples, N) draws of a zero-mean Gaussian field with variance ``var_mm2`` at the points
    ``xy`` (N, 2) and the correlation exp(-d^2 / (2 length^2)) between them; zeros (and no
    random numbers used) where the variance is zero everywhere."""
    var = np.asarray(var_mm2, dtype=np.float64).ravel()
    if not np.any(var > 0.0):
        return np.zeros((samples, len(var)))
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    ux, uy = np.unique(xy[:, 0]), np.unique(xy[:, 1])
    gx, gy = np.meshgrid(ux, uy, indexing="ij")
    z = rng.standard_normal((samples, len(var)))
    if len(ux) * len(uy) == len(xy) and np.array_equal(np.c_[gx.ravel(), gy.ravel()], xy):
        # a grid (the plan's evaluation grid): the correlation is the Kronecker product of the
        # axes' ones, and so is its square root -- (S, nx, ny) draws as Rx Z Ry^T
        rx, ry = (_root(u[:, None], length_mm) for u in (ux, uy))
        field = (rx @ z.reshape(samples, len(ux), len(uy)) @ ry.T).reshape(samples, -1)
    else:
        field = z @ _root(xy, length_mm).T
    return field * np.sqrt(np.maximum(var, 0.0))


def _root(xy, length_mm: float) -> np.ndarray:
    """R with R R^T = exp(-d^2 / (2 length^2)) between the points: an eigen square root, since
    on points closer than the length the correlation is near singular (negative round-off
    eigenvalues set to zero keep each point's variance exact to about 1e-12)."""
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1)
    w, v = np.linalg.eigh(np.exp(-0.5 * d2 / length_mm**2))
    return v * np.sqrt(np.clip(w, 0.0, None))


def plate_answer(eval_xy, eval_rows, belief: bl.Belief, rng: np.random.Generator,
                 samples: int = SAMPLES, unresolved_mm2=None,
                 length_mm: float | None = None, features=(), reach=None) -> tuple[dict, dict]:
    """(tilt, flatness of the whole plate): the tilt of the mean map's least-squares plane with
    the std of its angles over the sampled surfaces, and the figures with intervals.
    ``unresolved_mm2``: s_u^2 at the evaluation points (None: the spline's variance alone),
    drawn with correlation length ``length_mm`` (``unresolved_draws``) after the spline's.
    ``features``: (row, departure_mm, sd_mm, x_mm, y_mm) of local features a retake confirmed
    (``analysis.local_features``): points added to the figures at the map plus the departure,
    drawn with its sd; the tilt stays the grid's. ``reach``: (xy, rows, s_u^2 or None) of a grid
    spanning the part touches could reach: the figures there (the same coefficient draws, the
    features added; its s_u^2 field drawn from a generator spawned from ``rng``, so the whole
    plate's and the touched points' digits do not move) are the entry ``within_reach``."""
    x, y = eval_xy[:, 0], eval_xy[:, 1]
    mean, _ = bl.predict(belief, eval_rows)
    coef = bl.sample(belief, rng, samples)
    draws = coef @ eval_rows.T  # (S, N)
    if unresolved_mm2 is not None:
        draws = draws + unresolved_draws(eval_xy, unresolved_mm2, length_mm, rng, samples)
    tilt = fl.plane_tilt(x, y, mean)
    angles = np.array([fl.tilt_correction_deg(*fl.least_squares_plane(x, y, d)[:2]) for d in draws])
    tilt["rx_std_deg"], tilt["ry_std_deg"] = (float(v) for v in angles.std(axis=0))
    added = []  # a confirmed feature lies on a touch: within reach too
    for row, dep, sd, fx, fy in features:
        added.append((fx, fy, float(row @ belief.mean) + dep,
                      coef @ row + dep + sd * rng.standard_normal(samples)))
    if added:
        fx, fy, fm, fd = (np.array(v) for v in zip(*added))
        x, y, mean, draws = np.r_[x, fx], np.r_[y, fy], np.r_[mean, fm], np.c_[draws, fd.T]
    figures = _figures(x, y, mean, draws, "figure of the mean map")
    if reach is not None:
        rxy, rrows, ru = reach
        rdraws = coef @ rrows.T
        if ru is not None:
            rdraws = rdraws + unresolved_draws(rxy, ru, length_mm, rng.spawn(1)[0], samples)
        rx, ry, rmean = rxy[:, 0], rxy[:, 1], bl.predict(belief, rrows)[0]
        if added:
            rx, ry, rmean = np.r_[rx, fx], np.r_[ry, fy], np.r_[rmean, fm]
            rdraws = np.c_[rdraws, fd.T]
        figures["within_reach"] = _figures(rx, ry, rmean, rdraws, "figure of the mean map")
    return tilt, figures


def touched_answer(x, y, z, rows, belief: bl.Belief, noise_std_mm: float,
                   rng: np.random.Generator, samples: int = SAMPLES, nu: float | None = None) -> dict:
    """Flatness of the touched points: the figures of the heights z (mm) at (x, y), intervals over
    predicted repeats B m* + e* (``rows`` = B, the touches' spline rows; ``repeat_noise_mm``).
    A repeat's noise is as uncertain as its learned sd: s*^2 = s^2 nu / chi2_nu drawn once per
    repeat (the noise variance's posterior on nu degrees of freedom, a Jeffreys prior), nu =
    sum_i (1 - l_i) the touches less what the map spent (``noise_dof``; with s alone the
    intervals held fresh repeats 0.91 of the time, benchmarks/bench_flatness.py). ``nu``: where
    known (None: from ``rows``), inf for a noise the cell states and does not learn."""
    x, y, z = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    rows = np.asarray(rows, dtype=np.float64)
    draws = bl.sample(belief, rng, samples) @ rows.T
    if noise_std_mm > 0:
        draws = draws + repeat_noise_mm(rows, belief, noise_std_mm, rng, samples, nu, z)
    out = _figures(x, y, z, draws, MEASURED)
    return {"points": int(len(z)), **out}


def repeat_noise_mm(rows, belief: bl.Belief, noise_std_mm: float, rng: np.random.Generator,
                    samples: int, nu: float | None = None, heights=None) -> np.ndarray:
    """(samples, n) reading noise of repeats at the touches ``rows``: each row s* e, e ~ N(0, I)
    -- Student-t of unit variance where the readings ``heights`` (mm) there are heavy-tailed
    (``analysis.tails``) -- s*^2 = s^2 nu / chi2_nu (``touched_answer``); ``nu`` None:
    ``noise_dof`` of the rows; inf: s* = s (a stated noise, no chi2 drawn)."""
    nu = noise_dof(rows, belief, noise_std_mm) if nu is None else nu
    scale = (np.full(samples, noise_std_mm) if np.isinf(nu)
             else noise_std_mm * np.sqrt(nu / rng.chisquare(nu, samples)))
    tails = tail_dof_of(rows, belief, heights, noise_std_mm)
    return scale[:, None] * unit_noise(tails, rng, (samples, len(rows)))


def noise_dof(rows, belief: bl.Belief, noise_std_mm: float) -> float:
    """The degrees of freedom the learned noise rests on at these touches: sum_i (1 - l_i), l_i
    = h_i C h_i / s^2 (``planning.closure.residual_dof``, every touch at full weight: the same
    number from a run's state and from its saved belief)."""
    from adaptive_cal.planning.closure import residual_dof

    return residual_dof(rows, np.ones(len(rows)), belief.cov, noise_std_mm**2)


TWO_SD = float(special.ndtr(2.0))  # the upper end of a 2-sd interval's share, 0.97725


def t_std_factor(nu: float) -> float:
    """What the std of a quantity whose conditional posterior scales with the learned noise sd
    (the tilt: data, not its 1 deg prior, decide it) grows by when that sd's own uncertainty is
    counted: the posterior is then a Student-t on ``nu`` degrees of freedom (``noise_dof``),
    reported as the Gaussian std with the same 2-sd (95.45 %) interval, t_nu(0.97725) / 2 --
    finite for every nu, within 3 % of the t's own std sqrt(nu / (nu - 2)) from nu = 4 on
    (1.26 at nu = 6, 1.14 at 10, 1.07 at 20). Measured before it was counted: on 140 runs of
    seven plate families rx, ry +- 2 sd held the true map's plane 0.92 of the time, error / sd
    RMS 1.25 in runs under 15 touches, 1.10 at 15-21 (benchmarks/bench_flatness.py)."""
    if not np.isfinite(nu) or nu <= 0:
        return 1.0
    return float(special.stdtrit(nu, TWO_SD) / 2.0)  # t_nu's quantile


def flatness_answer(plan, belief: bl.Belief, noise_std_mm: float, touched_xyz=None,
                    rng: np.random.Generator | None = None, samples: int = SAMPLES,
                    unresolved_mm2=None, features=(), noise_learned: bool = True) -> dict:
    """{"tilt", "flatness_mm" (whole plate), "touched_flatness_mm" (when ``touched_xyz`` =
    (x, y, height) in mm is given)} from a ``SurveyPlan``'s evaluation grid and a belief over its
    spline. ``unresolved_mm2``: s_u^2 on ``plan.eval_xy``; ``features``: the confirmed local
    features' dicts (``analysis.local_features.confirmed``; ``plate_answer``). ``rng`` defaults
    to ``default_rng(SEED)``; the plate is drawn first. With the touches the tilt's stds count
    the learned noise's degrees of freedom (``t_std_factor``; result.json ``tilt.noise_dof``);
    ``noise_learned`` False (a cell that states its noise and does not learn it,
    ``model.learn_hyper: false``): the stated noise is taken as exact, in the tilt and in the
    touched points' repeats alike."""
    rng = np.random.default_rng(SEED) if rng is None else rng
    surface = plan.model.surface
    extra = [(surface.basis(np.array([f["x_mm"]]), np.array([f["y_mm"]]))[0], f["departure_mm"],
              f["sd_mm"], f["x_mm"], f["y_mm"]) for f in features]
    box = getattr(plan, "bounds_mm", None)
    reach = None
    if box is not None and not np.all(_in_box(plan.eval_xy, box)):
        rxy = reach_grid(plan.eval_xy, box)
        ru = None if unresolved_mm2 is None else on_grid(plan.eval_xy, unresolved_mm2, rxy)
        reach = (rxy, surface.basis(rxy[:, 0], rxy[:, 1]), ru)
    tilt, plate = plate_answer(plan.eval_xy, plan.eval_rows, belief, rng, samples, unresolved_mm2,
                               correlation_length_mm(surface), extra, reach)
    rows = None
    if touched_xyz is not None:
        x, y, z = touched_xyz
        rows = surface.basis(np.asarray(x, float), np.asarray(y, float))
        nu = np.inf  # a stated noise, or none: exact
        if noise_std_mm > 0 and noise_learned:  # the learned noise's own uncertainty counted
            nu = noise_dof(rows, belief, noise_std_mm)
            f = t_std_factor(nu)
            tilt["rx_std_deg"], tilt["ry_std_deg"] = tilt["rx_std_deg"] * f, tilt["ry_std_deg"] * f
            tilt["noise_dof"] = float(nu)
    out = {"tilt": tilt, "flatness_mm": plate, "flatness_mm_is": PLATE_IS}
    within = plate.pop("within_reach", None)
    if within is not None:
        within.pop("range")
        out["flatness_within_reach_mm"] = {
            "box_mm": [list(map(float, b)) for b in box],
            "eval_points": len(reach[0]),
            **within, "means": WITHIN_MEANS}
    if rows is not None:
        out["touched_flatness_mm"] = touched_answer(x, y, z, rows, belief, noise_std_mm, rng,
                                                    samples, nu)
    return out


WITHIN_MEANS = ("the same figures of the map on a grid of eval_points spanning box_mm, the part "
                "of the workplane touches could reach (the plate less its edge margin): beyond it "
                "the map is an extrapolation no reading tested, and an edge that rolls off there "
                "is in no interval (the whole plate's figures include that margin)")


def _in_box(xy, box) -> np.ndarray:
    (x0, x1), (y0, y1) = box
    x, y = np.asarray(xy, float)[:, 0], np.asarray(xy, float)[:, 1]
    return (x >= x0 - 1e-9) & (x <= x1 + 1e-9) & (y >= y0 - 1e-9) & (y <= y1 + 1e-9)


# -- the words, shared by the terminal (run, flatness) and the report ---------------------------
def value_text(f: dict) -> str:
    """e.g. "276.4 um (95 % 268.6 .. 293.6 um)", "7009.8 um = 7.01 mm (...)"; a posterior
    median is marked with "*"."""
    star = {MEDIAN: "*", OUTSIDE: OUTSIDE_MARK}.get(f.get("value_is"), "")
    if f.get("value") is None:
        return "n/a"
    lo, hi = f.get("ci95", [None, None])
    ci = f" (95 % {lo * 1e3:.1f} .. {hi * 1e3:.1f} um)" if lo is not None else ""
    mm = f" = {f['value']:.2f} mm" if abs(f["value"]) >= 1.0 else ""  # not 7009.8 um alone
    return f"{f['value'] * 1e3:.1f} um{star}{mm}{ci}"


def answer_line(what: str, figures: dict) -> str:
    return f"flatness {what}: " + "; ".join(
        f"{name.split(' (')[0]} {value_text(figures[key])}" for key, name in FIGURES if key in figures)


def answer_lines(result: dict, provisional: bool = False, no_plate: str | None = None) -> list[str]:
    """The flatness lines of a result (touched points first, then the whole plate, then the raw
    spread and a note for any posterior median); ``no_plate``: what to say when there is no map."""
    mark = ", provisional" if provisional else ""
    lines, used = [], []
    touched = result.get("touched_flatness_mm")
    if touched:
        lines.append(answer_line(touched_what(touched["points"]) + mark, touched))
        used.append(touched)
    plate = result.get("flatness_mm")
    if plate:
        lines.append(answer_line(PLATE + mark, plate))
        used.append(plate)
        within = result.get("flatness_within_reach_mm")
        if within:
            lines.append(answer_line(within_what(within) + mark, within))
            used.append(within)
        if "range" in plate:
            lines.append(f"{SPREAD}: {value_text(plate['range'])}")
        lines.append(PLATE_CALIBRATION)
    elif no_plate:
        lines.append(f"flatness {PLATE}: {no_plate}")
    said = {f.get("value_is") for u in used for f in u.values() if isinstance(f, dict)}
    lines += [note for kind, note in ((MEDIAN, MEDIAN_NOTE), (OUTSIDE, OUTSIDE_NOTE))
              if kind in said]
    if plate:
        from adaptive_cal.analysis.local_features import feature_line

        lines += [feature_line(f) for f in result.get("local_features") or ()]
    if plate and result.get("largest_gap"):
        lines.append(gap_line(result["largest_gap"]))
    return lines
