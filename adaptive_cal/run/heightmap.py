"""A run folder's map as a height function: RUN_DIR/belief.npz (the posterior, read by
``run.results.read_belief``), cell.yaml (its spline and workplane) and result.json (the tilt
correction the run proposed), for ``adaptive-cal compensate`` and the ``--grid`` export.

Frames: ``nominal`` gives the whole mapped height (tilt and offset included) in the workplane
frame the run measured in; ``corrected`` gives the height left once the run's proposed
correction is applied -- the frame rotated by rx, ry and its origin moved by +c along z, which
removes the least-squares plane z = a x + b y + c of the posterior mean on the run's evaluation
grid (result.json ``tilt``, from ``run.results.plate_estimates``): the form alone. The std is the
posterior std in both frames (the correction is a fixed, applied value), with the variance of
structure finer than the knots the run saved in belief.npz: the run's own bands.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from adaptive_cal.cell.build import plan_model
from adaptive_cal.cell.run_cell import load_run_cell
from adaptive_cal.formats.jsonfile import read_json
from adaptive_cal.formats.npz import read_npz, unresolved_at
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.spline import Surface
from adaptive_cal.report.status import missing
from adaptive_cal.run.results import read_belief

FRAMES = ("nominal", "corrected")
TOP_GRID = 101  # nodes per side of the grid that finds the highest mapped height


@dataclass(frozen=True)
class HeightMap:
    """``plane_abc``: the proposed correction's plane (a, b mm/mm, c mm); ``plate_mm``: the
    workplane ((x0, x1), (y0, y1)); ``unfinished``: what the run is missing, or None."""

    surface: Surface
    belief: bl.Belief
    plane_abc: tuple[float, float, float]
    plate_mm: tuple[tuple[float, float], tuple[float, float]]
    unfinished: str | None
    name: str
    # belief.npz's grid of the variance of structure finer than the knots (``unresolved_at``;
    # empty for a belief saved without it): the std is the run's band, spline and that
    unresolved: dict = field(default_factory=dict)
    # the box touches could reach (the workplane less its edge margin): beyond it the map is an
    # extrapolation no reading tested; None where touches could reach the whole workplane
    reach_mm: tuple | None = None
    # the workplane's keep-outs, ((x0, x1), (y0, y1)) each: never touched, the map there rests on
    # touches beside it (``run.results.keep_out_maps``), and a clamp may stand there
    keep_outs: tuple = ()
    # the run's fused touches (x, y) mm, from recording.csv (None without it): how far a cut
    # passes from every touch, where a dent or bump narrower than that can lie unseen
    touched_xy: object = None

    def height(self, frame: str = "nominal"):
        """height(x_mm, y_mm) -> (mean_mm, std_mm) in ``frame`` (see the module's doc)."""
        if frame not in FRAMES:
            raise ValueError(f"frame {frame!r}: choose one of {', '.join(FRAMES)}")
        a, b, c = self.plane_abc if frame == "corrected" else (0.0, 0.0, 0.0)

        def height(x_mm, y_mm):
            x, y = np.broadcast_arrays(np.asarray(x_mm, float), np.asarray(y_mm, float))
            mean, var = bl.predict(self.belief, self.surface.basis(x.ravel(), y.ravel()))
            mean = np.asarray(mean) - (a * x.ravel() + b * y.ravel() + c)
            var = np.asarray(var) + unresolved_at(self.unresolved, x.ravel(), y.ravel())
            std = np.sqrt(np.maximum(var, 0.0))
            return mean.reshape(x.shape), std.reshape(x.shape)

        return height

    def grid(self, step_mm: float, frame: str = "nominal"):
        """(x_mm, y_mm, height_mm, std_mm) on a regular grid covering the workplane, its ends
        on the edges and its step at most ``step_mm`` (flattened, x outer, y inner)."""
        if not step_mm > 0:
            raise ValueError(f"--step-mm {step_mm}: must be positive")
        axes = [np.linspace(lo, hi, int(np.ceil((hi - lo) / step_mm - 1e-9)) + 1)
                for lo, hi in self.plate_mm]
        xx, yy = (v.ravel() for v in np.meshgrid(*axes, indexing="ij"))
        mean, std = self.height(frame)(xx, yy)
        return xx, yy, mean, std

    def top_mm(self, frame: str = "nominal") -> float:
        """The highest mapped height on the workplane (on a TOP_GRID x TOP_GRID grid)."""
        step = max(hi - lo for lo, hi in self.plate_mm) / (TOP_GRID - 1)
        return float(self.grid(step, frame)[2].max())


def load_map(run_dir: str | Path) -> HeightMap:
    """The map of a run folder written by ``adaptive-cal run --out RUN_DIR``."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        what = "a file, not a run folder" if run_dir.exists() else "no such folder"
        raise FileNotFoundError(f"--map {run_dir}: {what} (give the run folder that "
                                "'adaptive-cal run --out' wrote)")
    for name in ("cell.yaml", "result.json", "belief.npz"):
        if not (run_dir / name).exists():
            from adaptive_cal.report.status import unfinished

            raise FileNotFoundError(f"--map {run_dir}: {name} is missing; "
                                    + unfinished(run_dir, name))
    cell = load_run_cell(run_dir / "cell.yaml")
    result = read_json(run_dir / "result.json")
    belief, _ = read_belief(run_dir, cell)
    tilt = result.get("tilt") or {}
    if any(tilt.get(k) is None for k in "abc"):
        raise ValueError(f"{run_dir / 'result.json'}: no tilt a, b, c (is it a finished run?)")
    wp = cell.workplane
    reach = wp.reach_mm if wp.edge_margin_mm > 0 else None
    return HeightMap(plan_model(cell).surface, belief,
                     (float(tilt["a"]), float(tilt["b"]), float(tilt["c"])),
                     (tuple(wp.x_mm), tuple(wp.y_mm)), missing(result), cell.name,
                     read_npz(run_dir / "belief.npz", keys=()), reach,
                     tuple((tuple(k.x_mm), tuple(k.y_mm)) for k in wp.keep_outs),
                     _touched(run_dir / "recording.csv"))


def _touched(path: Path):
    """The (x, y) of a run's fused touches that carry real weight (a reading judged more likely
    a gross error than not, ``outlier=P`` with P >= 0.5, tells nothing of the plate there), or
    None where the recording cannot be read (the map itself is belief.npz's: a recording lost
    or damaged costs only this line)."""
    from adaptive_cal.formats.recording import RecordingError, read_recording
    from adaptive_cal.planning.gate import flagged_p

    try:
        rec = read_recording(path)
    except (OSError, RecordingError, ValueError):
        return None
    weighty = np.array([flagged_p(f) < 0.5 for f in rec.flags], bool) if rec.flags else True
    return np.c_[rec.x_mm, rec.y_mm][rec.fused & weighty]
