"""explain's suggested touches are approached at the height of a plane fitted to the last
round (``identify._approach_plane``). Touches on one diagonal line do not determine the slope
across it: lstsq returned one anyway and the suggestions came at z = +-362,428 mm. Now a slope
the touches do not determine is level, and one they do is kept exactly."""
from types import SimpleNamespace

import numpy as np

from adaptive_cal.analysis.explain.identify import _approach_plane


def _design(x, y, seen, reading=0.5):
    n = len(x)
    return SimpleNamespace(features=SimpleNamespace(x_mm=np.asarray(x, float),
                                                    y_mm=np.asarray(y, float)),
                           z_mm=np.asarray(seen, float) - reading, reading_mm=np.full(n, reading),
                           round_index=np.zeros(n, int), rounds=1)


def test_a_plane_the_touches_determine_is_recovered_exactly():
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-200, 200, 30), rng.uniform(-150, 150, 30)
    seen = 0.014 * x - 0.002 * y + 0.2
    (a, b, c), indication = _approach_plane(_design(x, y, seen))
    assert np.allclose([a, b, c], [0.014, -0.002, 0.2], atol=1e-12) and indication == 0.5


def test_touches_on_one_line_give_a_level_slope_across_it():
    t = np.linspace(-200, 200, 20)
    x, y = t, 0.8 * t
    y = y + np.where(np.arange(20) == 7, 1e-3, 0.0)  # one touch 1 um off the line
    seen = 1e-4 * t + 1e-6 * np.sin(t)  # 0.1 mm/m along the line, um noise
    (a, b, c), _ = _approach_plane(_design(x, y, seen))
    # along the line the slope is kept; across it (direction (-0.8, 1) / |.|) it is level
    along = (a + 0.8 * b) / np.hypot(1, 0.8)
    across = (-0.8 * a + b) / np.hypot(1, 0.8)
    assert abs(along - 1e-4 / np.hypot(1, 0.8)) < 1e-6 and abs(across) < 1e-9
    # a suggestion at a far corner stays near the plate, not hundreds of metres away
    assert abs(a * -215 + b * 175 + c) < 0.1
