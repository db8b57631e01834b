"""What ``adaptive-cal compensate`` says about the moves ``analysis.compensate`` finds it cannot
promise the tolerance on: a band wider than it, a cut beyond the box touches could reach, a cut
over a keep-out. Text only."""
from __future__ import annotations

from adaptive_cal.gaussian.belief import Z95


def under_text(u, keep_outs) -> str:
    """``keep_outs[i] (x a..b, y c..d mm)`` of a cut over it (``u``: an ``Under``)."""
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
