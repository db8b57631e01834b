"""A bound the touch budget cannot reach is said before anything moves (an outside audit: a
0.2 um bound with a 3-8 um probe ran all 150 touches to end INCOMPLETE at 1.4 um, unwarned)."""
import re

import yaml

from adaptive_cal.cli import main
from adaptive_cal.cli.run_guards import unreachable_bound

from helpers import SIM_CELL, sim_cell


def test_a_bound_below_the_budgets_noise_floor_is_warned_of_with_the_floor():
    cell = sim_cell(plan={"stop": {"mean_std_mm": 0.0002, "max_touches": 150}},
                    probe={"noise_range_mm": [0.003, 0.008]})
    said = unreachable_bound(cell)
    assert said and "plan.stop.mean_std_mm=0.0002 mm" in said and "max_touches=150" in said
    assert "3 um (probe.noise_range_mm's low end)" in said
    floor_um = float(re.search(r"below ([\d.]+) um", said).group(1))
    # the floor lies above the bound, and below one reading's noise (150 readings average it)
    assert 0.2 < floor_um < 3.0


def test_a_reachable_bound_says_nothing():
    assert unreachable_bound(sim_cell()) is None  # the quick start's cell
    # just below the floor warns, just above does not: the floor is the relaxed design's
    cell = sim_cell(plan={"stop": {"mean_std_mm": 0.0002, "max_touches": 150}},
                    probe={"noise_range_mm": [0.003, 0.008]})
    floor_mm = 1e-3 * float(re.search(r"below ([\d.]+) um", unreachable_bound(cell)).group(1))
    above = sim_cell(plan={"stop": {"mean_std_mm": floor_mm * 1.02, "max_touches": 150}},
                     probe={"noise_range_mm": [0.003, 0.008]})
    assert unreachable_bound(above) is None


def test_run_and_its_dry_run_warn_before_anything_moves(tmp_path, capsys):
    data = yaml.safe_load(SIM_CELL.read_text())
    data["plan"] = {**data.get("plan", {}), "stop": {"mean_std_mm": 0.0002, "max_touches": 12}}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(tmp_path / "cell.yaml"), "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "warning: plan.stop.mean_std_mm=0.0002 mm is out of reach" in err
