"""Effect forward models against the effect table's definitions, and the simulated cell's
reading relation checked by Monte Carlo."""
import numpy as np
import pytest

from adaptive_cal import effects
from adaptive_cal.run.devices import open_cell
from adaptive_cal.formats.recording import read_recording

from helpers import sim_cell

GEOM = effects.Geometry((-225.0, 225.0), (-185.0, 185.0), (0.0, -650.0))


def _features(x, y, t=0.0, direction=0.0, ideal_reading=5.0):
    n = np.broadcast(np.asarray(x), np.asarray(y)).shape
    full = lambda v: np.broadcast_to(np.asarray(v, float), n).copy()  # noqa: E731
    return effects.Features(full(x), full(y), full(t), full(direction), full(ideal_reading))


def test_sign_conventions_of_the_effect_table():
    f = _features([0.0, 0.0], [0.0, 0.0], t=[10.0, 20.0], direction=[1.0, -1.0],
                  ideal_reading=[2.0, 4.0])
    rev = effects.reading_change("reversal", {"span_mm": 0.01}, f, GEOM)
    assert rev[0] - rev[1] == pytest.approx(0.01)  # arriving +x minus arriving -x
    drift = effects.reading_change("thermal_drift", {"rate_mm_per_s": 1e-4}, f, GEOM)
    assert drift[1] - drift[0] == pytest.approx(1e-3)
    gain = effects.reading_change("probe_gain", {"gain": 0.01}, f, GEOM)
    np.testing.assert_allclose(gain, [0.02, 0.04])  # reading = (1 + gain) ideal reading
    sag = effects.reading_change("arm_sag", {"sag_mm_at_1m": 0.05, "p": 2.0},
                                 _features([0.0], [350.0]), GEOM)
    assert sag[0] == pytest.approx(0.05)  # r = 1000 mm from the base at (0, -650)
    tilt = effects.reading_change("tilt", {"a": 0.01, "b": -0.002, "c": 0.3},
                                  _features([100.0], [50.0]), GEOM)
    assert tilt[0] == pytest.approx(0.01 * 100 - 0.002 * 50 + 0.3)


def test_form_has_the_stated_peak_to_valley_and_zero_mean():
    gx, gy = np.meshgrid(np.linspace(-225, 225, 201), np.linspace(-185, 185, 201), indexing="ij")
    for shape in ({"bow_y": 1.0}, {"twist": 1.0, "bow_x": -0.5}, {"warp": 1.0}):
        h = effects.form_height(gx, gy, {"pv_mm": 0.28, **shape}, GEOM)
        assert h.max() - h.min() == pytest.approx(0.28, rel=1e-3)
        assert abs(h.mean()) < 1e-3


def test_local_defect_is_confined():
    f = _features(np.array([50.0, 54.0, 60.0, 0.0]), np.array([20.0, 20.0, 20.0, 0.0]))
    d = effects.reading_change("local_defect", {"x_mm": 50, "y_mm": 20, "height_mm": 0.05,
                                                "radius_mm": 8}, f, GEOM)
    assert d[0] == pytest.approx(0.05) and 0 < d[1] < 0.05 and d[2] == 0 and d[3] == 0


def test_unknown_effect_or_parameter_is_named():
    with pytest.raises(KeyError, match="unknown effect 'wobble'"):
        effects.complete_params("wobble", {})
    with pytest.raises(KeyError, match="span"):
        effects.complete_params("reversal", {"span": 1})


def test_simulated_reading_relation_monte_carlo():
    """reading = surface - z + zero + noise: over 400 touches at one point the mean is within
    4 standard errors of the truth and the std within 15 % of sqrt(noise^2 + repeatability^2)."""
    cell = sim_cell(simulation={"noise_std_mm": 0.002, "repeatability_mm": 0.005})
    oc = open_cell(cell)
    x, y, z = 30.0, -40.0, 0.5
    readings = np.array([oc.cycle.touch(x, y, z).reading_mm for _ in range(400)])
    truth = float(oc.simulated.surface_mm(x, y)) - z + cell.probe.zero_mm
    sigma = np.hypot(0.002, 0.005)
    assert abs(readings.mean() - truth) < 4 * sigma / np.sqrt(400) + 1e-4  # + resolution
    assert readings.std() == pytest.approx(sigma, rel=0.15)


def test_simulated_effects_reach_the_recording(tmp_path):
    """A drift switched on in the simulation shows up in the recorded readings."""
    from adaptive_cal.run import session

    cell = sim_cell(simulation={"effects": {"tilt": {"a": 0.0, "b": 0.0, "c": 0.0},
                                            "thermal_drift": {"rate_mm_per_s": 1e-4}},
                                "noise_std_mm": 0.0, "repeatability_mm": 0.0,
                                "xy_repeatability_mm": 0.0},
                    plan={"stop": {"mean_std_mm": None, "max_touches": 6}})
    session.run(cell, tmp_path / "d", progress=False)
    rec = read_recording(tmp_path / "d" / "recording.csv")
    heights = rec.reading_mm - 5.0 + rec.z_mm
    np.testing.assert_allclose(heights, 1e-4 * rec.t_s, atol=2e-4)


def test_a_resumed_run_arrives_in_the_direction_its_recording_says():
    """An outside audit (2026-11-29): after --resume the simulator's first touch had no
    direction of arrival (reversal 0) where the recording's row order -- and so explain --
    gives it one. The last row's x and direction now carry over."""
    from adaptive_cal.simulation.cell import SimulatedCell
    from helpers import sim_cell

    cell = sim_cell(simulation={"effects": {"reversal": {"span_mm": 0.02}}, "noise_std_mm": 0.0,
                                "repeatability_mm": 0.0, "xy_repeatability_mm": 0.0})

    def reading(arrival):
        sim = SimulatedCell.from_cell(cell, start_touch=5, start_arrival=arrival)
        sim.move_to(50.0, 0.0, 15.0)
        sim.move_to(50.0, 0.0, 0.0)
        return sim.read().reading_mm

    fresh = reading(None)  # no move along x before: direction 0, as Recording.direction has it
    assert reading((100.0, 1.0)) - fresh == pytest.approx(-0.01, abs=1e-12)  # 100 -> 50: -x
    assert reading((0.0, -1.0)) - fresh == pytest.approx(+0.01, abs=1e-12)   # 0 -> 50: +x
    assert reading((50.0, -1.0)) - fresh == pytest.approx(-0.01, abs=1e-12)  # in place: kept
