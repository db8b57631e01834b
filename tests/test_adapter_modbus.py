"""The modbus adapter against the emulated PLC (a real pymodbus ModbusTcpServer on 127.0.0.1)."""
import time

import pytest
from pymodbus.client import ModbusTcpClient

from adaptive_cal.hardware.base import AdapterError, BadSample
from adaptive_cal.hardware.modbus.adapter import ModbusLink, ModbusMotion, ModbusProbe
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT

CELL = load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml")


def config(**kw):
    kw = {"timeout_s": 0.3, "retries": 0, "poll_s": 0.002, "move_timeout_s": 1.0,
          "probe_timeout_s": 0.3, "watchdog_s": 0.4, **kw}
    return CELL.robot.modbus.model_copy(update=kw)


@pytest.fixture
def plc(request):
    cfg = config(**getattr(request, "param", {}))
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
    link = ModbusLink(cfg.model_copy(update={"port": server.port}))
    yield server, link
    link.close()
    server.close()


@pytest.mark.parametrize("plc", [{}, {"word_order": "big"}, {"number": "float32", "scale": 1.0}],
                         indirect=True)
def test_move_handshake_and_probe_value_with_word_order_and_scale(plc):
    server, link = plc
    motion, probe = ModbusMotion(link), ModbusProbe(link)
    motion.move_to(-12.5, 40.0, 0.25)
    assert server.robot.pose() == pytest.approx((-12.5, 40.0, 0.25), abs=1e-4)
    assert motion.position() == (-12.5, 40.0, 0.25) and not server.bit("start")
    s = probe.read()
    assert s.reading_mm == pytest.approx(server.read_mm("probe_value"))
    assert 0 < s.reading_mm < 10 and len(s.raw) == 4


def test_registers_are_where_the_delta_map_says(plc):
    server, link = plc
    ModbusMotion(link).move_to(1.0, 2.0, 3.0)
    raw = ModbusTcpClient(host="127.0.0.1", port=server.port, timeout=0.3, retries=0)
    assert raw.connect()
    words = raw.read_holding_registers(0x1000 + 100, count=2, device_id=1).registers
    # 1.0 mm x 10000 counts/mm, low word first
    assert raw.convert_from_registers(words, raw.DATATYPE.INT32, word_order="little") == 10000
    assert raw.read_coils(0x0800 + 11, count=1, device_id=1).bits[0]  # done = M11
    raw.close()


def test_fault_flag_stops_with_what_to_do(plc):
    server, link = plc
    server.faults.fault_on_move = 1
    with pytest.raises(AdapterError, match="fault flag M12 is set.*clear it at the HMI"):
        ModbusMotion(link).move_to(1.0, 2.0, 3.0)


def test_stale_probe_value_rejected(plc):
    server, link = plc
    ModbusMotion(link).move_to(0.0, 0.0, 0.2)  # tip on the plate
    server.faults.probe_silent = 1
    with pytest.raises(BadSample, match="stale"):
        ModbusProbe(link).read()
    assert ModbusProbe(link).read().reading_mm > 0  # next trigger answered


def test_connection_closed_mid_run_reconnects_once(plc):
    server, link = plc
    server.faults.close_connections = 1
    ModbusMotion(link).move_to(4.0, 5.0, 6.0)
    assert server.robot.pose() == pytest.approx((4.0, 5.0, 6.0), abs=1e-4)


def test_plc_gone_is_a_clean_error_not_a_hang(plc):
    server, link = plc
    server.close()
    t = time.monotonic()
    with pytest.raises(AdapterError, match="link lost|cannot|refused"):
        ModbusMotion(link).move_to(4.0, 5.0, 6.0)
    assert time.monotonic() - t < 3.0


def test_watchdog_expires_when_the_pc_stops_kicking(plc):
    server, link = plc
    link._stop.set()  # the PC program hangs: no more watchdog writes
    link._dog.join(1.0)
    time.sleep(0.6)
    assert server.bit("fault")
    with pytest.raises(AdapterError, match="fault flag"):
        ModbusProbe(link).read()


def test_cannot_connect_names_the_endpoint():
    with pytest.raises(AdapterError, match="modbus 127.0.0.1:9: cannot connect"):
        ModbusLink(config(port=9))
