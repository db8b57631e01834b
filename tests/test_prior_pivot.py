"""Where the prior knows the plate's height (model.pivot_mm): a frame taught with its origin at
a corner of the plate (common in machining) has its z set there, not at the plate's centre.
An outside audit (2026-12-01): x 0..600, y 0..200 mm, 1 deg about both axes through the
origin -- the plate stood 7 mm high at the centre, beyond the probe's stroke; the first touch
there read past the stroke's top and the run stopped, "touches rejected after 1 touch". The
origin made the default for a day, a second audit found the converse (z set at the centre of a
corner-origin plate: stopped after 1 touch): the default stays the centre, and a cell file
whose origin on the plate is far enough from it to matter is warned to say which."""
import json

import numpy as np
import pytest

from adaptive_cal.cell.build import pivot, prior_model
from tests.helpers import sim_cell

CORNER = dict(
    workplane={"x_mm": [0, 600], "y_mm": [0, 200], "edge_margin_mm": 10, "keep_outs": []},
    workspace={"x_mm": [-5, 605], "y_mm": [-5, 205], "z_mm": [-20, 60]},
    robot={"base_xy_mm": [300, -650]},
    simulation={"seed": 3, "effects": {"tilt": {"a": 0.0175, "b": 0.0175, "c": 0.0},
                                       "form": {"pv_mm": 0.05, "bow_y": 1.0, "twist": 0.4}},
                "noise_std_mm": 0.002, "repeatability_mm": 0.005})


def test_the_pivot_is_the_workplanes_centre_unless_given_and_a_corner_origin_is_warned():
    from adaptive_cal.cell.build import cell_doubts

    assert pivot(sim_cell()) == (0.0, 0.0)  # centred: the origin is the centre
    assert pivot(sim_cell(**CORNER)) == (300.0, 100.0)
    assert pivot(sim_cell(**CORNER, model={"pivot_mm": [0, 0]})) == (0.0, 0.0)
    said = [line for line in cell_doubts(sim_cell(**CORNER)) if "pivot_mm" in line]
    assert len(said) == 1 and said[0].startswith("model.pivot_mm is not given: the prior knows "
                                                 "the plate's height to 0.5 mm")
    assert "lies on the plate 316 mm from it" in said[0] and "5.5 mm off" in said[0]
    assert "say model.pivot_mm: [0, 0]" in said[0] and "model.pivot_mm: [300, 100]" in said[0]
    for quiet in (sim_cell(), sim_cell(**CORNER, model={"pivot_mm": [0, 0]}),
                  sim_cell(**dict(CORNER, workplane=dict(CORNER["workplane"], x_mm=[100, 700]),
                                  workspace=dict(CORNER["workspace"], x_mm=[95, 705])))):
        assert not [line for line in cell_doubts(quiet) if "pivot_mm" in line]
    # the prior's height std: offset_std_mm at the pivot, growing with the distance from it
    model = prior_model(sim_cell(**CORNER, model={"pivot_mm": [0, 0]}))
    var = np.diag(model.tilt_cov())
    gx, gy = model.surface.knot_grid()
    at_origin = np.argmin(gx**2 + gy**2)
    assert var[at_origin] == pytest.approx(0.5**2)
    assert var.max() > 25 * var[at_origin]


def test_a_plate_tilted_about_a_corner_origin_is_mapped(tmp_path, capsys):
    import yaml

    from adaptive_cal.cli import main
    from adaptive_cal.cell.schema import load_yaml
    from tests.helpers import SIM_CELL

    data = load_yaml(SIM_CELL)
    for key, value in CORNER.items():
        data[key] = {**data[key], **value}
    data["model"]["pivot_mm"] = [0, 0]  # the frame taught at the corner: its z set there
    f = tmp_path / "corner.yaml"
    f.write_text(yaml.safe_dump(data))
    code = main(["run", "--robot", str(f), "--out", str(tmp_path / "run"), "--yes"])
    assert code == 0, capsys.readouterr().err[-2000:]
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["stopped_because"] == "mean_std_bound", result["stopped_because"]
    assert result["touches"] <= 60 and result["truth"]["rms_error_mm"] < 0.006
    # the closure touched the first place as it was touched (the basis rows gave its y = 10
    # back as 9.999999999999993, inside the edge margin: the safety check refused it)
    assert result["closure"]["made"] and result["closure"]["y_mm"] == 10.0
