"""Whole `adaptive-cal run`s through each adapter kind the docs offer -- the emulated HSES and
Modbus cells and the manual cell with typed readings -- a few touches each, recorded and fused.
A planner change once broke the Modbus and manual runs at their first touch while every
adapter's own tests passed: those adapters know no position before their first move (NaN), and
the time-aware choice priced every candidate at NaN."""
import json
import subprocess
import sys

import pytest
import yaml

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.simulation.emulator import start_emulator
from conftest import ROOT

TOUCHES = 5


def _short(d: dict) -> dict:
    """A few touches, short timeouts, no link retries: bounded in time."""
    d["plan"]["stop"].update(max_touches=TOUCHES, mean_std_mm=1e-4, max_std_mm=None)
    if d["robot"].get("hses"):
        d["robot"]["hses"].update(timeout_s=0.2, retries=1, poll_s=0.002, move_timeout_s=5.0)
    for role in ("robot", "probe"):
        if d[role].get("modbus"):
            d[role]["modbus"].update(timeout_s=0.5, retries=0, poll_s=0.002, move_timeout_s=5.0,
                                     probe_timeout_s=0.5)
    return d


def _fused_rows(out):
    rec = read_recording(out / "recording.csv")
    return [f for f in rec.flags if "rejected" not in f and "gated" not in f]


@pytest.mark.parametrize("name", ["hses", "modbus"])
def test_an_emulated_cell_is_mapped_through_its_adapters(name, tmp_path):
    emu = start_emulator(load_cell(ROOT / "configs" / f"cell-{name}-emulated.yaml"),
                         ephemeral=True, move_s=0.002)
    try:
        cell = tmp_path / "cell.yaml"
        cell.write_text(yaml.safe_dump(_short(emu.client_cell().model_dump(mode="json"))))
        out = tmp_path / "run"
        rc = main(["run", "--robot", str(cell), "--out", str(out), "--yes", "--no-progress"])
    finally:
        emu.close()
    assert rc in (0, 1)  # the touch budget ends it (INCOMPLETE), not an error (2)
    assert len(_fused_rows(out)) >= TOUCHES - 1
    assert (out / "result.json").exists()


def _run_manual(tmp_path, typed: str):
    """`adaptive-cal run` on the (shortened) manual cell with ``typed`` as the operator's input:
    (the finished process, the run folder)."""
    d = _short(yaml.safe_load((ROOT / "configs" / "cell-manual.yaml").read_text()))
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(d))
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "run", "--robot", str(cell),
                        "--out", str(out), "--yes", "--no-progress"], input=typed,
                       capture_output=True, text=True, timeout=300)
    return p, out


def test_the_manual_cell_is_mapped_from_typed_readings(tmp_path):
    # readings a live gauge gives (the same one typed every time is a frozen readout: rejected
    # after a few, see test_probe_cycle)
    p, out = _run_manual(tmp_path, "".join(f"{5.01 + 0.003 * (k % 5):.3f}\n"
                                           for k in range(2 * TOUCHES + 4)))
    assert p.returncode in (0, 1), p.stderr
    assert "error" not in p.stderr
    assert len(_fused_rows(out)) >= TOUCHES - 1


def test_q_typed_at_the_manual_cell_stops_as_an_interruption_not_a_device_error(tmp_path):
    """An outside docs audit (2026-11-29): `q` ended the run with 'error: manual adapter:
    stopped by the operator', exit status 2 and result.json's `error` set -- the status README
    gives a failed device. It now ends as Ctrl-C does: INCOMPLETE, `interrupted`, 130."""
    p, out = _run_manual(tmp_path, "5.011\n5.014\nabc\nq\n")
    assert p.returncode == 130, p.stderr
    assert "error" not in p.stderr and "INCOMPLETE" in p.stdout
    result = json.loads((out / "result.json").read_text())
    assert result["stopped_because"] == "interrupted" and "error" not in result
    assert len(_fused_rows(out)) == 2
