"""Shared helpers for tests: cells built from the simulated reference cell with overrides."""
from pathlib import Path

from adaptive_cal.cell.schema import load_yaml, parse_cell

ROOT = Path(__file__).resolve().parents[1]
SIM_CELL = ROOT / "configs" / "sim-cell.yaml"


def sim_cell(**sections):
    """configs/sim-cell.yaml with top-level sections merged (one level deep)."""
    data = load_yaml(SIM_CELL)
    for key, value in sections.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return parse_cell(data, "test cell")


def drive(mapper, opened, limit=500):
    """Run the ask/tell loop on a simulated cell until a stopping rule fires."""
    while not mapper.stop_reason() and mapper.touches < limit:
        t = mapper.ask()[0]
        touch = opened.cycle.touch(t.x_mm, t.y_mm, t.z_mm)
        mapper.tell(t.x_mm, t.y_mm, t.z_mm, touch.reading_mm)
    return mapper
