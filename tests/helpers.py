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


def drive(plan, opened, limit=500, state=None):
    """The product's loop (``run.loop``) on a simulated cell until the survey's stopping rule
    fires or ``limit`` touches were made; returns the final survey state."""
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.run.loop import run_loop

    def stop(state, status):
        return plan.stop(status) or ("limit" if state.touches >= limit else None)

    state, _ = run_loop(plan, state if state is not None else sv.start(plan), opened.cycle,
                        stop=stop)
    return state


def loop_on(cell):
    """The product's loop on a simulated cell until its own stopping rule fires: (plan, final
    survey state, why it stopped)."""
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.run.loop import run_loop

    plan = survey_plan(cell)
    opened = open_cell(cell)
    try:
        state, why = run_loop(plan, sv.start(plan), opened.cycle)
    finally:
        opened.close()
    return plan, state, why


def wait_listening(port: int, host: str = "127.0.0.1", timeout_s: float = 10.0) -> None:
    """Until a server thread that binds and listens on its own accepts on ``port``."""
    import socket
    import time

    t = time.monotonic()
    while time.monotonic() - t < timeout_s:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
            return
        except OSError:
            time.sleep(0.02)


def record_moves(monkeypatch) -> tuple[list, list]:
    """Every target SimulatedCell.move_to is sent, in order, and the simulated cells that were
    sent them (their ``surface_mm`` is the true plate): (sent, sims)."""
    from adaptive_cal.simulation.cell import SimulatedCell

    sent, sims = [], []
    original = SimulatedCell.move_to

    def move_to(self, x, y, z):
        sims.append(self)
        sent.append((x, y, z))
        original(self, x, y, z)

    monkeypatch.setattr(SimulatedCell, "move_to", move_to)
    return sent, sims
