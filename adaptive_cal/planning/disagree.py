"""Readings that agree neither with the map nor with each other, at one place: a survey that
cannot go on.

The gate retakes a reading it holds back; where the retake is held back too and differs from
the first by more than the noise the map assumes, neither is fused (``planning.gate``). Nothing
was learned, so the planner asks for the same place again. An outside audit (2026-12-01): with
``probe.noise_std_mm: 0.0001`` (0.1 um, the readings' true noise about 5 um) the first readings
fixed the plate's tilt to a fraction of a micron, the fifth touch was held back, and the same
point was gated and retaken 12 times over (24 touches) before a refit let one through; at 0.01
um the touch budget went with 4 readings fused and the map 1.3 mm off. ``DISAGREE_STOP`` such
rejected retakes in a row at one place (within ``PLACE_MM``; no reading fused in between) end
the survey as ``readings_disagree``, and ``text`` says what the readings there show: a spread
far above the noise the map assumes (a rejected pair differs by more than the gate's sigmas
times sqrt(2) of it: the noise stated too small, or a probe or plate that moves between
touches; in a survey from an earlier run's map, that map's noise).
"""
from __future__ import annotations

import math

import numpy as np

from adaptive_cal.planning.gate import Told

#: rejected retakes in a row at one place that end a survey
DISAGREE_STOP = 2
#: one place: the planner may move a touch from a rejected point by a millimetre or so (the
#: touches already made push it apart), and a second audit saw the count start afresh there
PLACE_MM = 5.0
READINGS_DISAGREE = "readings_disagree"


class Disagreements:
    """Counts, touch by touch, the readings held back at one place since the last fused one."""

    def __init__(self):
        self.heights_mm: list[float] = []
        self.rejected = 0
        self.where: tuple[float, float] | None = None  # (x, y) mm of the place

    def see(self, told: Told) -> bool:
        """Take one judged reading; True once ``DISAGREE_STOP`` retakes in a row at its place
        were rejected."""
        if told.fused:
            self.__init__()
            return False
        if self.where is None or math.hypot(told.x_mm - self.where[0],
                                            told.y_mm - self.where[1]) > PLACE_MM:
            self.__init__()
            self.where = (told.x_mm, told.y_mm)
        self.heights_mm.append(told.height_mm)
        self.rejected += "rejected" in told.flags
        return self.rejected >= DISAGREE_STOP

    def text(self, plan, state) -> str:
        """What the readings held back at the place show, in um (``plan``, ``state``: the
        survey's; its belief is the one they were judged by: nothing was fused since)."""
        x, y = self.where
        h = plan.model.surface.basis(np.array([x]), np.array([y]))[0]
        mean = float(h @ state.belief.mean)
        std = float(np.sqrt(max(h @ state.belief.cov @ h, 0.0)))
        heights = np.asarray(self.heights_mm)
        spread = float(np.std(heights, ddof=1)) if len(heights) > 1 else 0.0
        noise = float(np.sqrt(state.noise_var))
        said = (f"{len(heights)} readings at x {x:.1f}, y {y:.1f} mm (each touch retaken, "
                f"{self.rejected} retakes rejected) lie {abs(heights.mean() - mean) * 1e3:.1f} "
                f"um from where the map puts the plate (its std there {std * 1e3:.2g} um) and "
                f"spread {spread * 1e3:.2g} um among themselves, where the map assumes "
                f"{noise * 1e3:.2g} um of reading noise: ")
        if state.prior is not None:  # a survey from an earlier run's map: its noise, not ours
            return said + ("the map this survey started from (run --prior-from, start_survey's "
                           "prior) assumes a noise the readings do not have, or the plate has "
                           "changed: map from scratch in a new folder, or from a run whose "
                           "noise was learned from enough readings")
        return said + ("the readings are noisier than the map assumes -- the probe's noise "
                       "stated too small (probe.noise_std_mm is a first guess; the first "
                       "readings were taken as that precise), or a probe or plate that moves "
                       "between touches? State the probe's noise (probe.noise_std_mm, or "
                       "probe.noise_range_mm from its datasheet), check that the probe and "
                       "plate hold still, and map again in a new folder")
