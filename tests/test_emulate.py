"""The emulated cell end to end: the real adapters from open_cell() against the emulator's
HSES controller, Modbus PLC and gauge on 127.0.0.1, with faults injected into the emulator."""
import os
import socket
import subprocess
import sys
import time

import pytest
import yaml

from adaptive_cal.hardware.base import AdapterError, BadSample, UnsafeTarget
from adaptive_cal.run.devices import open_cell
from adaptive_cal.cell.schema import load_cell, parse_cell
from adaptive_cal.simulation.emulator import start_emulator
from tests.conftest import ROOT

POINTS = [(0.0, 0.0), (120.0, -80.0), (-150.0, 140.0), (200.0, 170.0)]


def fast(cell):
    """Short timeouts, no link retries: every test is bounded in time."""
    d = cell.model_dump()
    if d["robot"]["hses"]:
        d["robot"]["hses"].update(timeout_s=0.1, retries=1, poll_s=0.002, move_timeout_s=2.0)
    for role in ("robot", "probe"):
        if d[role].get("modbus"):
            d[role]["modbus"].update(timeout_s=0.3, retries=0, poll_s=0.002, move_timeout_s=2.0,
                                     probe_timeout_s=0.3)
    if d["probe"]["serial"]:
        d["probe"]["serial"]["timeout_s"] = 0.2
    return parse_cell(d)


def emulate(name):
    cell = load_cell(ROOT / "configs" / f"cell-{name}-emulated.yaml")
    emu = start_emulator(cell, ephemeral=True, move_s=0.002)
    opened = open_cell(fast(emu.client_cell()))
    yield emu, opened
    opened.close()
    emu.close()


@pytest.fixture(params=["hses", "modbus"])
def emulated(request):
    yield from emulate(request.param)


@pytest.fixture
def hses_cell():
    yield from emulate("hses")


@pytest.fixture
def modbus_cell():
    yield from emulate("modbus")


def expected(emu, x, y, z):
    zero = emu.cell.probe.zero_mm
    return float(emu.robot.sim.surface_mm(x, y)) - z + zero


def test_readings_are_the_plate_at_the_reached_pose(emulated):
    emu, opened = emulated
    for x, y in POINTS:
        z = float(emu.robot.sim.surface_mm(x, y)) - 0.3
        t = opened.cycle.touch(x, y, z)
        assert t.reading_mm == pytest.approx(expected(emu, x, y, z), abs=0.03)
        assert emu.robot.pose() == pytest.approx((x, y, emu.cell.robot.safe_height_mm), abs=1e-3)
    assert emu.robot.readings == len(POINTS) * emu.cell.probe.samples


def test_unsafe_target_never_reaches_the_emulator(emulated):
    emu, opened = emulated
    moves = emu.robot.moves
    for target in [(-220.0, 0.0, 0.0), (-20.0, 80.0, 0.0), (0.0, 0.0, 80.0)]:  # margin, clamp, box
        with pytest.raises(UnsafeTarget):
            opened.cycle.touch(*target)
    assert emu.robot.moves == moves


def test_hses_dropped_and_delayed_answers_still_give_the_reading(hses_cell):
    emu, opened = hses_cell
    z = float(emu.robot.sim.surface_mm(50, 50))
    emu.hses.faults.delay_answers, emu.hses.faults.delay_s = 1, 0.15  # later than timeout_s
    assert opened.cycle.touch(50.0, 50.0, z).reading_mm == pytest.approx(5.0, abs=0.03)
    time.sleep(0.2)  # the late answer arrives now; the next request must not take it
    emu.hses.faults.drop_answers = 1
    z = float(emu.robot.sim.surface_mm(60, 50))
    assert opened.cycle.touch(60.0, 50.0, z).reading_mm == pytest.approx(5.0, abs=0.03)
    assert opened.cycle.motion.dropped == 1


def test_gauge_garbage_once_is_retried_silent_gauge_stops_cleanly(hses_cell):
    emu, opened = hses_cell
    z = float(emu.robot.sim.surface_mm(0, 0))
    emu.gauge.faults.garbage = 1
    t = opened.cycle.touch(0.0, 0.0, z)
    assert "does not match" in t.extra["problems"][0]
    emu.gauge.faults.silent = 100
    start, before = time.monotonic(), emu.robot.readings
    with pytest.raises(BadSample, match="no usable probe sample after 3"):
        opened.cycle.touch(10.0, 0.0, z)
    assert time.monotonic() - start < 3.0 and emu.robot.readings == before
    assert emu.robot.pose()[2] == pytest.approx(emu.cell.robot.safe_height_mm)  # retracted


def test_modbus_connection_closed_mid_run_and_fault_flag(modbus_cell):
    emu, opened = modbus_cell
    z = float(emu.robot.sim.surface_mm(0, 0))
    emu.plc.faults.close_connections = 1
    assert opened.cycle.touch(0.0, 0.0, z).reading_mm == pytest.approx(5.0, abs=0.03)
    emu.plc.faults.fault_on_move = 1
    with pytest.raises(AdapterError, match="fault flag M12"):
        opened.cycle.touch(10.0, 0.0, z)


def test_hses_alarm_is_a_clean_stop_with_the_pendant_action(hses_cell):
    emu, opened = hses_cell
    emu.hses.faults.alarm_on_move = 1
    with pytest.raises(AdapterError, match="alarm"):
        opened.cycle.touch(0.0, 0.0, 0.0)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_emulate_command_serves_the_ports_of_the_cell_file(tmp_path):
    d = yaml.safe_load((ROOT / "configs" / "cell-hses-emulated.yaml").read_text())
    d["robot"]["hses"]["port"] = free_port()
    d["probe"]["serial"]["port"] = f"socket://127.0.0.1:{free_port()}"
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(d))
    proc = subprocess.Popen([sys.executable, "-m", "adaptive_cal.cli", "emulate", "--robot",
                             str(path), "--seconds", "30", "--move-s", "0.002"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "JAX_PLATFORMS": "cpu"})
    try:
        line = proc.stdout.readline()
        assert "emulating 'hses emulated cell'" in line and str(d["robot"]["hses"]["port"]) in line
        opened = open_cell(fast(load_cell(path)))
        try:
            t = opened.cycle.touch(30.0, -40.0, 0.0)
            assert 0.5 < t.reading_mm < 9.5
        finally:
            opened.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
