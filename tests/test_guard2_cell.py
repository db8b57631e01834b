"""Cell keys that passed validation and failed (or misbehaved) later: each is refused at load,
naming the key, and the command line says so on stderr with exit 2 before anything moves."""
import os
import subprocess
import sys

import pytest

from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell

from helpers import ROOT, SIM_CELL, sim_cell


def _patched(**sections):
    data = load_yaml(SIM_CELL)
    for key, value in sections.items():
        data[key] = {**data.get(key, {}), **value}
    return data


@pytest.mark.parametrize("value", [0, 0.0, -1])
def test_a_touch_that_takes_no_time_is_refused(value):
    # at 0 s a repeat touch where the probe stands costs nothing: the time-aware planner spent
    # the whole budget on one point
    with pytest.raises(ConfigError, match=r"robot\.touch_time_s: must be above 0 s.*"
                                          r"planner weighs travel"):
        parse_cell(_patched(robot={"touch_time_s": value}))


def test_a_short_touch_time_is_still_allowed():
    assert sim_cell(robot={"touch_time_s": 0.001}).robot.touch_time_s == 0.001


@pytest.mark.parametrize("seed", [-1, -(2 ** 40)])
def test_a_negative_simulation_seed_is_refused_at_load(seed):
    with pytest.raises(ConfigError, match=r"simulation\.seed.*greater than or equal to 0"):
        parse_cell(_patched(simulation={"seed": seed}))


def test_seed_zero_and_large_seeds_load():
    assert sim_cell(simulation={"seed": 0}).simulation.seed == 0
    assert sim_cell(simulation={"seed": 2 ** 40}).simulation.seed == 2 ** 40


def test_run_dry_run_refuses_a_zero_touch_time_on_stderr(tmp_path):
    text = SIM_CELL.read_text()
    assert "touch_time_s: 3" in text
    cell = tmp_path / "cell.yaml"
    cell.write_text(text.replace("touch_time_s: 3", "touch_time_s: 0"))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    p = subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot", str(cell),
                        "--dry-run"], capture_output=True, text=True, env=env, timeout=300,
                       cwd=ROOT)
    assert p.returncode == 2, p.stderr
    assert "robot.touch_time_s" in p.stderr and "Traceback" not in p.stderr
