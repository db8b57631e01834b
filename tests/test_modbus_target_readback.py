"""The target registers are read back before ``start``: a PLC that holds another value there
(a ladder rung, an HMI screen or a gateway writing them too) refuses the move, nothing moves."""
import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.modbus.adapter import ModbusLink, ModbusMotion
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT

CELL = load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml")


def config(**kw):
    kw = {"timeout_s": 0.3, "retries": 0, "poll_s": 0.002, "move_timeout_s": 1.0,
          "probe_timeout_s": 0.3, "watchdog_s": 0.4, **kw}
    return CELL.robot.modbus.model_copy(update=kw)


class SwappingPlc(PlcServer):
    """A PLC whose target_y register holds its two words swapped by the time the PC reads it
    (as a rung that re-orders the words in place would): -10 counts become -589825."""

    async def _action(self, fc, start, address, count, registers, values):
        a = self.map["target_y"]
        if fc == 3 and not values and address <= a.address < address + count:
            i = a.address - start
            registers[i], registers[i + 1] = registers[i + 1], registers[i]
        return await super()._action(fc, start, address, count, registers, values)


@pytest.fixture
def swapping():
    cfg = config()
    server = SwappingPlc(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
    link = ModbusLink(cfg.model_copy(update={"port": server.port}))
    yield server, link
    link.close()
    server.close()


def test_a_target_register_that_reads_back_another_value_refuses_the_move(swapping):
    server, link = swapping
    motion = ModbusMotion(link)
    with pytest.raises(AdapterError) as e:
        motion.move_to(10.0, -0.001, 15.0)  # y = -10 counts: words [0xFFF6, 0xFFFF]
    said = str(e.value)
    assert "target_y (D102) reads back -58.9825 mm" in said
    assert "after the PC wrote -0.0010 mm" in said
    assert "start (M10) was not set and nothing moved" in said
    assert not server.bit("start") and server.robot.moves == 0
    assert server.robot.pose() == pytest.approx(EmulatedRobot.from_cell(CELL).pose())


def test_a_plc_that_holds_what_was_written_moves():
    cfg = config()
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
    link = ModbusLink(cfg.model_copy(update={"port": server.port}))
    try:
        ModbusMotion(link).move_to(10.0, -0.001, 15.0)
        assert server.robot.pose() == pytest.approx((10.0, -0.001, 15.0), abs=1e-6)
    finally:
        link.close()
        server.close()
