"""A run folder's cell.yaml, read for what reads the run (report, flatness, compensate)."""
from __future__ import annotations

from pathlib import Path

from adaptive_cal.cell.files import ConfigError, load_yaml
from adaptive_cal.cell.schema import Cell, parse_cell, resolve_files


def load_run_cell(path: str | Path) -> Cell:
    """A run folder's cell.yaml, for what reads the run (report, flatness, compensate): a
    simulated plate's height map gone since the run (the folder copied elsewhere, the map moved)
    or refused now (edited since) is said and left out -- they read the run's belief, never the
    simulated truth. ``--resume`` loads with ``load_cell``: it simulates on, and needs the map."""
    data = resolve_files(load_yaml(path), path)
    sim = data.get("simulation") if isinstance(data, dict) else None
    if not (isinstance(sim, dict) and isinstance(sim.get("surface_file"), str)):
        return parse_cell(data, str(path))
    name = sim["surface_file"]
    if Path(name).is_file():
        try:
            return parse_cell(data, str(path))
        except ConfigError as e:
            if "simulation.surface_file" not in str(e):
                raise
            why = f"cannot be used now ({str(e).splitlines()[-1].strip()})"
    else:
        why = "is gone"
    from adaptive_cal.formats.recording import say

    say([f"{path}: the simulated plate's height map {name} {why}; left out (what reads a run "
         "needs its map, not the simulated truth)"])
    return parse_cell({**data, "simulation": {k: v for k, v in sim.items()
                                              if k != "surface_file"}}, str(path))
