"""The bands a run folder's readers draw are the run's: belief.npz keeps the variance of
structure finer than the knots (s_u^2) on a grid, and the report's std map and compensate's
map (``run.heightmap``) add it to the spline's variance, as the run's surface.png does."""
import subprocess
import sys

import numpy as np
import pytest

from adaptive_cal.formats.npz import read_npz, unresolved_at
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.run.heightmap import load_map

from helpers import SIM_CELL


def test_unresolved_grid_is_interpolated_bilinearly_and_absent_is_zero():
    gx, gy = np.linspace(0, 10, 6), np.linspace(-5, 5, 3)
    u = 1e-6 * (11 + gx[:, None] + 2 * gy[None, :])  # bilinear: reproduced exactly
    data = {"unresolved_x_mm": gx, "unresolved_y_mm": gy, "unresolved_var_mm2": u}
    x, y = np.array([0.0, 3.3, 10.0, 12.0]), np.array([-5.0, 1.7, 5.0, 0.0])
    got = unresolved_at(data, x, y)
    assert np.allclose(got, 1e-6 * (11 + np.minimum(x, 10) + 2 * y), rtol=1e-12)
    assert np.array_equal(unresolved_at({}, x, y), np.zeros(4))


@pytest.mark.slow
def test_a_run_folder_map_carries_the_saved_unresolved_variance(tmp_path):
    out = tmp_path / "run"
    subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot", str(SIM_CELL),
                    "--out", str(out), "--no-progress"], check=True, capture_output=True)
    data = read_npz(out / "belief.npz")
    assert data["unresolved_var_mm2"].shape == (81, 81) and data["unresolved_var_mm2"].max() > 0
    hm = load_map(out)
    x, y = np.array([-200.0, 0.0, 150.0]), np.array([-150.0, 10.0, 170.0])
    _, std = hm.height("nominal")(x, y)
    _, var = bl.predict(hm.belief, hm.surface.basis(x, y))
    assert np.allclose(std**2, var + unresolved_at(data, x, y), rtol=1e-10)
    assert np.all(std**2 > var)
