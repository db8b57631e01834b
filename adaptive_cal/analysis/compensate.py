"""A height map applied to a toolpath: pure maths on ``formats.toolpath`` moves and a callable
``height(x_mm, y_mm) -> (mean_mm, std_mm)``.

Cutting moves (G1, CSV rows): every point's Z is raised by the mapped height there. A move is
sampled densely (at most ``sample_mm`` apart, its ends included) and split by bisection at those
samples until, at every sample, the straight output between two kept points departs from the
mapped surface by at most the budget left by the map's own uncertainty, ``T - band`` (band: the
95 % half-width Z95 x std), so that path error + map error stays within T. Where the band itself
exceeds T the move is reported in ``wide`` (the caller refuses, or marks it; a marked move is
split to T against the map alone). Where a cut leaves ``reach_mm``, the box touches can reach
(the workplane less its edge margin), it is reported in ``beyond``, refused or marked the same
way: the map there is an extrapolation no reading tested (``planning.adequacy``: on plates whose
edges roll off, the run's bands held the truth at 0.35 of the margin's points), so no tolerance
can be promised there, however narrow the band. A cut over one of ``keep_outs`` (a clamp or a
fixture: never touched, the map there rests on touches beside it) is reported in ``under``,
refused or marked alike (an outside audit: a cut through the clamp was compensated in silence).

Rapids (G0) are not checked against the band: each end point is raised by the mapped height
there (a clearance programmed above the nominal plane stays a clearance above the plate at the
rapid's ends), or by ``top_mm`` (the highest mapped height) while X or Y is not known yet. A
level rapid (X, Y only) the raise would tilt is written as two: across at the higher end's Z,
and the Z change on its own, first when rising, last when descending (a control may move a
rapid's axes each at its own speed). ``rapid_dip_mm``: the most the plate rises above the
rapids' travel between their raised ends, the most any programmed clearance shrinks.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from adaptive_cal.formats.toolpath import Move, Toolpath, ToolpathError
from adaptive_cal.gaussian.belief import Z95

Height = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
SAMPLE_MM = 0.5  # dense check samples along a move at most this far apart
EDGE_MM = 1e-9  # a point this close outside the plate counts as on its edge


@dataclass(frozen=True)
class Wide:
    """Where a move's 95 % band exceeds the tolerance: its worst sample."""

    line: int
    x_mm: float
    y_mm: float
    band_mm: float


@dataclass(frozen=True)
class Beyond:
    """Where a cut leaves the box touches can reach: its sample furthest outside."""

    line: int
    x_mm: float
    y_mm: float
    outside_mm: float  # how far beyond the reachable box


@dataclass(frozen=True)
class Under:
    """Where a cut passes over a keep-out: its first sample there, and which keep-out."""

    line: int
    x_mm: float
    y_mm: float
    index: int


@dataclass
class Compensated:
    """``pieces``: item -> output points (x, y, z) mm, the last the move's end; ``wide``: moves
    whose band exceeds T; ``beyond``: cuts that leave the reachable box; ``added``: points
    inserted by splitting; ``max_deviation_mm``: the
    largest departure of the output from the mapped surface at the check samples;
    ``rapid_dip_mm``: see the module's doc."""

    pieces: dict = field(default_factory=dict)
    wide: list = field(default_factory=list)
    beyond: list = field(default_factory=list)
    under: list = field(default_factory=list)
    added: int = 0
    max_deviation_mm: float = 0.0
    rapid_dip_mm: float = 0.0
    cuts: int = 0
    rapids: int = 0


def samples(length_mm: float, sample_mm: float = SAMPLE_MM) -> np.ndarray:
    """Parameters 0 .. 1 of check samples along a move of ``length_mm``, ``sample_mm`` apart
    at most (ends included)."""
    n = max(int(np.ceil(length_mm / sample_mm)), 1)
    return np.linspace(0.0, 1.0, n + 1)


def bisect(surface_mm: np.ndarray, limit_mm: np.ndarray) -> list[int]:
    """Indices of the samples kept (first and last included): an interval [i, j] is kept when
    the chord from sample i to sample j departs from ``surface_mm`` by at most ``limit_mm`` at
    every sample between; else it is split at its middle sample."""
    kept, stack = [0], [(0, len(surface_mm) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i > 1:
            t = np.linspace(0.0, 1.0, j - i + 1)[1:-1]
            chord = surface_mm[i] + t * (surface_mm[j] - surface_mm[i])
            if np.any(np.abs(chord - surface_mm[i + 1:j]) > limit_mm[i + 1:j]):
                m = (i + j) // 2
                stack += [(m, j), (i, m)]  # left half first
                continue
        kept.append(j)
    return kept


def deviation(t: np.ndarray, z_out_mm: np.ndarray, z_prog_mm: np.ndarray, mean_mm: np.ndarray,
              kept: list[int]) -> np.ndarray:
    """|output - (programmed + mapped)| at each sample t (the move's parameter), the output
    straight between the kept samples."""
    return np.abs(np.interp(t, t[kept], z_out_mm) - z_prog_mm - mean_mm)


def _inside(plate_mm, x: float, y: float) -> bool:
    (x0, x1), (y0, y1) = plate_mm
    return x0 - EDGE_MM <= x <= x1 + EDGE_MM and y0 - EDGE_MM <= y <= y1 + EDGE_MM


def _check_inside(path_name: str, plate_mm, move: Move, *points) -> None:
    for p in points:
        if p is not None and p[0] is not None and p[1] is not None and not _inside(plate_mm, p[0], p[1]):
            (x0, x1), (y0, y1) = plate_mm
            raise ToolpathError(
                f"{path_name} line {move.line}: ({p[0]:g}, {p[1]:g}) mm is outside the mapped "
                f"workplane x [{x0:g}, {x1:g}] mm, y [{y0:g}, {y1:g}] mm")


def outside_mm(reach_mm, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """How far each point (x, y) lies outside the box ``reach_mm`` ((x0, x1), (y0, y1)), mm
    (0 inside or on its edge)."""
    (x0, x1), (y0, y1) = reach_mm
    dx = np.maximum(np.maximum(x0 - x, x - x1), 0.0)
    dy = np.maximum(np.maximum(y0 - y, y - y1), 0.0)
    return np.hypot(dx, dy)


def compensate(path: Toolpath, height: Height, plate_mm, tolerance_mm: float, *,
               top_mm: float, sample_mm: float = SAMPLE_MM, name: str = "program",
               reach_mm=None, keep_outs=()) -> Compensated:
    """The output points of every move of ``path`` (see the module's doc). Refuses
    (``ToolpathError``) a point outside ``plate_mm`` and a cut whose start is not known.
    ``reach_mm``: the box touches can reach, or None (the whole plate was reachable);
    ``keep_outs``: ((x0, x1), (y0, y1)) each."""
    if not tolerance_mm > 0:
        raise ValueError(f"tolerance {tolerance_mm} mm must be positive")
    out = Compensated()
    for move in path.moves:
        _check_inside(name, plate_mm, move, move.end, move.start)
        if move.cut:
            _cut(out, move, height, tolerance_mm, sample_mm, name, reach_mm, keep_outs)
        else:
            _rapid(out, move, height, top_mm, sample_mm)
    return out


def _cut(out: Compensated, move: Move, height: Height, tol: float, sample_mm: float,
         name: str, reach_mm=None, keep_outs=()) -> None:
    out.cuts += 1
    end = np.array(move.end, float) if None not in move.end else None
    if end is None:
        raise ToolpathError(f"{name} line {move.line}: a cutting move (G1) to a point whose X, Y "
                            "or Z is not known yet: give X, Y and Z in full first (a G0)")
    if move.start is None:
        start = end  # a CSV's first point: a point, not a segment
    elif None in move.start:
        raise ToolpathError(f"{name} line {move.line}: a cutting move (G1) from a point whose X, "
                            "Y or Z is not known yet: move there first with a G0 giving X, Y and Z")
    else:
        start = np.array(move.start, float)
    t = samples(float(np.hypot(*(end - start)[:2])), sample_mm)
    pts = start + t[:, None] * (end - start)
    mean, std = (np.asarray(a, float) for a in height(pts[:, 0], pts[:, 1]))
    band = Z95 * std
    worst = int(np.argmax(band))
    if band[worst] > tol:
        out.wide.append(Wide(move.line, float(pts[worst, 0]), float(pts[worst, 1]),
                             float(band[worst])))
    if reach_mm is not None:
        far = outside_mm(reach_mm, pts[:, 0], pts[:, 1])
        k = int(np.argmax(far))
        if far[k] > EDGE_MM:
            out.beyond.append(Beyond(move.line, float(pts[k, 0]), float(pts[k, 1]),
                                     float(far[k])))
    for i, ((x0, x1), (y0, y1)) in enumerate(keep_outs):
        over = np.flatnonzero((pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0)
                              & (pts[:, 1] < y1))
        if over.size:
            out.under.append(Under(move.line, float(pts[over[0], 0]), float(pts[over[0], 1]), i))
    limit = np.where(band <= tol, tol - band, tol)
    surface = pts[:, 2] + mean
    kept = bisect(surface, limit)
    z_out = surface[kept]
    dev = deviation(t, z_out, pts[:, 2], mean, kept)
    out.max_deviation_mm = max(out.max_deviation_mm, float(dev.max()))
    keep = kept[1:] if len(kept) > 1 else kept
    out.pieces[move.item] = [(float(pts[k, 0]), float(pts[k, 1]), float(surface[k])) for k in keep]
    out.added += len(keep) - 1


def _raise_at(height: Height, p, top_mm: float):
    if p[0] is None or p[1] is None:
        return top_mm
    return float(np.asarray(height(np.array([p[0]]), np.array([p[1]]))[0])[0])


def _rapid(out: Compensated, move: Move, height: Height, top_mm: float, sample_mm: float) -> None:
    out.rapids += 1
    x, y, z = move.end
    if z is None:
        return  # Z never given: the line stays as written
    h1 = _raise_at(height, move.end, top_mm)
    out.pieces[move.item] = [(x, y, z + h1)]
    if move.start is None or move.start[2] is None or None in (x, y):
        return
    h0 = _raise_at(height, move.start, top_mm)
    if None in move.start[:2]:  # from somewhere not known, raised by top_mm: across first
        if move.start[2] == z and h1 < h0:
            out.pieces[move.item] = [(x, y, z + h0), (x, y, z + h1)]
        return
    a, b = np.array(move.start[:2], float), np.array([x, y], float)
    t = samples(float(np.hypot(*(b - a))), sample_mm)
    xy = a + t[:, None] * (b - a)
    mean = np.asarray(height(xy[:, 0], xy[:, 1])[0], float)
    if move.start[2] == z and np.any(a != b) and h0 != h1:
        # a level rapid the map would tilt: across in X, Y at the higher end's Z, and up or down
        # on its own (a control may move each axis of a rapid at its own speed: Z done first,
        # a descending rapid ran 0.5 mm into the plate of an outside audit's program)
        up = max(h0, h1)
        out.pieces[move.item] = ([(x, y, z + h0), (x, y, z + h1)] if h1 < h0 else
                                 [(a[0], a[1], z + h1), (x, y, z + h1)])
        out.rapid_dip_mm = max(out.rapid_dip_mm, float(np.max(mean - up)))
        return
    out.rapid_dip_mm = max(out.rapid_dip_mm, float(np.max(mean - (h0 + t * (h1 - h0)))))


def under_text(u: Under, keep_outs) -> str:
    """``keep_outs[i] (x a..b, y c..d mm)`` of a cut over it."""
    (x0, x1), (y0, y1) = keep_outs[u.index]
    return f"keep_outs[{u.index}] (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm)"


def beyond_text(mm: float) -> str:
    """How far beyond the box, never "0.0" for a cut that is beyond it (0.001 mm)."""
    return f"{mm:.1f}" if mm >= 0.05 else f"{mm:.3f}"


def refusal(wide: list, tolerance_mm: float, name: str = "program", shown: int = 5,
            beyond: list = (), reach_mm=None, under: list = (), keep_outs=()) -> str:
    """The message refusing a path whose band exceeds the tolerance (``wide``) or whose cuts
    leave the box touches can reach (``beyond``, ``reach_mm``), naming where."""
    parts = []
    if wide:
        lines = [f"line {w.line} at ({w.x_mm:.1f}, {w.y_mm:.1f}) mm: band {w.band_mm * 1e3:.1f} um"
                 for w in sorted(wide, key=lambda w: -w.band_mm)[:shown]]
        more = f" and {len(wide) - shown} more" if len(wide) > shown else ""
        parts.append(
            f"the map's 95 % band exceeds the tolerance {tolerance_mm * 1e3:.1f} um on "
            f"{len(wide)} move(s): " + "; ".join(lines) + more
            + f". Measure more there (a cell whose plan.stop.max_std_mm is at most "
            f"{tolerance_mm / Z95:.4f} mm, the tolerance / 1.96, bounds the band everywhere), "
            "or raise --tolerance-mm")
    if beyond:
        (x0, x1), (y0, y1) = reach_mm
        lines = [f"line {b.line} at ({b.x_mm:.1f}, {b.y_mm:.1f}) mm, "
                 f"{beyond_text(b.outside_mm)} mm beyond it"
                 for b in sorted(beyond, key=lambda b: -b.outside_mm)[:shown]]
        more = f" and {len(beyond) - shown} more" if len(beyond) > shown else ""
        parts.append(
            f"{len(beyond)} cut(s) leave the box touches could reach, x [{x0:g}, {x1:g}] mm, "
            f"y [{y0:g}, {y1:g}] mm (the workplane less its edge margin): " + "; ".join(lines)
            + more + ". The map there is an extrapolation no reading tested (an edge that "
            "rolls off is not in it), so no tolerance can be promised there: keep the cuts "
            "inside that box, or map closer to the edge (a smaller workplane.edge_margin_mm, "
            "where the probe can touch there)")
    if under:
        lines = [f"line {u.line} at ({u.x_mm:.1f}, {u.y_mm:.1f}) mm, over {under_text(u, keep_outs)}"
                 for u in under[:shown]]
        more = f" and {len(under) - shown} more" if len(under) > shown else ""
        parts.append(
            f"{len(under)} cut(s) pass over a keep-out (workplane.keep_outs: a clamp or fixture "
            "the probe never touched): " + "; ".join(lines) + more + ". The map there rests on "
            "touches beside it and no reading tested it, and whatever stands there is in the "
            "cutter's way: keep the cuts off it")
    return (f"{name}: " + ". Also, ".join(parts)
            + ". Or write the output with those lines marked (--mark)")
