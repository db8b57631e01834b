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

``touched_xy`` (the run's fused touches): ``farthest`` is the cut sample farthest from any of
them. A dent or bump narrower than that distance can lie there unseen, and no band includes
one: an outside audit's 50 um boss 44 mm from the nearest touch was cut over at a 10 um
tolerance with a narrow band. Said, not refused: every map has such a distance.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from adaptive_cal.formats.toolpath import Move, Toolpath, ToolpathError
from adaptive_cal.gaussian.belief import Z95
from adaptive_cal.analysis.compensate_text import beyond_text, refusal, under_text  # noqa: F401

Height = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
SAMPLE_MM = 0.5  # dense check samples along a move at most this far apart
CHUNK = 50_000  # check samples given to ``height`` at once (each holds 2-3 rows of the basis)
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


@dataclass(frozen=True)
class Far:
    """The cut sample farthest from every touch: where a feature narrower than that can hide."""

    line: int
    x_mm: float
    y_mm: float
    distance_mm: float


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
    farthest: Far | None = None  # the cut sample farthest from a touch (``touched_xy``)


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
               reach_mm=None, keep_outs=(), progress=None, touched_xy=None) -> Compensated:
    """The output points of every move of ``path`` (see the module's doc). Refuses
    (``ToolpathError``) a point outside ``plate_mm`` and a cut whose start is not known, the
    first in the file. ``reach_mm``: the box touches can reach, or None (the whole plate was
    reachable); ``keep_outs``: ((x0, x1), (y0, y1)) each; ``progress(moves)``: called as
    moves are done. ``height`` is called on many points at once (CHUNK check samples): a
    million-line program is a few dozen calls, not a million."""
    if not tolerance_mm > 0:
        raise ValueError(f"tolerance {tolerance_mm} mm must be positive")
    out, cuts, ends, rapids = Compensated(), [], [], []
    for move in path.moves:  # every refusal first, in the file's order
        _check_inside(name, plate_mm, move, move.end, move.start)
        if move.cut:
            cuts.append(move)
            ends.append(_cut_ends(move, name))
        else:
            rapids.append(move)
    # a cut from nowhere (a CSV's first row) is a point, not a move (an audit: a one-row CSV
    # printed "1 cutting moves")
    out.cuts, out.rapids = sum(m.start is not None for m in cuts), len(rapids)
    tree = None
    if touched_xy is not None and len(touched_xy):
        from scipy.spatial import cKDTree

        tree = cKDTree(np.asarray(touched_xy, float)[:, :2])
    if cuts:
        se = np.asarray(ends, float)  # (cuts, 2, 3): start and end
        counts = _counts(se[:, 0], se[:, 1], sample_mm)
        for a, b in _chunks(counts):
            _cuts(out, cuts[a:b], se[a:b, 0], se[a:b, 1], counts[a:b], height, tolerance_mm,
                  reach_mm, keep_outs, tree)
            if progress is not None:
                progress(b - a)
    _rapids(out, rapids, height, top_mm, sample_mm)
    if progress is not None:
        progress(len(rapids))
    return out


def _cut_ends(move: Move, name: str):
    if None in move.end:
        raise ToolpathError(f"{name} line {move.line}: a cutting move (G1) to a point whose X, Y "
                            "or Z is not known yet: give X, Y and Z in full first (a G0)")
    if move.start is None:
        return move.end, move.end  # a CSV's first point: a point, not a segment
    if None in move.start:
        raise ToolpathError(f"{name} line {move.line}: a cutting move (G1) from a point whose X, "
                            "Y or Z is not known yet: move there first with a G0 giving X, Y and Z")
    return move.start, move.end


def _counts(start: np.ndarray, end: np.ndarray, sample_mm: float) -> np.ndarray:
    """Check samples per move (``samples``'s, ends included), for (n, 2+) starts and ends."""
    n = np.ceil(np.hypot(end[:, 0] - start[:, 0], end[:, 1] - start[:, 1]) / sample_mm)
    return np.maximum(n.astype(np.int64), 1) + 1


def _chunks(counts: np.ndarray):
    """(first, last + 1) move ranges of about CHUNK samples each (a longer move alone)."""
    edges = np.searchsorted(np.cumsum(counts), np.arange(CHUNK, counts.sum(), CHUNK),
                            side="right")
    bounds = np.unique(np.r_[0, edges, len(counts)])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _along(start: np.ndarray, end: np.ndarray, counts: np.ndarray):
    """Every move's check samples, flattened: (owner move, parameter t, points, first index of
    each move's samples), t as ``samples`` gives it (k / n, the last exactly 1)."""
    first = np.r_[0, np.cumsum(counts)[:-1]]
    owner = np.repeat(np.arange(len(counts)), counts)
    k = np.arange(int(counts.sum())) - first[owner]
    t = k * (1.0 / (counts - 1))[owner]
    t[first + counts - 1] = 1.0
    pts = start[owner] + t[:, None] * (end - start)[owner]
    return owner, t, pts, first


def _cuts(out: Compensated, moves: list, start: np.ndarray, end: np.ndarray,
          counts: np.ndarray, height: Height, tol: float, reach_mm, keep_outs,
          tree=None) -> None:
    owner, t, pts, first = _along(start, end, counts)
    if tree is not None:
        d = tree.query(pts[:, :2])[0]
        k = int(np.argmax(d))
        if out.farthest is None or d[k] > out.farthest.distance_mm:
            out.farthest = Far(moves[owner[k]].line, float(pts[k, 0]), float(pts[k, 1]),
                               float(d[k]))
    mean, std = (np.asarray(a, float).ravel() for a in height(pts[:, 0], pts[:, 1]))
    band = Z95 * std
    for m in np.flatnonzero(np.maximum.reduceat(band, first) > tol):
        w = first[m] + int(np.argmax(band[first[m]:first[m] + counts[m]]))
        out.wide.append(Wide(moves[m].line, float(pts[w, 0]), float(pts[w, 1]), float(band[w])))
    if reach_mm is not None:
        far = outside_mm(reach_mm, pts[:, 0], pts[:, 1])
        for m in np.flatnonzero(np.maximum.reduceat(far, first) > EDGE_MM):
            k = first[m] + int(np.argmax(far[first[m]:first[m] + counts[m]]))
            out.beyond.append(Beyond(moves[m].line, float(pts[k, 0]), float(pts[k, 1]),
                                     float(far[k])))
    under = []
    for i, ((x0, x1), (y0, y1)) in enumerate(keep_outs):
        over = ((pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0)
                & (pts[:, 1] < y1)).astype(np.int8)
        for m in np.flatnonzero(np.maximum.reduceat(over, first)):
            k = first[m] + int(np.argmax(over[first[m]:first[m] + counts[m]]))
            under.append((m, i, Under(moves[m].line, float(pts[k, 0]), float(pts[k, 1]), i)))
    out.under += [u for _, _, u in sorted(under, key=lambda e: e[:2])]
    limit = np.where(band <= tol, tol - band, tol)
    surface = pts[:, 2] + mean
    last = first + counts - 1
    # the chord from each move's first sample to its last, at every sample: no split needed
    # where it stays within the limit at every sample between (bisect's first test)
    chord = surface[first][owner] + t * (surface[last] - surface[first])[owner]
    off = np.abs(chord - surface) > limit
    off[first] = off[last] = False
    split = np.maximum.reduceat(off.astype(np.int8), first).astype(bool)
    dev = np.abs(chord - pts[:, 2] - mean)
    whole = np.flatnonzero(~split)
    if whole.size:
        out.max_deviation_mm = max(out.max_deviation_mm,
                                   float(np.max(np.maximum.reduceat(dev, first)[whole])))
    ends = np.c_[pts[last, :2], surface[last]].tolist()
    for m in whole:
        out.pieces[moves[m].item] = [tuple(ends[m])]
    for m in np.flatnonzero(split):
        a, b = first[m], last[m] + 1
        kept = bisect(surface[a:b], limit[a:b])
        d = deviation(t[a:b], surface[a:b][kept], pts[a:b, 2], mean[a:b], kept)
        out.max_deviation_mm = max(out.max_deviation_mm, float(d.max()))
        out.pieces[moves[m].item] = [(float(pts[a + k, 0]), float(pts[a + k, 1]),
                                      float(surface[a + k])) for k in kept[1:]]
        out.added += len(kept) - 2


def _rapids(out: Compensated, moves: list, height: Height, top_mm: float,
            sample_mm: float) -> None:
    """Each rapid's end raised (``top_mm`` where X or Y is not known yet), a level one the map
    tilts split in two, and ``rapid_dip_mm`` over the travel of those whose both ends are
    known; ``height`` called on every end at once, then on every travel sample at once."""
    moves = [m for m in moves if m.end[2] is not None]  # Z never given: the line as written
    if not moves:
        return
    ends = [p for m in moves for p in (m.start, m.end)]  # start, end of each rapid in turn
    known = [p is not None and None not in p[:2] for p in ends]
    pts = np.array([p[:2] if ok else (0.0, 0.0) for p, ok in zip(ends, known)], float)
    h = np.where(known, np.asarray(height(pts[:, 0], pts[:, 1])[0], float).ravel(), top_mm)
    h0s, h1s = h[0::2], h[1::2]
    travel = []
    for j, move in enumerate(moves):
        (x, y, z), h0, h1 = move.end, float(h0s[j]), float(h1s[j])
        out.pieces[move.item] = [(x, y, z + h1)]
        if move.start is None or move.start[2] is None or None in (x, y):
            continue
        if None in move.start[:2]:  # from somewhere not known, raised by top_mm: across first
            if move.start[2] == z and h1 < h0:
                out.pieces[move.item] = [(x, y, z + h0), (x, y, z + h1)]
            continue
        level = move.start[2] == z and move.start[:2] != (x, y) and h0 != h1
        if level:
            # a level rapid the map would tilt: across in X, Y at the higher end's Z, and up or
            # down on its own (a control may move each axis of a rapid at its own speed: Z done
            # first, a descending rapid ran 0.5 mm into the plate of an outside audit's program)
            out.pieces[move.item] = ([(x, y, z + h0), (x, y, z + h1)] if h1 < h0 else
                                     [(move.start[0], move.start[1], z + h1), (x, y, z + h1)])
        travel.append((move.start[0], move.start[1], x, y, h0, h1, level))
    if travel:
        tr = np.array(travel, float)
        counts = _counts(tr[:, :2], tr[:, 2:4], sample_mm)
        for a, b in _chunks(counts):
            part = tr[a:b]
            owner, t, xy, _ = _along(part[:, :2], part[:, 2:4], counts[a:b])
            mean = np.asarray(height(xy[:, 0], xy[:, 1])[0], float).ravel()
            h0, h1, level = part[owner, 4], part[owner, 5], part[owner, 6] > 0
            ref = np.where(level, np.maximum(h0, h1), h0 + t * (h1 - h0))
            out.rapid_dip_mm = max(out.rapid_dip_mm, float(np.max(mean - ref)))
