"""Bad adapter input refused at load time with the key named; Delta names translated."""
import copy

import pytest
import yaml

from adaptive_cal.hardware.modbus.registers import resolve
from adaptive_cal.cell.schema import ConfigError, load_cell, parse_cell
from tests.conftest import ROOT

HSES = yaml.safe_load((ROOT / "configs" / "cell-hses-emulated.yaml").read_text())
MODBUS = yaml.safe_load((ROOT / "configs" / "cell-modbus-emulated.yaml").read_text())


def edited(base, path, value):
    d = copy.deepcopy(base)
    *keys, last = path.split(".")
    node = d
    for k in keys:
        node = node[k]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return d


@pytest.mark.parametrize("base, path, value, expect", [
    (HSES, "robot.adapter", "kuka", "robot.adapter: Input should be"),
    (HSES, "probe.adapter", "laser", "probe.adapter: Input should be"),
    (HSES, "robot.hses.host", KeyError, "robot.hses.host: missing"),
    (HSES, "robot.hses.port", KeyError, "robot.hses.port: missing"),
    (HSES, "robot.hses.host", " ", "robot.hses.host: must be an IP address or a host name"),
    (HSES, "robot.hses.tmeout_s", 1, "robot.hses.tmeout_s: unknown key"),
    (HSES, "robot.hses", KeyError, "needs a robot.hses block"),
    (HSES, "probe.serial.baudrate", 9601, "probe.serial.baudrate: baud rate 9601 does not exist"),
    (HSES, "probe.serial.preset", "citizen", "probe.serial.preset: Input should be"),
    (HSES, "probe.serial.pattern", "([0-9", "probe.serial.pattern: pattern"),
    (MODBUS, "robot.modbus.word_order", "middle", "robot.modbus.word_order: Input should be"),
    (MODBUS, "robot.modbus.baudrate", 12345, "baud rate 12345 does not exist"),
    (MODBUS, "robot.modbus.host", KeyError, "transport 'tcp' needs host"),
    (MODBUS, "robot.modbus.port", KeyError, "transport 'tcp' needs port"),
])
def test_bad_input_names_the_key(base, path, value, expect):
    with pytest.raises(ConfigError, match=expect.replace("(", r"\(").replace("[", r"\[")):
        parse_cell(edited(base, path, value), "cell.yaml")


@pytest.mark.parametrize("registers, expect", [
    ({"target_y": "D101"}, "registers.target_y='D101' overlaps registers.target_x='D100'"),
    ({"done": "M10"}, "registers.done='M10' overlaps registers.start='M10'"),
    ({"start": "D7"}, "registers.start='D7' must be a bit"),
    ({"target_x": "M5"}, "registers.target_x='M5' must be a register"),
    ({"start": "X7"}, "is an input (read-only)"),
    # the PC clears done before each start: on an input that write lands on the coil of the
    # same number, another output (an outside audit, 2026-11-30)
    ({"done": "X7"}, "registers.done='X7' is an input (read-only)"),
    ({"done": "di:3"}, "registers.done='di:3' is an input (read-only)"),
    ({"done": "X18"}, "octal"),
    ({"watchdog": "Q5"}, "'Q5' is not a PLC address"),
])
def test_register_map_problems_named(registers, expect):
    bad = edited(MODBUS, "robot.modbus.registers", {**MODBUS["robot"]["modbus"]["registers"],
                                                    **registers})
    with pytest.raises(ConfigError, match="robot.modbus") as e:
        parse_cell(bad, "cell.yaml")
    assert expect in str(e.value)


def test_int16_values_may_sit_one_register_apart():
    regs = {**MODBUS["robot"]["modbus"]["registers"], "target_y": "D101", "target_z": "D102",
            "probe_value": "D103", "probe_count": "D104"}
    d = edited(edited(MODBUS, "robot.modbus.registers", regs), "robot.modbus.number", "int16")
    d = edited(d, "robot.modbus.scale", 100)  # int16 carries +-327 mm at 100 counts per mm
    d["probe"]["modbus"] = d["robot"]["modbus"]
    assert parse_cell(d).robot.modbus.number == "int16"


@pytest.mark.parametrize("name, table, address", [
    ("D100", "hr", 0x1064), ("D0", "hr", 0x1000), ("M10", "coil", 0x080A),
    ("M1536", "coil", 0xB000), ("X17", "di", 0x040F), ("Y10", "coil", 0x0508),
    ("$100", "hr", 100), ("$M5", "hr", 2005), ("hr:0x20", "hr", 32), ("coil:7", "coil", 7),
])
def test_delta_and_dop_names_translated(name, table, address):
    a = resolve(name)
    assert (a.table, a.address) == (table, address)


@pytest.mark.parametrize("name", ["cell-hses-emulated", "cell-modbus-emulated", "cell-manual"])
def test_shipped_cell_files_load(name):
    cell = load_cell(ROOT / "configs" / f"{name}.yaml")
    assert cell.robot.adapter in ("hses", "modbus", "manual")


def test_sim_probe_with_a_real_robot_is_refused_at_load_time():
    from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell
    from helpers import SIM_CELL

    data = load_yaml(SIM_CELL)
    data["probe"] = {**data["probe"], "adapter": "manual"}
    with pytest.raises(ConfigError, match="probe.adapter='manual'"):
        parse_cell(data)


def test_a_simulated_cell_gets_the_default_simulation_and_a_real_one_none():
    from adaptive_cal.cell.schema import Simulation

    plate = {"x_mm": [0, 100], "y_mm": [0, 50]}
    sim = parse_cell({"workplane": plate})
    assert sim.simulation == Simulation()
    assert parse_cell({"workplane": plate, "simulation": None}).simulation == Simulation()
    given = parse_cell({"workplane": plate, "simulation": {"seed": 7}})
    assert given.simulation.seed == 7
    real = {k: v for k, v in HSES.items() if k != "simulation"}  # the emulator's truth removed
    assert parse_cell(real).simulation is None  # a real robot gets no simulated truth
    with pytest.raises(Exception):  # frozen: the filled value is the model's own, not patched in
        sim.simulation = None


def test_modbus_config_checks_its_register_map_without_the_adapter():
    """The config block and the register map load without pymodbus (no import cycle either)."""
    import subprocess
    import sys

    probe = ("import sys; from adaptive_cal.hardware.modbus.config import ModbusConfig; "
             "ModbusConfig(host='127.0.0.1', port=502); print('pymodbus' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr
    with pytest.raises(ValueError, match="registers.done"):
        from adaptive_cal.hardware.modbus.config import ModbusConfig

        ModbusConfig(host="127.0.0.1", port=502, registers={"done": "D5"})


def test_modbus_default_scale_is_the_jobs_0_1_um_counts():
    """A cell file that leaves scale out must send what hw/ACAL_TOUCH.JBI reads: 0.1 um counts,
    divided by 10 into the um that SETE puts in P001 (the map, the job and the docs say 10000)."""
    import re

    from adaptive_cal.hardware.modbus.config import ModbusConfig

    cfg = ModbusConfig(host="192.168.1.5", port=502)
    job = (ROOT / "hw" / "ACAL_TOUCH.JBI").read_text()
    div = int(re.search(r"^DIV D041 (\d+)$", job, re.M).group(1))  # the target copied to D041
    assert "0.1 UM" in job.upper() and div == 10
    for mm in (2.0, 100.0, -185.0):
        counts = round(mm * cfg.scale)
        assert int(counts / div) / 1000 == mm  # SETE: um -> the job moves to mm
    assert re.search(r"`scale` is register counts per mm \(10000 = 0\.1\s+um\)",
                     (ROOT / "hw" / "plc-register-map.md").read_text())
    assert cfg.scale == MODBUS["robot"]["modbus"]["scale"] == 10000


@pytest.mark.parametrize("number, scale, fits", [
    ("int32", 10000, True), ("int16", 10000, False), ("int16", 100, True),
    ("float32", 10000, True), ("float32", 1e5, False)])
def test_modbus_number_and_scale_checked_against_the_workspace(number, scale, fits):
    from adaptive_cal.hardware.modbus.config import ModbusConfig

    cfg = ModbusConfig(host="127.0.0.1", port=502, number=number, scale=scale)
    box = {k: tuple(v) for k, v in MODBUS["workspace"].items()}  # x up to 230 mm
    if fits:
        cfg.check_reach(box, "robot.modbus")
    else:
        with pytest.raises(ValueError, match=f"robot.modbus.scale={scale:g} with "
                                             f"robot.modbus.number='{number}' carries at most"):
            cfg.check_reach(box, "robot.modbus")


def test_modbus_serial_data_bits_per_transport():
    """Modbus over Serial Line V1.02 s.2.5.1: RTU is 8 data bits (even parity by default);
    7 data bits exist in ASCII mode only (Delta DVP's default 9600 7E1)."""
    from adaptive_cal.hardware.modbus.config import ModbusConfig

    rtu = ModbusConfig(transport="rtu", serial_port="/dev/ttyUSB0")
    ascii_ = ModbusConfig(transport="ascii", serial_port="/dev/ttyUSB0")
    assert (rtu.bytesize, rtu.parity, rtu.stopbits) == (8, "E", 1)
    assert (ascii_.bytesize, ascii_.parity, ascii_.stopbits) == (7, "E", 1)
    assert ModbusConfig(transport="ascii", serial_port="x", bytesize=8).bytesize == 8
    bad = edited(edited(MODBUS, "robot.modbus.transport", "rtu"), "robot.modbus.bytesize", 7)
    bad = edited(bad, "robot.modbus.serial_port", "/dev/ttyUSB0")
    with pytest.raises(ConfigError, match="robot.modbus: bytesize 7 with transport 'rtu'"):
        parse_cell(bad, "cell.yaml")


def test_a_cell_whose_workspace_does_not_fit_the_modbus_registers_is_refused_at_load():
    """int16 at 10000 counts per mm carries 3.3 mm: the cell file is refused when it is loaded,
    naming the keys, before anything connects (not at the first move)."""
    bad = edited(MODBUS, "robot.modbus.number", "int16")
    with pytest.raises(ConfigError, match=r"robot\.modbus\.scale=10000 with "
                                          r"robot\.modbus\.number='int16' carries at most"):
        parse_cell(bad)
    parse_cell(edited(bad, "robot.modbus.scale", 100))  # 327 mm: the workspace fits


def _modbus_probe(number, scale):
    """The HSES cell with the Modbus cell's probe (a gauge read through the PLC), its length
    format ``number`` at ``scale`` counts per mm."""
    d = copy.deepcopy(HSES)
    probe = copy.deepcopy(MODBUS["probe"])
    probe["modbus"] = {**copy.deepcopy(probe["modbus"]), "number": number, "scale": scale,
                       "parked_at_safe_height": True}
    for role in ("actual_x", "actual_y", "actual_z"):
        probe["modbus"]["registers"].pop(role, None)
    d["probe"] = probe
    return d


def test_a_modbus_probe_whose_registers_cannot_hold_the_stroke_is_refused():
    """int16 at 10000 counts per mm holds +-3.2767 mm: a 7.1 mm reading wrapped to 0.5464 mm,
    inside the usable stroke, and was fused (an outside audit, 2026-11-29)."""
    with pytest.raises(ConfigError, match=r"probe\.modbus\.scale=10000 with probe\.modbus\."
                       r"number='int16' carries at most 3\.2767 mm, but a reading anywhere in "
                       r"probe\.stroke_mm=\[0\.0, 10\.0\] reaches 10 mm"):
        parse_cell(_modbus_probe("int16", 10000), "cell.yaml")
    assert parse_cell(_modbus_probe("int16", 1000), "cell.yaml").probe.modbus.reach_mm() > 10


@pytest.mark.parametrize("path, value, expect", [
    ("robot.hses.orientation_deg", [1e6, 0, 0], "robot.hses.orientation_deg: orientation_deg "
     "[1000000.0, 0.0, 0.0]: each angle must lie in [-180, 180]"),
    ("robot.hses.orientation_deg", [float("nan"), 0, 0], "robot.hses.orientation_deg"),
    ("robot.hses.offset_mm", [3e6, 0, 0], "robot.hses.offset_mm: offset_mm [3000000.0, 0.0, "
     "0.0] puts the workplane more than 10 m"),
    ("probe.serial.scale", 0, "probe.serial.scale: must be a finite, non-zero number"),
])
def test_numbers_sent_or_read_by_the_adapters_are_checked_at_load(path, value, expect):
    """Before, these loaded: the HSES angle and offset switched servo power on and failed at the
    first move with a bare struct.error (an i32 word); a serial scale of 0 read every sample as
    0.0 mm, each touch rejected as a stroke end (an outside audit, 2026-11-29)."""
    with pytest.raises(ConfigError, match=expect.replace("(", r"\(").replace("[", r"\[")
                       .replace(".", r"\.")):
        parse_cell(edited(HSES, path, value), "cell.yaml")


@pytest.mark.parametrize("block, kwargs, field", [
    ("robodk", dict(robot_name="r", tool_name="t", frame_name="f",
                    orientation_deg=(float("nan"), 0.0, 0.0)), "orientation_deg.0"),
    ("modbus", dict(host="127.0.0.1", port=502, timeout_s=float("inf")), "timeout_s"),
    ("modbus", dict(host="127.0.0.1", port=502, scan_s=float("nan")), "scan_s"),
    ("hses", dict(host="127.0.0.1", port=10040, move_timeout_s=float("inf")), "move_timeout_s"),
    ("serial", dict(port="/dev/ttyUSB0", timeout_s=float("inf")), "timeout_s"),
])
def test_blocks_built_in_python_refuse_nan_and_inf(block, kwargs, field):
    """A cell file already refused NaN and inf (cell.block); a block built through the Python
    API took them: a RoboDK orientation of NaN reached the first move, a Modbus timeout of inf
    waited for ever on a dead link (noted, not mended, on 2026-11-29)."""
    import importlib

    from pydantic import ValidationError

    module = importlib.import_module(f"adaptive_cal.hardware.{block}.config")
    cls = next(getattr(module, n) for n in dir(module)
               if n.lower() == f"{block}config")
    with pytest.raises(ValidationError, match=rf"(?s){field}\n.*finite number"):
        cls(**kwargs)


def test_a_modicon_style_raw_address_is_warned_about_before_anything_moves(tmp_path, capsys):
    """An outside audit (2026-12-01): hr:40101 was taken silently as protocol address 40101;
    Modicon's 40101 is holding register 101, protocol address 100 (Modbus Application
    Protocol s.4.4: counted from 0)."""
    import yaml

    from adaptive_cal.cell.consistency import doubts, modicon_doubt
    from adaptive_cal.cell.schema import load_yaml, parse_cell
    from adaptive_cal.cli import main

    assert modicon_doubt("hr:40101").endswith("write hr:100")
    assert modicon_doubt("ir:30005").endswith("write ir:4")
    assert modicon_doubt("di:10001").endswith("write di:0")
    for fine in ("hr:100", "hr:4196", "hr:0x1064", "hr:30005", "coil:2058", "D100", "hr:40000"):
        assert modicon_doubt(fine) is None, fine
    data = load_yaml(ROOT / "configs" / "cell-modbus-emulated.yaml")
    data["robot"]["modbus"]["registers"]["watchdog"] = "hr:40121"
    cell = parse_cell(data)
    said = doubts(cell)
    assert len(said) == 1 and said[0].startswith("robot.modbus.registers.watchdog: hr:40121 reads "
                                                 "like a Modicon reference"), said
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump(data))
    assert main(["run", "--robot", str(f), "--dry-run"]) == 0
    assert "warning: robot.modbus.registers.watchdog: hr:40121" in capsys.readouterr().err


def test_a_six_digit_modicon_reference_is_refused_with_what_to_write():
    with pytest.raises(ValueError, match=r"beyond 65535 \(a 6-digit Modicon reference, counted "
                                         r"from 1\? hr:N takes the protocol address: 400101 is "
                                         r"hr:100\)"):
        resolve("hr:400101")
    with pytest.raises(ValueError, match=r"beyond 65535$"):
        resolve("hr:99999999")
