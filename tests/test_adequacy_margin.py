"""The map beyond the box touches can reach (the workplane's edge margin) is named as an
extrapolation in the model's verdict (result.json's "model", the terminal's model line)."""
import numpy as np

import adaptive_cal

adaptive_cal.use_float64()


def _plan(**workplane):
    from adaptive_cal.cell.build import survey_plan
    from helpers import sim_cell

    more = {"workplane": workplane} if workplane else {}
    return survey_plan(sim_cell(probe={"noise_range_mm": [0.003, 0.008]}, **more), grow=False)


def _checked(plan, n=12, seed=4):
    from dataclasses import replace

    from adaptive_cal.planning import survey as sv

    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1) = plan.bounds_mm
    xy = np.stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)], 1)
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    y = 0.001 * xy[:, 0] + 0.005 * rng.standard_normal(n)
    return sv.refit(plan, replace(sv.start(plan), rows=rows, heights_mm=y)).adequacy


def test_the_unreachable_margin_is_named_with_its_share_of_the_plate():
    """Oracle: the share is 1 - (inner box area / plate area), by hand for the simulated cell's
    workplane and its 10 mm margin."""
    plan = _plan()
    (x0, x1), (y0, y1) = plan.plate_mm
    m = 10.0
    assert plan.bounds_mm == ((x0 + m, x1 - m), (y0 + m, y1 - m))
    v = _checked(plan)
    ext = v.extrapolated()
    share = 1 - (x1 - x0 - 2 * m) * (y1 - y0 - 2 * m) / ((x1 - x0) * (y1 - y0))
    assert ext["margin_mm"] == [m, m, m, m]
    assert abs(ext["share"] - share) < 1e-12
    assert f"within {m:.0f} mm" in v.summary() and f"{100 * share:.0f} %" in v.summary()
    d = v.as_dict()
    assert d["extrapolated"]["share"] == ext["share"] and ext["text"] in d["summary"]


def test_no_margin_no_extrapolation_line():
    plan = _plan(edge_margin_mm=0)
    v = _checked(plan)
    assert v.extrapolated() is None
    assert "extrapolated" not in v.summary() and v.as_dict()["extrapolated"] is None
