"""A touch floor left to its default (the spline's coefficients) above the touch budget: no
variance bound can stop the run, which spends its budget and ends with no result. An outside
audit (2026-12-01): a 3 x 2 m plate's 256 coefficients against the default budget of 200 were
said only at the end (an explicit min_touches above max_touches is refused at load)."""
import warnings

import yaml

from adaptive_cal.cell.build import cell_doubts
from adaptive_cal.cell.schema import load_yaml
from tests.helpers import SIM_CELL, sim_cell

SHORT = {"stop": {"mean_std_mm": 0.004, "max_touches": 25}}


def test_a_defaulted_floor_above_the_budget_is_warned_before_anything_moves(tmp_path, capsys):
    from adaptive_cal.cli import main

    said = cell_doubts(sim_cell(plan=SHORT))
    assert len(said) == 1 and said[0].startswith("plan.stop.max_touches: 25 touches is below "
                                                 "the touch floor of 30 (the spline's 6 x 5")
    data = load_yaml(SIM_CELL)
    data["plan"]["stop"] = dict(SHORT["stop"])
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 0
    assert "warning: plan.stop.max_touches: 25 touches is below the touch floor of 30" in \
        capsys.readouterr().err
    from adaptive_cal import start_survey
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        start_survey(f)
    assert any("below the touch floor of 30" in str(w.message) for w in seen)


def test_no_floor_no_warning():
    for plan in ({"stop": {**SHORT["stop"], "min_touches": 10}},  # stated: the user's choice
                 {"stop": {**SHORT["stop"], "max_touches": 30}}):  # the floor fits
        assert cell_doubts(sim_cell(plan=plan)) == []
    # a stated noise span (no floor), a survey from an earlier belief (no floor)
    assert cell_doubts(sim_cell(plan=SHORT, probe={"noise_range_mm": [0.002, 0.006],
                                                   "noise_std_mm": 0.004})) == []
    assert cell_doubts(sim_cell(plan=SHORT), informed_prior=True) == []


def test_no_shipped_cell_file_is_warned_about():
    """A second audit: configs/cell-manual.yaml (25 touches, a first-guess noise: a floor of
    30) warned on every run and could never give a result; it states its gauge's span now."""
    from adaptive_cal.cell.schema import load_cell
    from tests.helpers import ROOT

    cells = sorted(p for p in (ROOT / "configs").glob("*.yaml") if not p.name.startswith("study"))
    assert len(cells) >= 6
    for path in cells:
        assert cell_doubts(load_cell(path)) == [], path.name


def test_a_plate_mostly_beyond_reach_is_warned_about():
    """An outside audit (2026-12-02): an edge margin of a third of the plate left 85 % of it to
    extrapolation; the 4 um bound was never met and the whole budget was spent, unwarned."""
    from adaptive_cal.cell.consistency import doubts, unreachable_share

    assert abs(unreachable_share(sim_cell().workplane) - 0.13) < 0.01  # 10 mm margin, a clamp
    assert not [d for d in doubts(sim_cell()) if "beyond the touches' reach" in d]
    said = [d for d in doubts(sim_cell(workplane={"edge_margin_mm": 123}))
            if "beyond the touches' reach" in d]
    assert len(said) == 1 and said[0].startswith("workplane: 85% of the plate lies beyond")
