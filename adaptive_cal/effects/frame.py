"""The user-frame correction of a tilted plate, as a robot controller applies it.

The correction (rx, ry) in deg is ``frame_new = frame_nominal * rotx(rx) * roty(ry)`` (RoboDK
order, HARDWARE.md), the convention of ``analysis.flatness.tilt_correction_deg``, which proposes
the angles whose frame has the plate normal as its z axis. It is a rotation about the user
frame's ORIGIN (x = y = z = 0 of the workplane frame), not about the plate centre: a point
p_new in the corrected frame is ``R p_new`` in the nominal one, R = rotx(rx) roty(ry). For a
plate whose centre is far from the origin, the height at the centre changes with the
correction too; ``plane_in_corrected_frame`` accounts for it exactly.
"""
from __future__ import annotations

import numpy as np


def rotation(rx_deg: float, ry_deg: float) -> np.ndarray:
    """R = rotx(rx) roty(ry) (3 x 3): nominal coordinates of a corrected-frame point, p = R p_new."""
    cx, sx = np.cos(np.radians(rx_deg)), np.sin(np.radians(rx_deg))
    cy, sy = np.cos(np.radians(ry_deg)), np.sin(np.radians(ry_deg))
    rotx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    roty = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return rotx @ roty


def plane_in_corrected_frame(a: float, b: float, c_mm: float, rx_deg: float, ry_deg: float
                             ) -> tuple[float, float, float]:
    """The plane z = a x + b y + c (nominal frame; a, b in mm/mm, c in mm) in the corrected
    frame, exactly: z_new = a' x_new + b' y_new + c'. Its points satisfy n . p = c with
    n = (-a, -b, 1); with p = R p_new, (R^T n) . p_new = c, so with n' = R^T n:
    a' = -n'_x / n'_z, b' = -n'_y / n'_z, c' = c / n'_z. The correction
    ``tilt_correction_deg(a, b)`` gives a' = b' = 0 and c' = c / sqrt(1 + a^2 + b^2)."""
    n = rotation(rx_deg, ry_deg).T @ np.array([-a, -b, 1.0])
    return float(-n[0] / n[2]), float(-n[1] / n[2]), float(c_mm / n[2])


def height_in_corrected_frame(surface_mm, x_mm, y_mm, rx_deg: float, ry_deg: float,
                              tol_mm: float = 1e-12, max_iter: int = 50) -> np.ndarray:
    """Heights of a surface (``surface_mm(x, y)``, nominal frame) along the corrected frame's z
    axis at corrected-frame positions (x_new, y_new): the t with R (x_new, y_new, t) on the
    surface, i.e. where a probe moving along the corrected z meets the plate. Fixed point
    t = (h(p_x, p_y) - R_20 x_new - R_21 y_new) / R_22; it contracts by about the surface slope
    times sin(angle) per step (1e-4 for a 1 deg plate), so a few steps reach ``tol_mm``."""
    r = rotation(rx_deg, ry_deg)
    x = np.asarray(x_mm, float)
    y = np.broadcast_to(np.asarray(y_mm, float), x.shape)
    t = np.asarray(surface_mm(x, y), float)
    for _ in range(max_iter):
        px = r[0, 0] * x + r[0, 1] * y + r[0, 2] * t
        py = r[1, 0] * x + r[1, 1] * y + r[1, 2] * t
        new = (np.asarray(surface_mm(px, py), float) - r[2, 0] * x - r[2, 1] * y) / r[2, 2]
        done = np.max(np.abs(new - t), initial=0.0) <= tol_mm
        t = new
        if done:
            break
    return t
