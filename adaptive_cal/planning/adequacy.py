"""Is the spline adequate for the plate it maps? Self-checks on the fused readings, and the
variance of the structure the spline cannot represent (finer than its knot spacing).

The learned reading noise sigma_n is a nugget: probe noise plus whatever the bicubic spline on
its knots cannot follow. With the probe's stated noise span [lo, hi] (``probe.noise_range_mm``)
the probe's share is r_p = min(sigma_n, hi)^2; the rest is unresolved structure of the TRUE
plate, which the map's bands must carry. Checks (each at a stated level; ALPHA in all):

1. ``innovations``: the standardized innovations' mean square below its chi2(n) / n bound;
2. ``noise_span``: sigma_n <= hi (1 + z / sqrt(2 n)), its sampling error allowed (with a span);
3. ``loo``: closed-form leave-one-out residuals e_i standardized by the surface's LOO variance
   q_i plus r_p: their mean square below the chi2 bound;
4. ``regions``: the same per region of a grid over the plate (Bonferroni), which says *where*;
5. ``resolution``: the learned form (amplitude s_f, length scale l) has a part finer than the
   knots, f - P f (P: L2 projection onto the spline), whose variance is exact and closed form
   (``gaussian.checks.unresolved_form_var``); its RMS must stay below half the probe noise;
6. ``repeats`` (the learned noise suspect and enough readings repeats at their place,
   ``gaussian.checks.repeats``): sigma_n^2 over the repeats' pooled variance s_r^2 (dof d)
   below the F(n, d) upper alpha point (``planning.repeats.judged``: its level, the readings):
   repeats read the probe alone, so a learned noise well above them is plate structure the
   model missed. Where it fails, the unresolved variance is measured beyond s_r^2 instead;
7. ``halves``: the LOO mean square of one half of the plate over the other's, split along x
   and along y, below its F bound (``gaussian.checks.halves``): one side rough, one smooth.

Unresolved variance at a point: the projection variance of the learned form there, plus the
region's s_k^2 = max(0, mean_k(e_i^2 - q_i - r_p)) (unbiased for an extra white term), kept
only where a check 1-4 fails (else 0) -- except in a model that grew (``suspect``: the coarse
knots failed their checks, ``planning.survey.refit``), which keeps it in every region while
its checks pass (the plate's mean excess where a region has too few readings): the bands and
the stop statistic add it (``survey.status``); the stop never fires while a check fails. With
every check passing the bands still carry the form's finer part, and a grown model's excess.
The probe is the same wherever it touches: a half of the plate whose readings scatter beyond the
other's by more than chance allows at ALPHA_UNEVEN (``checks.uneven``) carries that excess in its
regions whether or not a check fails (a plate rough on its right half stopped at 20-54 touches,
every check passing, claiming 3.1-4.0 um against a true 7.4-10.3 um).

What the checks cannot see (``checks.unseen_rms``): structure finer than the touches' spacing looks
like noise. With a stated span [lo, hi] the probe may be as good as lo, so the learned noise can
take structure of RMS s with lo^2 + s^2 <= hi^2 unseen; beyond, the noise-span check fires at
hi (1 + z / sqrt(2 n)), and the leave-one-out check (r_p held at hi^2) at a mean excess of
(b - 1) / mean(1 / (q_i + hi^2)), b its chi2 bound. The smaller of the two is the size such
structure reaches before a check sees it: ``Adequacy.unseen_rms_mm``, in result.json and the
summary (the checks fire about a quarter of the time at that size, never at 0.7 x, mostly at
1.3 x: tests/test_adequacy.py). Without a span only repeat readings bound it: structure passes the
repeats check up to s^2 = (F - 1) s_r^2, F its bound; with neither, the noise takes all of it
(docs/plates.md: a 6 um ripple at a 30 mm period passed every check after 12 touches).

The map beyond the reachable box (the edge margin no touch can reach, ``reach_mm``) is an
extrapolation no check can test: ``extrapolated`` names it (result.json, the summary), with no
variance added (the form prior's Taylor remainder there is 0.02-0.1 um at 10 mm; edge roll-off
put 11-16 um RMS of error there, docs/plates.md): marked, not widened (``compensate`` refuses
or marks a cut there)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special  # fdtri, ndtri: scipy.stats's f.isf and norm.isf, without loading it

from adaptive_cal.gaussian import checks
from adaptive_cal.gaussian.places import positions_mm

ALPHA = 0.01  # false-alarm level of checks 1-6 on an adequate model (split below; 7: + 1/6)
ALPHA_UNEVEN = 0.05  # a half wider than the other beyond chance at 1.25 % a side widens its bands
MIN_READINGS = 3  # a region is tested with at least this many readings
NEGLIGIBLE_MM = 0.5e-3  # unresolved RMS below this is not reported (still in the stds)
SHOWN_REGIONS = 3  # the summary names this many regions, then says how many more
LOCAL = ("regions", "resolution")  # checks that fail in a region, not over the plate


@dataclass(frozen=True, eq=False)
class Adequacy:
    """The verdict: ``adequate``; ``checks`` (name -> dict with passed, value, bound);
    ``region_var_mm2`` (rx, ry) unresolved variance per region between ``edges_x_mm`` and
    ``edges_y_mm``; ``knot_spacing_mm``: the finest scale the spline resolves."""

    adequate: bool
    checks: dict
    region_var_mm2: np.ndarray
    edges_x_mm: np.ndarray
    edges_y_mm: np.ndarray
    knot_spacing_mm: float
    readings: np.ndarray  # (rx, ry) fused readings per region
    surface: object = None  # the spline, for the learned form's projection variance
    form: tuple = (0.0, 1.0, "se")  # learned (s_f mm, l mm, kernel)
    form_var_mm2: float = 0.0  # its plate mean
    plate_mm: tuple | None = None  # ((x0, x1), (y0, y1)) the workplane
    reach_mm: tuple | None = None  # ((x0, x1), (y0, y1)) the box touches can reach
    unseen_rms_mm: float | None = None  # structure that passes the checks (``unseen_rms``)
    noise_std_mm: float | None = None  # the learned reading noise the checks judged by
    repeat_dof: int = 0  # readings beyond the first at a place (``checks.repeats``)
    repeat_std_mm: float | None = None  # their pooled std: the probe's own noise
    map_knot_spacing_mm: float | None = None  # the map's, where the form lives on coarser knots
    grew: bool = False  # a grown model (``assess(suspect=True)``): its regions carry the excess
    uneven: dict | None = None  # the half that scatters beyond the other (``checks.uneven``)

    def unresolved_var_mm2(self, x_mm, y_mm) -> np.ndarray:
        """s_u^2 (mm^2) at points (x, y): the projection variance of the learned form there
        plus the region's variance."""
        x_mm, y_mm = np.asarray(x_mm, float), np.asarray(y_mm, float)
        return self._region_var(x_mm, y_mm) + (
            checks.unresolved_form_var(self.surface, *self.form[:2], x_mm, y_mm,
                                       kernel=self.form[2])[0]
            if self.form_var_mm2 > 0 else 0.0)

    def _region_var(self, x_mm, y_mm) -> np.ndarray:
        i = np.clip(np.searchsorted(self.edges_x_mm, x_mm, side="right") - 1, 0,
                    len(self.edges_x_mm) - 2)
        j = np.clip(np.searchsorted(self.edges_y_mm, y_mm, side="right") - 1, 0,
                    len(self.edges_y_mm) - 2)
        return self.region_var_mm2[i, j]

    @property
    def unresolved_rms_mm(self) -> float:
        """sqrt of the area-mean unresolved variance (regions are equal)."""
        return float(np.sqrt(self.region_var_mm2.mean() + self.form_var_mm2))

    def where(self) -> list[dict]:
        """The regions with unresolved structure, largest first."""
        out = []
        total = self.region_var_mm2 + self.form_var_mm2
        for i, j in zip(*np.nonzero(total >= NEGLIGIBLE_MM**2)):
            out.append({"x_mm": [float(self.edges_x_mm[i]), float(self.edges_x_mm[i + 1])],
                        "y_mm": [float(self.edges_y_mm[j]), float(self.edges_y_mm[j + 1])],
                        "unresolved_rms_mm": float(np.sqrt(total[i, j])),
                        "readings": int(self.readings[i, j])})
        return sorted(out, key=lambda w: -w["unresolved_rms_mm"])

    def extrapolated(self) -> dict | None:
        """The part of the workplane outside the reachable box, or None when touches reach the
        whole plate: ``margin_mm`` [left, right, bottom, top] (how far the map extrapolates
        beyond the last point a touch can reach), ``share`` of the plate's area, and a line."""
        if self.plate_mm is None or self.reach_mm is None:
            return None
        (x0, x1), (y0, y1) = self.plate_mm
        (a0, a1), (b0, b1) = self.reach_mm
        margin = [max(0.0, a0 - x0), max(0.0, x1 - a1), max(0.0, b0 - y0), max(0.0, y1 - b1)]
        inner = max(0.0, min(a1, x1) - max(a0, x0)) * max(0.0, min(b1, y1) - max(b0, y0))
        share = 1.0 - inner / ((x1 - x0) * (y1 - y0))
        if share <= 0.0:
            return None
        text = (f"the map within {max(margin):.0f} mm of the workplane's edge "
                f"({100 * share:.0f} % of the plate) is extrapolated: no touch can reach it "
                "and no check tests it")
        return {"margin_mm": margin, "share": share, "text": text}

    def summary(self) -> str:
        """One line: adequate, or why not and where the map should not be trusted (the
        unresolved structure, then the unreachable margin)."""
        out = self._summary()
        ext = self.extrapolated()
        return out if ext is None else f"{out}; {ext['text']}"

    def _summary(self) -> str:
        if self.adequate and self.unresolved_rms_mm < NEGLIGIBLE_MM:
            return ("model adequate: the readings agree with the spline and the probe's noise"
                    f"{self._noise()}; {self._unseen()}")
        knots, m = f"{self.knot_spacing_mm:.0f} mm", self.map_knot_spacing_mm
        mapped = f" (the form's knots; the map's are {m:.0f} mm)" if m and m < (
            self.knot_spacing_mm - 0.5) else ""  # a grown model's form lives on coarser knots
        if not self.adequate:
            failed = ", ".join(k for k, c in self.checks.items() if not c["passed"])
            parts = [f"model inadequate ({failed}{self._noise()}): structure finer than {knots}"
                     f"{mapped}, about {self.unresolved_rms_mm * 1e3:.1f} um RMS unresolved"]
        else:  # the caveat of an adequate model holds here too (an outside audit: it was left out)
            parts = [f"model checks pass; bands widened by about {self.unresolved_rms_mm * 1e3:.1f}"
                     f" um RMS: {self._widened_by(knots, mapped)}",
                     self._unseen()]
        where, rms = self.where(), [w["unresolved_rms_mm"] for w in self.where()]
        if len(where) == self.region_var_mm2.size > 1 and max(rms) - min(rms) <= 0.01 * max(rms):
            where, parts[0] = [], parts[0] + " over the whole plate alike"  # not 3 regions of 9
        for w in where[:SHOWN_REGIONS]:
            parts.append(f"x {w['x_mm'][0]:.0f}..{w['x_mm'][1]:.0f} mm, y {w['y_mm'][0]:.0f}.."
                         f"{w['y_mm'][1]:.0f} mm: {w['unresolved_rms_mm'] * 1e3:.1f} um")
        if len(where) > SHOWN_REGIONS:
            more = len(where) - SHOWN_REGIONS
            parts[-1] += f" (and {more} more region{'s' * (more != 1)})"
        return "; ".join(parts)

    def _unseen(self) -> str:  # what no check sees: structure finer than the touches' spacing
        if self.unseen_rms_mm is None:
            return ("structure finer than the touches' spacing cannot be told from that noise (no "
                    "probe.noise_range_mm stated)")
        room = "the stated span leaves" if "noise_span" in self.checks else "its repeats leave"
        size = f"{self.unseen_rms_mm * 1e3:.1f} um RMS"
        return f"structure finer than the touches' spacing up to about {size} would pass these " \
            f"checks ({room} room for it)"

    def _noise(self) -> str:
        """" (learned noise 9.4 um; 12 repeat readings: the probe 5.1 um)", or "" unknown."""
        if self.noise_std_mm is None:
            return ""
        out = f" (learned noise {self.noise_std_mm * 1e3:.1f} um"
        if self.repeat_dof and self.repeat_std_mm is not None:
            out += (f"; {self.repeat_dof} repeat reading{'s' * (self.repeat_dof != 1)}: the "
                    f"probe {self.repeat_std_mm * 1e3:.1f} um")
        return out + ")"

    def _widened_by(self, knots: str, mapped: str = "") -> str:
        """What widens the bands of a model whose checks all pass (module docstring): the
        learned form's part finer than the knots (always in the bands), and, only in a model
        that grew (the coarse knots failed their checks: ``assess(suspect=True)``; else a
        region's variance is 0 while every check passes), the readings' leave-one-out excess
        over the model's own spread, carried as structure finer than the refined knots."""
        out = []
        grown = float(np.sqrt(self.region_var_mm2.mean())) if self.grew else 0.0
        form = float(np.sqrt(self.form_var_mm2))
        if self.uneven is not None:
            out.append(f"the readings on {self.uneven['half']} scatter beyond the other half's by "
                       f"about {self.uneven['rms_mm'] * 1e3:.1f} um RMS more than chance allows: "
                       "the probe is the same everywhere, so it is carried there as plate "
                       "structure the knots do not resolve")
        if grown > 0.0:
            out.append(f"the coarse knots failed their checks, so the model grew {knots} knots "
                       f"and carries the readings' scatter beyond the model and the probe noise, "
                       f"about {grown * 1e3:.1f} um RMS (the plate's mean where a region has "
                       f"fewer than {MIN_READINGS} readings), as structure finer than them")
        if form >= NEGLIGIBLE_MM or not out:
            out.append(f"the learned form's part finer than the {knots} knots{mapped}, about "
                       f"{form * 1e3:.1f} um RMS")
        return "; ".join(out)

    def as_dict(self) -> dict:
        return {"adequate": self.adequate, "checks": self.checks,
                "unresolved_rms_mm": self.unresolved_rms_mm, "where": self.where(),
                "finer_than_mm": self.knot_spacing_mm, "unseen_rms_mm": self.unseen_rms_mm,
                "noise_std_mm": self.noise_std_mm, "uneven": self.uneven,
                "repeats": {"dof": self.repeat_dof, "std_mm": self.repeat_std_mm},
                "extrapolated": self.extrapolated(),
                "summary": self.summary()}


def assess(surface, plate_mm, rows, readings, prior, hyper, noise_range_mm=None,
           regions: tuple[int, int] = (3, 3), form_surface=None, suspect: bool = False,
           reach_mm=None, weights=None, repeats: tuple[float, int] | None = None) -> Adequacy:
    """Checks of the readings (heights y at basis ``rows`` of ``surface``) against the Gaussian
    ``prior`` belief under ``hyper`` (the learned form and noise); ``noise_range_mm``: the
    probe's stated span [lo, hi] or None; ``regions``: the grid the plate is split into;
    ``form_surface``: the spline the form can follow (default ``surface``); ``suspect``: the
    plate is known to have structure finer than the coarse knots (a grown model): then the
    learned noise beyond the span's centre sqrt(lo hi) counts as unresolved structure, not as
    probe noise (the readings alone cannot split the two); ``reach_mm``: the box touches can
    reach (the workplane less its edge margin), for ``Adequacy.extrapolated``; ``weights``:
    each reading's share w = 1 - p of the noise precision, as it was fused (the outlier
    mixture, ``planning.gate``): the checks judge reading i with noise r / w_i, the model the
    belief holds, so a reading the fusion trusted less does not count as structure in full;
    ``repeats``: (level alpha, repeat readings needed), ``repeats.judged``'s: judge the learned
    noise against readings repeated at one place (run where the learned noise exceeds what the
    cell says of its probe, ``planning.repeats``; a place read twice by chance asks nothing)."""
    form_surface = form_surface or surface
    n = len(readings)
    noise_std_mm = hyper.noise_std_mm
    inv_w = 1.0 / np.clip(np.ones(n) if weights is None else np.asarray(weights, float),
                          1e-9, 1.0)
    r = noise_std_mm**2 * inv_w
    r_p = (min(noise_std_mm, noise_range_mm[1]) ** 2 if noise_range_mm is not None
           else noise_std_mm**2)
    r_mag = r_p  # the probe noise the unresolved variance is measured beyond
    if suspect and noise_range_mm is not None:
        r_mag = min(r_p, noise_range_mm[0] * noise_range_mm[1])
    r_p0 = r_p  # the probe's share, for a reading fused with full weight
    xy = positions_mm(surface, rows)
    rep_dof, rep_var = checks.repeats(xy, readings, 1.0 / inv_w) if repeats else (0, np.nan)
    rep_dof = rep_dof if repeats and rep_dof >= repeats[1] else 0
    rep_bound = float(special.fdtri(n, rep_dof, 1.0 - repeats[0])) if rep_dof else np.inf
    # a repeat reading's own resolution floor: identical readings are not a noise of 0
    rep_ratio = noise_std_mm**2 / max(rep_var, 1e-14) if rep_dof else 0.0
    if rep_ratio > rep_bound:  # the learned noise holds structure: measure beyond the probe's
        r_mag = min(r_mag, rep_var)
    r_p, r_mag = r_p * inv_w, r_mag * inv_w
    ex = np.linspace(*plate_mm[0], regions[0] + 1)
    ey = np.linspace(*plate_mm[1], regions[1] + 1)
    spacing = form_surface.knot_interval_mm
    nreg = regions[0] * regions[1]
    a_glob, a_reg = ALPHA / 6, ALPHA / 2 / nreg  # innovations, noise, loo, halves: each
    ms_z = checks.innovations_mean_square(rows, readings, prior.mean, prior.cov, r)
    loo = checks.leave_one_out(rows, readings, prior.mean, prior.cov, r)
    q = np.maximum(loo.variance_mm2 - r, 0.0)
    e2 = loo.residual_mm**2
    form = (hyper.form_std_mm, hyper.length_scale_mm, hyper.kernel)
    form_pts, form_var = checks.unresolved_form_var(form_surface, *form[:2], xy[:, 0], xy[:, 1],
                                                    kernel=hyper.kernel)
    excess = e2 - q - r_mag - form_pts  # beyond the probe noise and the form's finer part
    stdz = e2 / (q + r_p)
    result = {
        "innovations": {"value": ms_z, "bound": checks.mean_square_upper(n, a_glob),
                        "is": "mean square of standardized innovations"},
        "loo": {"value": float(np.mean(stdz)), "bound": checks.mean_square_upper(n, a_glob),
                "is": "mean square of standardized leave-one-out residuals"},
        "halves": {"value": checks.halves(xy, stdz, plate_mm, a_glob), "bound": 1.0,
                   "is": "LOO mean square of one half of the plate over the other's, over "
                         "its F bound (the larger of the splits along x and y)"},
    }
    if noise_range_mm is not None:
        # sigma_n from n readings has a relative std of about 1 / sqrt(2 n)
        slack = 1.0 + float(-special.ndtri(a_glob)) / np.sqrt(2.0 * n)
        result["noise_span"] = {"value": noise_std_mm, "bound": float(noise_range_mm[1]) * slack,
                                "is": "learned noise std (mm) against the probe's stated high, "
                                      "with its sampling error"}
    if rep_dof:
        result["repeats"] = {"value": rep_ratio, "bound": rep_bound,
                             "is": "learned noise variance over that of repeat readings at one "
                                   "place"}
    i = np.clip(np.searchsorted(ex, xy[:, 0], side="right") - 1, 0, regions[0] - 1)
    j = np.clip(np.searchsorted(ey, xy[:, 1], side="right") - 1, 0, regions[1] - 1)
    counts = np.zeros(regions, int)
    var = np.zeros(regions)
    flagged = np.zeros(regions, bool)
    worst = 0.0
    for a in range(regions[0]):
        for b in range(regions[1]):
            sel = (i == a) & (j == b)
            counts[a, b] = sel.sum()
            if counts[a, b] < MIN_READINGS:
                continue
            ms = float(stdz[sel].mean())
            flagged[a, b] = ms > checks.mean_square_upper(int(counts[a, b]), a_reg)
            worst = max(worst, ms / checks.mean_square_upper(int(counts[a, b]), a_reg))
            var[a, b] = max(0.0, float(excess[sel].mean()))
    result["regions"] = {"value": worst, "bound": 1.0,
                         "is": "largest regional LOO mean square over its chi2 bound"}
    result["resolution"] = {"value": float(np.sqrt(form_var)), "bound": 0.5 * np.sqrt(r_p0),
                            "is": "RMS (mm) of the learned form finer than the knots"}
    for c in result.values():
        c["passed"] = bool(c["value"] <= c["bound"])
    adequate = all(c["passed"] for c in result.values())
    global_fail = not all(c["passed"] for k, c in result.items() if k not in LOCAL)
    if suspect:
        var = np.where(counts >= MIN_READINGS, var, max(0.0, float(excess.mean())))
    elif all(result[k]["passed"] for k in result if k != "resolution"):
        var[:] = 0.0
    else:
        thin = counts < MIN_READINGS
        var[thin] = max(0.0, float(excess.mean()))  # too few readings: the plate's mean
        if not global_fail:
            var[~flagged & ~thin] = 0.0
    t = inv_w < 2.0  # a reading the fusion judged more likely gross than not is no scatter
    u_var, u_axis, u_side = checks.uneven(xy[t], stdz[t], (q + r_p)[t], plate_mm, ALPHA_UNEVEN)
    var = np.maximum(var, u_var * checks.half_share(ex, ey, plate_mm, u_axis, u_side))
    uneven = {"half": checks.half_name(plate_mm, u_axis, u_side),
              "rms_mm": u_var**0.5} if u_var else None
    return Adequacy(adequate, result, var, ex, ey, spacing, counts, form_surface, form, form_var,
                    plate_mm=tuple(map(tuple, plate_mm)),
                    reach_mm=None if reach_mm is None else tuple(map(tuple, reach_mm)),
                    unseen_rms_mm=checks.unseen_rms(result, q, noise_range_mm, rep_var),
                    noise_std_mm=float(noise_std_mm), repeat_dof=rep_dof,
                    repeat_std_mm=float(np.sqrt(rep_var)) if rep_dof else None,
                    map_knot_spacing_mm=surface.knot_interval_mm, grew=bool(suspect),
                    uneven=uneven)

