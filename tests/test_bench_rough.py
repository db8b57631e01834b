"""benchmarks/bench_rough.py: its maps are height maps the product reads (DESIGN.md's format, the
workplane covered), drawn with the field it names (the plate's detrended std near the variant's
std and the generator's 3 um form together), and its summary counts a false stop only where a
run stopped on the bound with a true error above 1.25 x the bound."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_rough", ROOT / "benchmarks" / "bench_rough.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_maps_are_height_maps_of_the_named_field(bench, tmp_path):
    from adaptive_cal.formats.heightmap import load_heightmap

    bench.write_maps(tmp_path, "m32_10um_100mm", 2)
    x_mm, y_mm = bench.generate.workplane(bench.generate.CELL)
    stds = []
    for i in range(2):
        hm = load_heightmap(tmp_path / "m32_10um_100mm" / f"plate-{i:03d}.csv")
        assert hm.x_mm[0] <= x_mm[0] and hm.x_mm[-1] >= x_mm[1]
        assert hm.y_mm[0] <= y_mm[0] and hm.y_mm[-1] >= y_mm[1]
        X, Y = np.meshgrid(hm.x_mm, hm.y_mm, indexing="ij")
        A = np.column_stack([X.ravel(), Y.ravel(), np.ones(X.size)])
        z = hm.z_mm.ravel()
        resid = z - A @ np.linalg.lstsq(A, z, rcond=None)[0]
        stds.append(resid.std())
    # 10 um Matern and a 3 um form (sqrt(10^2 + 3^2) = 10.4 um) less their planes: one plate of
    # a 100 mm field holds about 20 length scales, so its own std strays by tens of per cent
    assert 4e-3 < np.mean(stds) < 16e-3, stds
    again = tmp_path / "again"
    bench.write_maps(again, "m32_10um_100mm", 1)
    assert (again / "m32_10um_100mm" / "plate-000.csv").read_bytes() == \
        (tmp_path / "m32_10um_100mm" / "plate-000.csv").read_bytes()  # seeded


def test_a_false_stop_is_a_bound_stop_beyond_the_target(bench):
    bound = 0.004
    recs = [{"variant": "m32_15um_80mm", "touches": t, "stop_reason": why, "mean_std_mm": 0.004,
             "true_rms_mm": true, "coverage95": c}
            for t, why, true, c in [(12, "mean_std_bound", 0.0051, 0.7),  # false: 5.1 > 5.0
                                    (30, "mean_std_bound", 0.0049, 0.9),  # within 1.25 x
                                    (200, "touch_budget", 0.009, 0.95)]]  # the budget, no claim
    s = bench.summarise(recs, bound)["m32_15um_80mm"]
    assert s["stopped_on_bound"] == 2 and s["false_stops"] == 1
    assert s["false_stops_true_um"] == [5.1] and s["touches_range"] == [12, 200]
    assert s["coverage95_mean"] == pytest.approx(0.85) and s["coverage95_min"] == 0.7
    lines = bench.report(bench.summarise(recs, bound), 1e3 * bound)
    assert any(l.startswith("MISS  m32_15um_80mm: coverage95 0.850") for l in lines)
    assert any(l.startswith("MISS  m32_15um_80mm: true RMS / stated bound 1.58") for l in lines)
