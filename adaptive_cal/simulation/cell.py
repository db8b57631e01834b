"""The simulated cell: a plate with tilt and form (or a height map, ``simulation.surface_file``),
every effect of the effect table as a forward model, robot repeatability, probe stroke,
resolution, noise (Gaussian, or Student-t with ``simulation.noise_dof``) and gross errors
(``simulation.outlier_rate`` / ``outlier_mm``), all seeded.

It knows the truth, so runs on it report their true error. Randomness for touch number ``k`` is
drawn from ``np.random.default_rng([seed, k])``: a resumed run sees the same plate and noise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from adaptive_cal import effects
from adaptive_cal.cell.schema import Cell, Simulation
from adaptive_cal.effects.frame import height_in_corrected_frame
from adaptive_cal.formats.heightmap import load_heightmap
from adaptive_cal.hardware.base import Sample


@dataclass
class SimulatedCell:
    """Motion and probe of a simulated cell (implements both protocols).

    The clock advances with travel (at ``speed_mm_per_s``) and ``touch_time_s`` per reading.
    """

    geometry: effects.Geometry
    sim: Simulation
    zero_mm: float
    stroke_mm: float
    resolution_mm: float
    speed_mm_per_s: float
    touch_time_s: float
    t_s: float = 0.0
    touches: int = 0
    pose: tuple[float, float, float] = (0.0, 0.0, 50.0)
    rest_mm: float = 0.0  # the indication with the tip free: the stroke reads rest .. rest + stroke
    _last_x: float | None = None
    _last_dir: float = 0.0
    _reached: tuple[float, float, float] = field(default=(0.0, 0.0, 50.0))

    @classmethod
    def from_cell(cls, cell: Cell, *, start_t_s: float = 0.0, start_touch: int = 0,
                  start_arrival: tuple[float, float] | None = None) -> "SimulatedCell":
        """``start_arrival``: (x mm, direction) of the recording's last row, for a resumed run:
        the next touch's direction of arrival follows from it, as the recording's row order says
        (DESIGN.md; until 2026-11-29 a resumed run's first touch had none)."""
        wp = cell.workplane
        start = (0.5 * sum(wp.x_mm), 0.5 * sum(wp.y_mm), cell.robot.safe_height_mm)
        return cls(cell.geometry, cell.simulation or Simulation(), cell.probe.zero_mm,
                   cell.probe.stroke_mm, cell.probe.resolution_mm, cell.robot.speed_mm_per_s,
                   cell.robot.touch_time_s, t_s=start_t_s, touches=start_touch, pose=start,
                   rest_mm=cell.probe.rest_mm, _reached=start,
                   _last_x=None if start_arrival is None else start_arrival[0],
                   _last_dir=0.0 if start_arrival is None else start_arrival[1])

    # -- truth -------------------------------------------------------------------------
    def surface_mm(self, x_mm, y_mm) -> np.ndarray:
        """True plate height (tilt + form + local defects) in the workplane frame the robot
        moves in: with ``simulation.frame_correction_deg`` the corrected one (the height along
        its z axis at its x, y: ``effects.frame``), else the nominal one."""
        fc = self.sim.frame_correction_deg
        if fc is None:
            return self.nominal_surface_mm(x_mm, y_mm)
        return height_in_corrected_frame(self.nominal_surface_mm, x_mm, y_mm, fc.rx_deg, fc.ry_deg)

    def nominal_surface_mm(self, x_mm, y_mm) -> np.ndarray:
        """True plate height in the nominal workplane frame (the effects as configured)."""
        x = np.asarray(x_mm, float)
        y = np.broadcast_to(np.asarray(y_mm, float), x.shape)
        f = effects.Features(x, y, np.zeros(x.shape), np.zeros(x.shape), np.zeros(x.shape))
        surface, _ = effects.split(self.sim.effects)
        height = effects.total_change(surface, f, self.geometry)
        if self.sim.surface_file is not None:
            height = height + load_heightmap(self.sim.surface_file)(x, y)
        return height

    # -- Motion --------------------------------------------------------------------------
    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        dist = float(np.linalg.norm(np.subtract((x_mm, y_mm, z_mm), self.pose)))
        self.t_s += dist / self.speed_mm_per_s
        if self._last_x is not None and abs(x_mm - self._last_x) > 1e-9:
            self._last_dir = 1.0 if x_mm > self._last_x else -1.0
        self._last_x = x_mm
        self.pose = (x_mm, y_mm, z_mm)

    def position(self) -> tuple[float, float, float]:
        return self.pose

    # -- Probe ---------------------------------------------------------------------------
    def read(self) -> Sample:
        rng = np.random.default_rng([self.sim.seed, self.touches])
        self.touches += 1
        self.t_s += self.touch_time_s
        x, y, z = self.pose
        xr = x + self.sim.xy_repeatability_mm * rng.standard_normal()
        yr = y + self.sim.xy_repeatability_mm * rng.standard_normal()
        zr = z + self.sim.repeatability_mm * rng.standard_normal()
        surface = float(self.surface_mm(xr, yr))
        ideal = surface - zr + self.zero_mm
        f = effects.Features(np.array([xr]), np.array([yr]), np.array([self.t_s]),
                             np.array([self._last_dir]), np.array([ideal]))
        _, others = effects.split(self.sim.effects)
        value = ideal + float(effects.total_change(others, f, self.geometry)[0])
        value += reading_noise_mm(self.sim, rng)
        value += gross_error_mm(self.sim, rng)
        # the probe bottoms out (and hangs free): its indications span rest .. rest + stroke
        value = float(np.clip(value, self.rest_mm, self.rest_mm + self.stroke_mm))
        value = round(value / self.resolution_mm) * self.resolution_mm
        return Sample(value, self.t_s, f"{value:.6f}".encode())

    def close(self) -> None:
        pass


def reading_noise_mm(sim: Simulation, rng: np.random.Generator) -> float:
    """A reading's probe noise of standard deviation ``noise_std_mm``: Gaussian, or with
    ``noise_dof`` Student-t of that many degrees of freedom, scaled by sqrt((dof - 2) / dof) so its
    standard deviation is the same."""
    if sim.noise_dof is None:
        return sim.noise_std_mm * rng.standard_normal()
    scale = sim.noise_std_mm * np.sqrt((sim.noise_dof - 2.0) / sim.noise_dof)
    return float(scale * rng.standard_t(sim.noise_dof))


def gross_error_mm(sim: Simulation, rng: np.random.Generator) -> float:
    """A reading's gross error: N(0, outlier_mm^2) with probability outlier_rate, else 0. Drawn
    after the reading's other draws, so the other draws do not depend on the outlier keys."""
    if sim.outlier_rate <= 0:
        return 0.0
    hit, error = rng.random(), rng.standard_normal()
    return sim.outlier_mm * error if hit < sim.outlier_rate else 0.0
