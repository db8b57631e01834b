"""The design: recordings of one cell (rounds) as per-touch features, the nominal simulation's
prediction, and the nuisance columns calibrated first (tilt per round, other unknown effects).

Nominal reading = probe zero - z_mm + known effects (the cell's simulation.effects that are not
marked unknown, and its height map, simulation.surface_file); the target of every fit is
reading - nominal. Tilt is always calibrated per round (a x + b y + c: the offset c also takes
the probe zero); other unknown linear effects are shared.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from adaptive_cal import effects
from adaptive_cal.cell.schema import Cell, ConfigError, Simulation
from adaptive_cal.formats.recording import MAX_ROWS, NOT_FUSED, Recording, RecordingError
from adaptive_cal.analysis.explain.layout import refuse_one_line

# what explain says where t_s is blank (``touch_times``, ``time_note``)
TIME_FILLED = "their times filled between the nearest rows with a time"
TIME_FROM_SEQ = "time taken as seq x robot.touch_time_s"
MIN_ROWS_PER_ROUND = 8  # tilt (3) + an effect with up to 4 parameters + a noise estimate


@dataclass(frozen=True)
class Design:
    """All rounds stacked. ``time_s`` is t_s, or seq x robot.touch_time_s where t_s is blank."""

    features: effects.Features  # ideal_reading_mm: calibrated in explain_design
    geometry: effects.Geometry
    round_index: np.ndarray
    seq: np.ndarray
    z_mm: np.ndarray
    reading_mm: np.ndarray
    nominal_mm: np.ndarray
    time_known: tuple[bool, ...]
    unknown: tuple[str, ...]
    paths: tuple[str, ...]
    noise_floor_mm: float = 0.0  # the probe's stated noise (cell file), 0 where not stated
    noise_stated_mm: float = 0.0  # the largest noise the cell file states, 0 where not stated
    readout_mm: float = 0.0  # the probe's readout step (probe.resolution_mm)
    # how the times of rows with t_s blank were taken (``time_note``), "" where none is blank
    time_blank: str = ""
    # the cell's rule for the points a run may touch, as arrays x, y -> bool array
    # (workplane.allowed: inside the edge margin, outside every keep-out), the one the planner's
    # candidate grid is built with; None: any point of the workplane
    allows: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None

    @property
    def n(self) -> int:
        return int(self.reading_mm.shape[0])

    @property
    def rounds(self) -> int:
        return len(self.paths)

    @property
    def target(self) -> np.ndarray:
        return self.reading_mm - self.nominal_mm

    def per_round(self, columns: np.ndarray) -> np.ndarray:
        """Block-diagonal copy of columns (n x k -> n x k*rounds), one block per round."""
        out = np.zeros((self.n, columns.shape[1] * self.rounds))
        for r in range(self.rounds):
            rows = self.round_index == r
            out[rows, r * columns.shape[1]:(r + 1) * columns.shape[1]] = columns[rows]
        return out

    def nuisance(self) -> tuple[np.ndarray, list[str]]:
        """Columns calibrated before anything else: tilt per round, other unknown effects."""
        cols = [self.per_round(effects.tilt.regressor(self.features, self.geometry))]
        names = [f"tilt.{p}[{r}]" for r in range(self.rounds) for p in effects.tilt.linear]
        for name in self.unknown:
            if name == "tilt":
                continue
            effect = effects.get(name)
            cols.append(effect.regressor(self.features, self.geometry, names=effect.plain))
            names += [f"{name}.{p}" for p in effect.plain]
        return np.hstack(cols), names

    @property
    def untestable(self) -> frozenset[str]:
        """Effects this design cannot show (``untestable_why``): not scored."""
        return frozenset(self.untestable_why())

    def untestable_why(self) -> dict[str, str]:
        """Effect name -> why the design cannot show it: along reach without robot.base_xy_mm;
        a reversal without touches arriving both ways along x within a round. (A drift where
        time is a linear function of position is tested -- a warm-up is not a plane -- and
        ``identify`` says that any drift is then confounded with the plate's shape.)"""
        out = {}
        if self.geometry.base_xy_mm is None:
            out.update({e.name: "not testable: the cell file lacks robot.base_xy_mm, the robot "
                        "base position the reach is measured from"
                        for e in effects.LIBRARY if e.axis == "reach"})
        d = self.features.direction
        pos = [int(np.count_nonzero((self.round_index == r) & (d > 0))) for r in range(self.rounds)]
        neg = [int(np.count_nonzero((self.round_index == r) & (d < 0))) for r in range(self.rounds)]
        if not any(p >= 2 and q >= 2 for p, q in zip(pos, neg)):
            out["reversal"] = (
                f"not testable: the design never reverses along x (touches arriving moving +x: "
                f"{sum(pos)}, moving -x: {sum(neg)}, no round with two of each); an offset by "
                "direction of arrival along x is then an offset of the touches before the first "
                "move along x, which the tilt and the plate's shape take")
        return out

    def with_ideal_reading(self, ideal_reading_mm: np.ndarray) -> "Design":
        feats = self.features.with_ideal_reading(ideal_reading_mm)
        return replace(self, features=feats)

    def select(self, keep: np.ndarray) -> "Design":
        """The rows where ``keep`` holds (directions of arrival as taken: the robot did travel
        through the rows left out)."""
        keep = np.asarray(keep, bool)
        f = self.features
        feats = effects.Features(f.x_mm[keep], f.y_mm[keep], f.t_s[keep], f.direction[keep],
                                 f.ideal_reading_mm[keep])
        return replace(self, features=feats, round_index=self.round_index[keep],
                       seq=self.seq[keep], z_mm=self.z_mm[keep],
                       reading_mm=self.reading_mm[keep], nominal_mm=self.nominal_mm[keep])


def _check_recording(rec: Recording, cell: Cell, label: str) -> None:
    wp = cell.workplane
    fused = rec.select(rec.fused)
    if len(fused) < MIN_ROWS_PER_ROUND:
        rows = f"{len(rec)} row{'s' * (len(rec) != 1)}"
        held = rows if len(fused) == len(rec) else (
            f"{rows}, {len(fused)} of them fused (the column flags marks the others "
            + "/".join(sorted(set().union(*(f & NOT_FUSED for f in rec.flags)) or {"not fused"}))
            + ")")
        raise RecordingError(f"{label}: {held}; explain needs at least {MIN_ROWS_PER_ROUND} fused "
                             "rows per recording (tilt, one effect and the noise)")
    for name in ("x_mm", "y_mm", "z_mm", "reading_mm"):  # a Recording built in memory
        bad = np.flatnonzero(~np.isfinite(getattr(fused, name)))
        if bad.size:
            raise RecordingError(f"{label}: seq {int(fused.seq[bad[0]])}: {name} is not a finite "
                                 f"number ({bad.size} fused row(s) like it); flag it rejected")
    off = wp.first_outside(fused.x_mm, fused.y_mm)  # a row the run refused (flagged invalid)
    if off is not None:  # is not used
        c, i, count = off
        lo, hi = getattr(wp, c)
        raise RecordingError(
            f"{label}: touch seq {int(fused.seq[i])}: column {c} = {getattr(fused, c)[i]:g} lies "
            f"outside the workplane {c} [{lo:g}, {hi:g}] of the cell file ({count} such touches)")
    refuse_one_line(fused.x_mm, fused.y_mm, label)  # one x, one y, or any one line: no tilt


def _refuse_repeats(recordings: list[Recording], probe) -> None:
    """One recording given twice is not two rounds: the second round repeats every reading
    exactly, and the "repeatability" between them (zero) reads as structure the noise cannot
    explain. Refused when two are the same file (resolved path) or hold the same positions and
    readings, row for row (a copy, retimed or not)."""
    import hashlib
    import os

    seen: dict[object, str] = {}
    for i, rec in enumerate(recordings):
        label = rec.path or f"recording {i}"
        keys = []
        if rec.path:
            keys.append(("path", os.path.realpath(rec.path)))
        digest = hashlib.sha256()
        for column in (rec.x_mm, rec.y_mm, rec.z_mm, rec.reading_mm):  # times aside: a copy
            digest.update(np.ascontiguousarray(column, dtype=float).tobytes())
        keys.append(("rows", digest.hexdigest()))
        for key in keys:
            if key in seen:
                why = ("are the same file" if key[0] == "path" else
                       "hold the same rows (every position and reading)")
                raise RecordingError(
                    f"{seen[key]} and {label} {why}: a recording given twice is not a "
                    "second round (its readings repeat exactly, and explain would read the "
                    "missing scatter as structure); give each round once")
            seen[key] = label
    _refuse_near_copies(recordings, probe)


def _refuse_near_copies(recordings: list[Recording], probe) -> None:
    """Two rounds at the same positions whose readings differ by far less than the probe's
    stated noise are one round copied (rounded, or its readings re-written): genuine repeats
    differ by about sqrt(2) noise RMS; below 0.2 x the stated noise that has a chance of about
    0.02^(n/2) over n rows. No noise stated: within the readout step (``resolution_mm``)."""
    if probe.noise_range_mm is not None:
        floor, key = 0.2 * probe.noise_range_mm[0], "probe.noise_range_mm (its lower end)"
    elif "noise_std_mm" in probe.model_fields_set:
        floor, key = 0.2 * probe.noise_std_mm, "probe.noise_std_mm"
    else:
        floor, key = probe.resolution_mm, "probe.resolution_mm (no noise stated)"
    for j, b in enumerate(recordings):
        for a in recordings[:j]:
            if len(a) != len(b) or len(a) < 4 or not all(
                    np.allclose(getattr(a, c), getattr(b, c), rtol=0, atol=1e-3)
                    for c in ("x_mm", "y_mm", "z_mm")):
                continue
            rms = float(np.sqrt(np.nanmean((a.reading_mm - b.reading_mm) ** 2)))
            if rms < floor:
                raise RecordingError(
                    f"{a.path or 'a recording'} and {b.path or 'another'} touch the same "
                    f"positions and their readings differ by {rms * 1e3:.3g} um RMS, below "
                    f"{floor * 1e3:.3g} um from {key}: genuine repeats differ by about "
                    "1.4 x the noise; one looks like a copy of the other (rounded?) and is not "
                    "a second round. Give each round once, or state the probe's noise")


def build_design(recordings: list[Recording], cell: Cell) -> Design:
    """Stack rounds, compute features and the nominal prediction; check the recordings fit."""
    sim = cell.simulation or Simulation()
    if "tilt" not in sim.unknown:
        raise ConfigError("simulation.unknown: explain calibrates the tilt first; add 'tilt' "
                          f"(got {sim.unknown})")
    unknown = tuple(dict.fromkeys(n.split(".")[0] for n in sim.unknown))
    for name in unknown:
        effect = effects.get(name)
        if not effect.plain:
            raise ConfigError(f"simulation.unknown: {name!r} has nonlinear parameters "
                              f"{effect.nonlinear}; explain calibrates only effects "
                              "linear in their parameters (give them in simulation.effects)")
    total = sum(len(rec) for rec in recordings)
    if total > MAX_ROWS:  # the reader's limit, also for recordings built in memory
        raise RecordingError(f"{total} rows in {len(recordings)} recording(s); explain takes at "
                             f"most {MAX_ROWS} rows at once: split the recordings by round")
    recordings = [part for rec in recordings for part in split_rounds(rec)]
    _refuse_repeats(recordings, cell.probe)
    cols = {k: [] for k in ("x", "y", "t", "d", "z", "r", "seq", "read")}
    blank_rows, none_known = [], []
    for i, rec in enumerate(recordings):
        label = rec.path or f"recording {i}"
        _check_recording(rec, cell, label)
        keep = rec.fused
        # arrival and time from every row the robot went to: a rejected or gated touch was a
        # move, and its time is on the clock (only then are the used rows selected)
        direction = arrival(rec)[keep]
        t = touch_times(rec, cell.robot.touch_time_s)[keep]
        blank_rows.append(int(np.count_nonzero(~np.isfinite(rec.t_s))))
        none_known.append(not np.any(np.isfinite(rec.t_s)))
        rec = rec.select(keep)
        for k, v in (("x", rec.x_mm), ("y", rec.y_mm), ("t", np.asarray(t, float)),
                     ("d", direction), ("z", rec.z_mm), ("r", np.full(len(rec), i)),
                     ("seq", rec.seq), ("read", rec.reading_mm)):
            cols[k].append(np.asarray(v))
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    geometry = cell.geometry
    zero = cell.probe.zero_mm
    base = zero - cat["z"]
    feats = effects.Features(cat["x"], cat["y"], cat["t"], cat["d"], base)
    surface, others = effects.split({k: v for k, v in sim.effects.items() if k not in unknown})
    for name in others:
        if effects.get(name).axis == "reach" and geometry.base_xy_mm is None:
            raise ConfigError(f"simulation.effects.{name} needs robot.base_xy_mm (the robot base "
                              "position in the workplane frame)")
    ideal = base + effects.total_change(surface, feats, geometry)
    if sim.surface_file is not None:  # the simulated plate's own shape, as the simulator has it
        from adaptive_cal.formats.heightmap import load_heightmap
        ideal = ideal + load_heightmap(sim.surface_file)(cat["x"], cat["y"])
    feats = effects.Features(cat["x"], cat["y"], cat["t"], cat["d"], ideal)
    nominal = ideal + effects.total_change(others, feats, geometry)
    return Design(feats, geometry, cat["r"].astype(int), cat["seq"].astype(int), cat["z"],
                  cat["read"], nominal, tuple(b == 0 for b in blank_rows), unknown,
                  tuple(r.path or f"recording {i}" for i, r in enumerate(recordings)),
                  stated_noise_mm(cell), stated_noise_mm(cell, high=True),
                  float(cell.probe.resolution_mm), time_note(blank_rows, none_known),
                  cell.workplane.allowed)


def time_note(blank_rows: list[int], none_known: list[bool]) -> str:
    """What explain says about blank t_s: per recording (round), its count of blank rows and
    whether it has no time at all (``touch_times``)."""
    if not any(blank_rows):
        return ""
    parts = []
    if any(none_known):
        parts.append(f"t_s blank throughout: {TIME_FROM_SEQ}")
    partly = sum(b for b, none in zip(blank_rows, none_known) if not none)
    if partly:
        parts.append(f"t_s blank on {partly} row{'s' * (partly != 1)}: {TIME_FILLED}")
    return "; ".join(parts)


def split_rounds(rec: Recording) -> list[Recording]:
    """A recording whose optional ``round`` column takes several values holds several rounds
    (DESIGN.md's optional columns): one recording per value, in the order they first appear,
    each named ``PATH (round V)`` -- as if each round had been given as its own file (its own
    tilt, its own directions of arrival). One value or no such column: the recording itself."""
    values = rec.rounds
    if len(values) <= 1:
        return [rec]
    r = np.asarray(rec.extra["round"], float)
    if not np.all(np.isfinite(r)):
        where = rec.path or "the recording"
        raise RecordingError(f"{where}: column round is blank on {int(np.sum(~np.isfinite(r)))} "
                             f"row(s) while it holds rounds {', '.join(f'{v:g}' for v in values)}: "
                             "every row must say its round")
    out = []
    for v in values:
        part = rec.select(r == v)
        out.append(replace(part, path=f"{rec.path or 'recording'} (round {v:g})"))
    return out


def arrival(rec: Recording) -> np.ndarray:
    """Direction of arrival along x of every row (``Recording.direction``) over the moves the
    robot made: every row but those the run refused before moving (flagged ``invalid`` for a
    place off the workplane or inside a keep-out -- not ``nonfinite``, a reading the probe did
    take). Rows the belief does not fuse (rejected, gated) were moves all the same: dropping
    them first would give the next row the direction of a move it did not make."""
    flags = rec.flags or ()
    moved = np.ones(len(rec), bool)
    if flags:
        moved = np.array([not ("invalid" in f and "nonfinite" not in f) for f in flags], bool)
    d = np.zeros(len(rec))
    d[moved] = rec.select(moved).direction
    return d


def touch_times(rec: Recording, touch_time_s: float) -> np.ndarray:
    """Time of every row: t_s; blank throughout, seq x ``touch_time_s`` (robot.touch_time_s);
    blank on some rows (DESIGN.md: t_s may be blank when unknown), those rows filled linearly
    between the nearest rows with a time, by row order, and beyond the first or last time at
    ``touch_time_s`` a row -- so one blank time does not discard every known one."""
    t = np.asarray(rec.t_s, float)
    ok = np.isfinite(t)
    if ok.all():
        return t
    if not ok.any():
        return rec.seq * touch_time_s
    i = np.arange(len(t), dtype=float)
    ki, kt = i[ok], t[ok]
    filled = np.interp(i, ki, kt)
    filled[i < ki[0]] = kt[0] - (ki[0] - i[i < ki[0]]) * touch_time_s
    filled[i > ki[-1]] = kt[-1] + (i[i > ki[-1]] - ki[-1]) * touch_time_s
    return np.where(ok, t, filled)


def stated_noise_mm(cell: Cell, high: bool = False) -> float:
    """The reading noise the cell file states: the lower end (``high``: the upper end) of
    probe.noise_range_mm, else probe.noise_std_mm where the file gives it; 0 where it states
    neither (the default first guess is not a statement)."""
    probe = cell.probe
    if probe.noise_range_mm is not None:
        return float(max(probe.noise_range_mm) if high else min(probe.noise_range_mm))
    if "noise_std_mm" in probe.model_fields_set:
        return float(probe.noise_std_mm)
    return 0.0
