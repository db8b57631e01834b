"""explain's simulation includes the cell's height map (``simulation.surface_file``), as the
simulator's does: a recording of a plate that is exactly that map is `none`. Before, explain
left the map out and named the map's own 50 um bow `form` at probability 1.00 (an audit,
2026-11-24)."""
import numpy as np

from adaptive_cal.analysis.explain import explain
from adaptive_cal.formats.writing import RecordingWriter
from adaptive_cal.formats.recording import read_recording

from helpers import sim_cell


def _bow(x, y):
    return 0.05 * (1.0 - (y / 175.0) ** 2)  # 50 um across y, the audit's map


def _cell(tmp_path, with_map: bool):
    gx, gy = np.arange(-225, 226, 25.0), np.arange(-185, 186, 18.5)
    X, Y = np.meshgrid(gx, gy)
    path = tmp_path / "plate.csv"
    rows = "\n".join(f"{x:g},{y:g},{_bow(x, y):.9f}" for x, y in zip(X.ravel(), Y.ravel()))
    path.write_text("x_mm,y_mm,height_mm\n" + rows + "\n")
    sim = {"seed": 1, "effects": {"tilt": {"a": 0.01, "b": -0.005, "c": 0.1}},
           "unknown": ["tilt"], "noise_std_mm": 0.002}
    if with_map:
        sim["surface_file"] = str(path)
    return sim_cell(simulation=sim)


def test_a_plate_that_is_the_cells_height_map_is_none_not_form(tmp_path):
    rng = np.random.default_rng(3)
    xs, ys = np.linspace(-200, 200, 9), np.linspace(-160, 160, 7)
    path = tmp_path / "rec.csv"
    with RecordingWriter(path) as w:
        k = 0
        for j, y in enumerate(ys):
            for x in (xs if j % 2 == 0 else xs[::-1]):
                h = 0.012 * x - 0.004 * y + 0.3 + _bow(x, y)  # another tilt: calibrated
                w.append(seq=k, t_s=3.0 * k, x_mm=x, y_mm=y, z_mm=0.0,
                         reading_mm=5.0 + h + 0.002 * rng.standard_normal())
                k += 1
    rec = read_recording(path)
    with_map = explain([rec], _cell(tmp_path, True), identifiability=False).findings
    assert with_map["verdict"] == "none"
    assert with_map["fit"]["rms_before_mm"] < 0.004  # the noise, not the 50 um bow
    without = explain([rec], _cell(tmp_path, False), identifiability=False).findings
    assert without["verdict"] == "form"  # the same readings against a flat simulation
