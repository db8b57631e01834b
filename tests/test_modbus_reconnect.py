"""A new connection (a --resume, a second run) after a run that stopped mid-move: the robot job
may still be in that move, and the PLC latches its 'done' when it ends; the first wait of the
new connection must not take it for its own (an outside audit, 2026-12-01: a Ctrl-C during a
move to (100, 0, 15), then --resume: the first move returned at once, the approach that
followed descended diagonally from where the old move ended)."""
import time

import pytest

from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.modbus.adapter import ModbusLink, ModbusMotion
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.test_adapter_modbus import CELL, config as adapter_config


def config(**kw):
    """The adapter tests' settings; a move outlasts 0.3 s, the watchdog a slow machine."""
    return adapter_config(**{"move_timeout_s": 0.3, "watchdog_s": 5.0, **kw})


@pytest.fixture
def plc():
    """(the emulated robot, the link settings of the emulated PLC serving it)."""
    cfg = config()
    robot = EmulatedRobot.from_cell(CELL, move_s=0.01)
    server = PlcServer(robot, cfg, port=0).start()
    yield robot, cfg.model_copy(update={"port": server.port})
    server.close()


def test_the_first_done_of_a_new_connection_is_checked_against_where_the_robot_is(plc):
    robot, cfg = plc
    first = ModbusMotion(ModbusLink(cfg))
    first.move_to(0.0, 0.0, 15.0)
    robot.move_s = 1.0  # the next move outlasts move_timeout_s: the run stops in it
    with pytest.raises(AdapterError, match="no 'done'"):
        first.move_to(100.0, 0.0, 15.0)
    first.close()
    robot.move_s = 0.01
    # --resume: a new connection, a new object
    second = ModbusMotion(ModbusLink(cfg.model_copy(update={"move_timeout_s": 3.0})))
    with pytest.raises(AdapterError) as e:
        second.move_to(0.0, 0.0, 15.0)  # the lift above where actual_x/y/z said it stood
    assert "not at the target" in str(e.value), str(e.value)
    time.sleep(0.2)
    assert robot.pose() == pytest.approx((100.0, 0.0, 15.0))  # where the old move ended
    second.close()


def test_a_plain_first_move_of_a_new_connection_still_goes(plc):
    robot, cfg = plc
    for target in [(10.0, 20.0, 15.0), (-40.0, 5.0, 15.0)]:  # two runs, one after another
        motion = ModbusMotion(ModbusLink(cfg))
        motion.move_to(*target)
        assert motion.position() == pytest.approx(target)
        assert robot.pose() == pytest.approx(target)
        motion.close()


class SilentActualsPlc(PlcServer):
    """A PLC whose actual_x/y/z registers are mapped but nobody writes: they read 0."""

    def write_mm(self, role, mm):
        if not role.startswith("actual_"):
            super().write_mm(role, mm)


def test_registers_nobody_writes_are_named_not_a_stale_done():
    """A second audit: mapped actual_x/y/z that nobody writes (they read 0) refused the first
    move, which had run, as 'the done of a move the job was still in' -- not the cause."""
    cfg = config()
    robot = EmulatedRobot.from_cell(CELL, move_s=0.01)
    server = SilentActualsPlc(robot, cfg, port=0).start()
    try:
        motion = ModbusMotion(ModbusLink(cfg.model_copy(update={"port": server.port})))
        with pytest.raises(AdapterError, match="they read the same before the move and after it: "
                                               "either nobody writes them"):
            motion.move_to(0.0, 0.0, 15.0)
        assert robot.pose() == pytest.approx((0.0, 0.0, 15.0))  # the move did run
        motion.close()
    finally:
        server.close()
