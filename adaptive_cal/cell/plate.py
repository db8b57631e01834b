"""The plate's geometry in a cell file: intervals, rectangles (keep-outs) and the workplane
(``cell.schema`` holds the rest of the cell and re-exports these)."""
from __future__ import annotations

import math

import numpy as np
from pydantic import Field, field_validator, model_validator

from adaptive_cal.cell.block import Block

Interval = tuple[float, float]
REACH_MM = 1e5  # no coordinate of a cell lies farther than 100 m from the workplane origin


def _interval(v: Interval, what: str) -> Interval:
    lo, hi = v
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        raise ValueError(f"{what} must be [low, high] with low < high, got [{lo}, {hi}] mm")
    if max(abs(lo), abs(hi)) > REACH_MM:
        raise ValueError(f"{what}=[{lo}, {hi}] mm lies beyond +-{REACH_MM:.0f} mm (100 m): "
                         "not a robot cell")
    return v


class Rect(Block):
    """An axis-aligned rectangle in the workplane (mm)."""

    x_mm: Interval = Field(description="[low, high] in x")
    y_mm: Interval = Field(description="[low, high] in y")

    @field_validator("x_mm", "y_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    def contains(self, x: float, y: float) -> bool:
        return self.x_mm[0] <= x <= self.x_mm[1] and self.y_mm[0] <= y <= self.y_mm[1]


def _left_free(inner: "Rect", keep_outs) -> bool:
    """Whether some point of ``inner`` lies outside every keep-out: the cells between all the
    rectangles' edges are each wholly in or wholly out of every one, so their midpoints decide."""
    def mids(lo, hi, edges):
        v = sorted({lo, hi} | {e for e in edges if lo < e < hi})
        return [0.5 * (a + b) for a, b in zip(v, v[1:])] or [lo]

    xs = mids(*inner.x_mm, [e for k in keep_outs for e in k.x_mm])
    ys = mids(*inner.y_mm, [e for k in keep_outs for e in k.y_mm])
    return any(not any(k.contains(x, y) for k in keep_outs) for x in xs for y in ys)


class Workplane(Block):
    """The plate to map: its extent, an edge margin no touch goes inside, and keep-outs."""

    x_mm: Interval = Field(description="[low, high]: the plate's extent in x, workplane frame")
    y_mm: Interval = Field(description="[low, high]: the plate's extent in y")
    edge_margin_mm: float = Field(5.0, ge=0, description="no touch closer than this to the plate edge")
    keep_outs: list[Rect] = Field([], description="rectangles never touched (clamps, holes); "
                                "each must overlap the workplane; the probe tip's centre stays "
                                "outside, so give each its clearance: the stylus radius and the "
                                "robot's accuracy added on every side")

    @field_validator("x_mm", "y_mm")
    @classmethod
    def _ordered(cls, v, info):
        return _interval(v, info.field_name)

    @model_validator(mode="after")
    def _usable(self):
        m = self.edge_margin_mm
        if 2 * m >= self.x_mm[1] - self.x_mm[0] or 2 * m >= self.y_mm[1] - self.y_mm[0]:
            raise ValueError(f"edge_margin_mm={m} mm leaves no plate to touch inside "
                             f"x_mm={list(self.x_mm)}, y_mm={list(self.y_mm)} mm")
        inner = Rect(x_mm=(self.x_mm[0] + m, self.x_mm[1] - m),
                     y_mm=(self.y_mm[0] + m, self.y_mm[1] - m))
        for i, k in enumerate(self.keep_outs):
            if (k.x_mm[0] <= inner.x_mm[0] and k.x_mm[1] >= inner.x_mm[1]
                    and k.y_mm[0] <= inner.y_mm[0] and k.y_mm[1] >= inner.y_mm[1]):
                raise ValueError(f"keep_outs[{i}] x_mm={list(k.x_mm)} y_mm={list(k.y_mm)} covers "
                                 "the whole plate: nothing is left to touch")
            if (k.x_mm[1] < self.x_mm[0] or k.x_mm[0] > self.x_mm[1]
                    or k.y_mm[1] < self.y_mm[0] or k.y_mm[0] > self.y_mm[1]):
                # touches only land on the plate: such a keep-out protects nothing -- most likely
                # a clamp given in another frame or unit, which the probe would then hit
                raise ValueError(f"keep_outs[{i}] x_mm={list(k.x_mm)} y_mm={list(k.y_mm)} lies "
                                 f"wholly outside the workplane x_mm={list(self.x_mm)}, "
                                 f"y_mm={list(self.y_mm)}: it keeps nothing out (keep-outs are "
                                 "in the workplane frame, mm); move it onto the plate or delete it")
        if self.keep_outs and not _left_free(inner, self.keep_outs):
            raise ValueError(f"keep_outs cover the whole plate together (x {list(inner.x_mm)}, "
                             f"y {list(inner.y_mm)} mm inside the edge margin): nothing is left "
                             "to touch; shrink or delete some of them")
        return self

    @property
    def reach_mm(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The box touches can reach, ((x0, x1), (y0, y1)) mm: the plate less its edge margin.
        Beyond it a map is an extrapolation."""
        m = self.edge_margin_mm
        return (self.x_mm[0] + m, self.x_mm[1] - m), (self.y_mm[0] + m, self.y_mm[1] - m)

    @property
    def area_mm2(self) -> float:
        return (self.x_mm[1] - self.x_mm[0]) * (self.y_mm[1] - self.y_mm[0])

    def first_outside(self, x, y) -> tuple[str, int, int] | None:
        """Of the points (x, y) (arrays, mm), the first one outside the plate's extent (round-off
        of 1e-9 mm allowed): (its column "x_mm" or "y_mm", its index, how many lie outside in
        that column), or None when the plate holds them all. The check replay and explain make
        before they use a recording's touches."""
        for c, values, (lo, hi) in (("x_mm", x, self.x_mm), ("y_mm", y, self.y_mm)):
            values = np.asarray(values, float)
            bad = np.flatnonzero((values < lo - 1e-9) | (values > hi + 1e-9))
            if bad.size:
                return c, int(bad[0]), int(bad.size)
        return None

    def allows(self, x: float, y: float) -> bool:
        """True if (x, y) lies inside the margin and outside every keep-out (``allowed``)."""
        return bool(self.allowed(x, y))

    def allowed(self, x, y) -> np.ndarray:
        """Of the points (x, y) (arrays, or numbers), which lie inside the margin and outside
        every keep-out (edges included in both): a boolean array of the shape of x and y."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        m = self.edge_margin_mm
        ok = ((self.x_mm[0] + m <= x) & (x <= self.x_mm[1] - m)
              & (self.y_mm[0] + m <= y) & (y <= self.y_mm[1] - m))
        for k in self.keep_outs:
            ok &= ~((k.x_mm[0] <= x) & (x <= k.x_mm[1]) & (k.y_mm[0] <= y) & (y <= k.y_mm[1]))
        return ok

    def kept_out(self, x: float, y: float) -> bool:
        """True if (x, y) lies inside a keep-out (the edge margin aside: a clamp at the edge
        lies in it)."""
        return any(k.contains(x, y) for k in self.keep_outs)
