"""The first Modbus move starts from where the robot stands: read from actual_x/y/z (the first
touch lifts straight up at the current x, y, then travels), or, where the PLC gives no
position, refused unless the cell file states the robot starts parked at the safe height."""
import time

import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.hardware.base import AdapterError, Sample
from adaptive_cal.hardware.cycle import ProbeCycle
from adaptive_cal.hardware.modbus.adapter import ModbusLink, ModbusMotion
from adaptive_cal.hardware.modbus.config import ModbusConfig
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT

CELL = load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml")
NO_POSITION = CELL.robot.modbus.registers.model_copy(
    update={"actual_x": None, "actual_y": None, "actual_z": None})


def config(**kw):
    kw = {"timeout_s": 0.3, "retries": 0, "poll_s": 0.002, "move_timeout_s": 1.0,
          "probe_timeout_s": 0.3, "watchdog_s": 0.4, **kw}
    return CELL.robot.modbus.model_copy(update=kw)


class Plc:
    """The emulated PLC and a link to it; every target the robot was sent is kept in order."""

    def __init__(self, cfg):
        self.server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
        self.sent = []
        command = self.server.robot.command
        self.server.robot.command = lambda *xyz: (self.sent.append(xyz), command(*xyz))[1]
        self.link = ModbusLink(cfg.model_copy(update={"port": self.server.port}))

    def park(self, pose):
        self.server.robot.sim.pose = pose
        time.sleep(0.05)  # a few scans: the PLC has written it to actual_x/y/z

    def close(self):
        self.link.close()
        self.server.close()


class Probe:
    def read(self):
        return Sample(5.0, 0.0)

    def close(self):
        pass


def test_the_first_touch_lifts_straight_up_from_where_the_plc_says_the_robot_is():
    plc = Plc(config())
    try:
        plc.park((120.0, -80.0, 2.0))  # left low, away from the first target
        cycle = ProbeCycle(ModbusMotion(plc.link), Probe(), lambda x, y, z: True,
                           safe_height_mm=15.0, usable_mm=(0.5, 9.5))
        cycle.touch(-50.0, 40.0, 0.2)
        assert plc.sent == [pytest.approx(t) for t in [
            (120.0, -80.0, 15.0),   # straight up where it stands
            (-50.0, 40.0, 15.0),    # across at the safe height
            (-50.0, 40.0, 0.2),     # down to touch
            (-50.0, 40.0, 15.0)]]   # retract
    finally:
        plc.close()


def test_a_position_outside_the_workspace_is_not_lifted_from():
    """A position read wrong (a word order that differs, a register the job does not write)
    lands far outside the box: the lift above it is refused, nothing is sent."""
    from adaptive_cal.hardware.base import UnsafeTarget

    plc = Plc(config())
    try:
        plc.park((39800.0, 0.0, 2.0))
        cycle = ProbeCycle(ModbusMotion(plc.link), Probe(),
                           lambda x, y, z: abs(x) <= 230 and abs(y) <= 190,
                           safe_height_mm=15.0, usable_mm=(0.5, 9.5))
        with pytest.raises(UnsafeTarget, match="x=39800.000"):
            cycle.touch(-50.0, 40.0, 0.2)
        assert plc.sent == []
    finally:
        plc.close()


def test_without_a_position_the_first_move_is_refused_before_anything_is_written():
    plc = Plc(config(registers=NO_POSITION))
    try:
        motion = ModbusMotion(plc.link)
        with pytest.raises(AdapterError) as e:
            motion.move_to(-50.0, 40.0, 15.0)
        said = str(e.value)
        assert "the robot's position is unknown (robot.modbus.registers maps no actual_x" in said
        assert "start was not set and nothing moved" in said
        assert "robot.modbus.parked_at_safe_height: true" in said
        assert plc.sent == [] and not plc.server.bit("start")
        assert plc.server.read_mm("target_x") == 0.0  # nothing written either
    finally:
        plc.close()


def test_a_cell_that_states_the_robot_starts_parked_moves_straight_across():
    plc = Plc(config(registers=NO_POSITION, parked_at_safe_height=True))
    try:
        motion = ModbusMotion(plc.link)
        cycle = ProbeCycle(motion, Probe(), lambda x, y, z: True, safe_height_mm=15.0,
                           usable_mm=(0.5, 9.5))
        cycle.touch(-50.0, 40.0, 0.2)
        assert plc.sent[0] == pytest.approx((-50.0, 40.0, 15.0))
        assert len(plc.sent) == 3
    finally:
        plc.close()


def test_only_the_first_move_needs_the_position():
    """After a move ended in done the PC knows where the robot is."""
    plc = Plc(config(registers=NO_POSITION, parked_at_safe_height=True))
    try:
        motion = ModbusMotion(plc.link)
        motion.move_to(1.0, 2.0, 15.0)
        assert motion.position() == (1.0, 2.0, 15.0)
        motion.move_to(1.0, 2.0, 0.5)
        assert len(plc.sent) == 2
    finally:
        plc.close()


def test_the_position_is_read_whole_or_not_at_all():
    with pytest.raises(ValueError, match=r"registers.actual_x='D130' needs registers.actual_y "
                                         r"and registers.actual_z too"):
        ModbusConfig(host="127.0.0.1", port=502, registers={"actual_x": "D130"})
    with pytest.raises(ValueError, match=r"registers.actual_y='D101' overlaps registers.target_x"):
        ModbusConfig(host="127.0.0.1", port=502, registers={
            "actual_x": "D130", "actual_y": "D101", "actual_z": "D134"})


def test_a_cell_that_cannot_make_a_safe_first_move_is_refused_at_load(tmp_path):
    # said when the cell file is read (run, --dry-run, emulate), before a run folder is made:
    # the adapter's own refusal comes only at the first move, after the run has begun
    from adaptive_cal.cell.files import ConfigError

    text = (ROOT / "configs" / "cell-modbus-emulated.yaml").read_text()
    bare = "\n".join(line for line in text.splitlines()
                     if not line.strip().startswith("actual_"))
    path = tmp_path / "cell.yaml"
    path.write_text(bare)
    with pytest.raises(ConfigError, match=r"robot.*parked_at_safe_height: true"):
        load_cell(path)
    path.write_text(bare.replace("    registers:", "    parked_at_safe_height: true\n    registers:", 1))
    assert load_cell(path).robot.modbus.parked_at_safe_height
