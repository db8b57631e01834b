"""The closure touch: when a variance bound stops a run (or with two touches of the budget left,
where none did), the probe touches the run's first place again, and the readings are compared.
A cell that warms up (robot links, probe, plate) or otherwise drifts while it touches changes
every later reading by the same amount, whatever the plate; a map of touches each at a new place
cannot tell that from the plate's form (measured: docs/study-notes.md, "Drift during a run"),
but two readings at one place can: the plate is the same there, so their difference is noise
plus the drift between them.

Test. The start is the first k <= 3 unflagged readings within ``CLUSTER_MM`` of the first one
(the planner's start puts its second and third touches 4 and 8 mm from the first, seconds
later); the repeat is one reading at the first place, as the gate judged it (``repeats_to_judge``: a
retake that confirms a gated repeat is averaged in, m = 2; one that does not replaces it; a
gated repeat with no retake or a pair that disagrees is no test). A repeat of one reading that
fails the test is confirmed by one touch more at the place where the budget allows
(``run.loop``), and the test is made again on both: one misreading the gate let through
(Student-t tails, a gross error inside the gate's reach) no longer ends the run as a drift, and a
drift reads the same twice. d = mean(h_repeat) - mean(h_start) - a . mu, a = mean(repeat rows) -
mean(start rows): the heights' difference less the map's own difference between the places (0
for one place). Under the model (no drift) d ~ N(0, r (1/m + 1/k) + a C a), C the belief's
covariance, r the noise variance; d / sd is compared with Student-t, two-sided at ``ALPHA``, on
the degrees of freedom r rests on: the fused readings less what the map spent fitting them
(``residual_dof``, sum of w_i (1 - leverage_i)). Until 2026-11-24 that was n - 3, as if the map
were a plane; the simulated cell's runs of about 31 readings spend about 13 of them (median
18 degrees of freedom left), and an 11-reading run on an independent plate 7: at 8 um readings
it had read a 3.4 sd "drift" from a noise the map had learned at 4.9 um (docs/study-notes.md,
"Few degrees of freedom"). Far below the form's coefficient count (a 10-touch budget on 30
form coefficients: 1-2 left) only a drift far beyond the noise shows; a pass there says how large
one would have shown (``detectable_mm``, below ``FEW_DOF`` in the text).

Which r. The learned noise is a nugget: probe noise plus whatever the map cannot hold -- and a
drift the form cannot follow goes there, so it hides itself (on the simulated cell a 40 um
warm-up raised the learned noise from 5 to 11 um, and the closure then caught 19 of 30). Where
the noise is learned and every reading's time is known, r is relearned with the drift the
closure reads taken out of every reading, as a drift linear in time from the start to the
repeat (``run.loop``), and the test takes that refit's degrees of freedom: 30 of 30 caught. On
a cell that does not drift that changes r little: 400 runs of the simulated cell gave 2 false
alarms (0.5 %) at the 1 % level (docs/study-notes.md). Until 2026-11-24 this was done only
with at least as many readings as form coefficients: below that the refit's noise rests on the
prior and can collapse (5.2 -> 2.3 um on a 12-touch run, a false alarm on n - 3 degrees of
freedom); a collapsed noise is one the map's leverages have spent, and on the refit's residual
degrees of freedom the test does not fire on it.

A failed closure ends the run (``DRIFT``): more touches cannot undo a drift the model does not
have. The map carries it: each reading is off by the drift since the run began, between 0 and
about d for a drift that grows monotonically; the bands and the stop statistic add d^2
everywhere (a warm-up that settles early puts most of the run near d, so d^2 / 3 -- a linear
drift's RMS -- would under-state it: 20 against a true 31 um on 40 um warm-ups). What to do is
said with it: warm the cell up and map again, or let ``adaptive-cal explain`` model the drift
on the recording.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import special  # stdtr, stdtrit: scipy.stats.t's sf and isf, without loading it

from adaptive_cal.formats.numbers import fixed

ALPHA = 0.01  # false-alarm level of the two-sided test on a cell that does not drift
#: the loop's stop reason after a failed closure
DRIFT = "drift"
#: the flag a closure touch (and its retake) carries in the recording
FLAG = "closure"
FIRST_OF = 3  # the place revisited is the first unflagged reading among the first three fused
CLUSTER_MM = 20.0  # the start's readings within this of it stand for the start (averaged)
#: below these degrees of freedom the verdict says how large a drift it could have seen
FEW_DOF = 5.0


@dataclass(frozen=True)
class Closure:
    """The closure's verdict (mm, s): where, which touches (0-based row indices of the run's
    recording), how many start readings were averaged, the difference and its sd, the
    two-sided p, ``passed``; ``made`` False (with ``why``) when no repeat reading could be
    taken; ``noise_h0_mm``: the learned noise before the drift was taken out (None when the
    test used it as it was)."""

    made: bool
    x_mm: float = float("nan")
    y_mm: float = float("nan")
    first_touch: int = -1
    first_readings: int = 1
    repeat_touches: tuple[int, ...] = ()
    elapsed_s: float | None = None
    difference_mm: float = float("nan")
    sd_mm: float = float("nan")
    dof: float = 0.0  # 0: not given (a verdict built by hand); a judged one has at least 1
    p: float = float("nan")
    passed: bool = True
    why: str = ""
    noise_h0_mm: float | None = None  # the learned noise before the drift was taken out

    @property
    def drift_var_mm2(self) -> float:
        """d^2 after a failed closure (added to the map's variance everywhere), else 0."""
        return self.difference_mm**2 if self.made and not self.passed else 0.0

    @property
    def detectable_mm(self) -> float:
        """The smallest |d| (mm) this test would have called a drift: Student-t's two-sided
        ``ALPHA`` quantile on its degrees of freedom times sd (NaN when not made or the degrees
        of freedom are not given)."""
        if not self.made or self.dof < 1.0:
            return float("nan")
        return float(-special.stdtrit(self.dof, ALPHA / 2) * self.sd_mm)

    def text(self) -> str:
        """One line for the terminal and the report."""
        if not self.made and self.repeat_touches:
            seq = ", ".join(str(k) for k in self.repeat_touches)
            return (f"closure: the first place (x {self.x_mm:.1f}, y {self.y_mm:.1f} mm) touched "
                    f"again (seq {seq}) but not judged: {self.why}")
        if not self.made:
            return f"closure touch not made: {self.why}"
        # elapsed_s is on the recording's clock (its t_s column), from the first reading there
        # to the repeat: not result.json's robot_time_s, an estimate from travel and touch time
        when = (f", touched again {self.elapsed_s:.0f} s after its first reading on the "
                "recording's clock (t_s),") if self.elapsed_s is not None else ""
        start = (f"the run's first {self.first_readings} readings there"
                 if self.first_readings > 1 else "the run's first reading")
        head = (f"closure: the first place (x {self.x_mm:.1f}, y {self.y_mm:.1f} mm){when} read "
                f"{fixed(self.difference_mm * 1e3, 1, '+')} um against {start} (sd "
                f"{self.sd_mm * 1e3:.1f} um, p {self.p:.2g})")
        if self.passed and 1.0 <= self.dof < FEW_DOF:
            return (f"{head}: no drift seen, but the noise rests on {self.dof:.1f} degrees of "
                    "freedom (the readings less what the map spent fitting them): only a drift "
                    f"beyond about {self.detectable_mm * 1e3:.0f} um would have shown")
        if self.passed:
            return f"{head}: no drift seen"
        return (f"{head}: the cell drifted during the run; the map carries up to about "
                f"{abs(self.difference_mm) * 1e3:.1f} um of it (in the bands)"
                "; warm the cell up and map again, or model it: adaptive-cal explain on the "
                "recording")

    def as_dict(self) -> dict:
        out = asdict(self)
        out["repeat_touches"] = list(self.repeat_touches)
        out["drift_rms_mm"] = math.sqrt(self.drift_var_mm2)
        out["detectable_mm"] = self.detectable_mm
        out["level"] = ALPHA
        out["text"] = self.text()
        return out


def first_place(weights: np.ndarray) -> int | None:
    """Index (among the fused readings) of the reading to revisit: the first with its full
    weight (not flagged an outlier) among the first ``FIRST_OF``; None when there is none."""
    for i, w in enumerate(np.asarray(weights, float)[:FIRST_OF]):
        if w >= 1.0:
            return i
    return None


def start_cluster(weights: np.ndarray, xy_mm: np.ndarray, i: int) -> list[int]:
    """The fused readings that stand for the run's start: those among the first ``FIRST_OF``
    with their full weight within ``CLUSTER_MM`` of reading ``i`` (the planner's start puts
    its second and third touches a few mm from the first, seconds later)."""
    w = np.asarray(weights, float)
    xy = np.asarray(xy_mm, float)
    return [j for j in range(min(FIRST_OF, len(w)))
            if w[j] >= 1.0 and math.hypot(*(xy[j] - xy[i])) <= CLUSTER_MM]


def repeats_to_judge(told) -> tuple[list[int], str]:
    """Which of the closure's readings (its repeat and the retake the gate owed, each a
    ``gate.Told``) stand for the first place, as the gate decided them, and why none do:

    * the repeat passed the gate: it alone;
    * it was gated and its retake confirmed it (``surprise``: the surface really is there): both,
      averaged -- a drift larger than the gate moves both readings alike;
    * its retake was fused as the map expects, the repeat not confirmed: the retake alone (the
      repeat was a gross error; averaging it in read 25 um of "drift" from one 50 um misreading);
    * both rejected (they disagree with each other and the map), or the gated repeat with no
      retake (a budget with one touch left): none -- one reading judged an outlier cannot tell a
      drift from a misreading (a probe that misreads 5 % of the time ended a run as "drift",
      Not a result, on one gated reading at outlier p 1.00)."""
    if not told:
        return [], ("the probe cycle rejected the touch or its reading was invalid (see the "
                    "recording's flags)")
    if told[0].fused:
        return [0], ""
    if len(told) < 2:
        return [], ("its reading was gated (far from the map: a gross error or a drift) and the "
                    "touch budget left no retake to tell which; drift neither seen nor ruled out")
    if "surprise" in told[1].flags:
        return [0, 1], ""
    if told[1].fused:
        return [1], ""
    return [], ("its reading and the retake disagreed with each other and with the map (a "
                "gross error); drift neither seen nor ruled out")


def residual_dof(rows, weights, cov, noise_var_mm2: float) -> float:
    """The degrees of freedom the learned noise rests on: sum_i w_i (1 - l_i), the readings less
    what the map spent fitting them, l_i = w_i h_i C h_i / r the leverage of reading i (the
    map's variance there over the reading's own: the share of its value the fit kept; sum l_i
    is the map's effective number of parameters, trace of the hat matrix). A reading weighted
    out as a gross error (w ~ 0) adds nothing. At least 1."""
    rows = np.atleast_2d(np.asarray(rows, float))
    w = np.clip(np.asarray(weights, float), 0.0, 1.0)
    lev = np.clip(np.einsum("ij,jk,ik->i", rows, np.asarray(cov, float), rows) * w
                  / noise_var_mm2, 0.0, 1.0)
    return max(float(w @ (1.0 - lev)), 1.0)


def judge(first_rows, first_mm, repeat_rows, repeat_mm, mean, cov, noise_var_mm2: float,
          dof: float, **where) -> Closure:
    """The test (module docstring): ``first_rows``/``first_mm`` the basis rows and heights of
    the start's readings (k >= 1); ``repeat_rows``/``repeat_mm`` the repeat readings' (m >= 1);
    ``mean``/``cov`` the belief; ``noise_var_mm2`` r; ``dof`` the degrees of freedom r rests
    on (``residual_dof``). ``where``: the Closure's x_mm, y_mm, first_touch, repeat_touches,
    elapsed_s."""
    first_rows = np.atleast_2d(np.asarray(first_rows, float))
    first_mm = np.atleast_1d(np.asarray(first_mm, float))
    repeat_rows = np.atleast_2d(np.asarray(repeat_rows, float))
    repeat_mm = np.atleast_1d(np.asarray(repeat_mm, float))
    k, m = len(first_mm), len(repeat_mm)
    a = repeat_rows.mean(axis=0) - first_rows.mean(axis=0)
    d = float(repeat_mm.mean() - first_mm.mean() - a @ np.asarray(mean, float))
    sd = math.sqrt(noise_var_mm2 * (1.0 / m + 1.0 / k) + max(float(a @ cov @ a), 0.0))
    dof = max(float(dof), 1.0)
    p = float(2.0 * special.stdtr(dof, -abs(d) / sd)) if sd > 0 else (0.0 if d else 1.0)
    return Closure(True, difference_mm=d, sd_mm=sd, dof=dof, p=p, passed=p >= ALPHA,
                   first_readings=k, **where)
