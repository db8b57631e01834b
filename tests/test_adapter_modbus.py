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
from tests.helpers import wait_listening

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


@pytest.mark.parametrize("plc", [{"probe_timeout_s": 2.0}], indirect=True)
def test_stale_probe_value_rejected(plc):
    """A trigger the PLC never acts on: the read is refused as stale, and the next trigger is
    answered. The timeout is 2 s here, not the fixture's 0.3 s: on a loaded 2-core machine the
    emulator's scan had not answered the second trigger within 0.3 s (a clean-clone CI run,
    2026-11-29), while the first read's refusal only needs the count not to advance."""
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


# -- the handshake's edges and exits (hw/plc-register-map.md, hw/ACAL_TOUCH.JBI) -----------------

def raw_client(server):
    raw = ModbusTcpClient(host="127.0.0.1", port=server.port, timeout=0.3, retries=0)
    assert raw.connect()
    return raw


def test_a_fault_during_a_move_leaves_start_cleared(plc):
    server, link = plc
    server.faults.fault_on_move = 1
    with pytest.raises(AdapterError, match="fault flag M12"):
        ModbusMotion(link).move_to(1.0, 2.0, 3.0)
    assert not server.bit("start")  # a level-triggered job would move when the fault clears
    server.clear_fault()
    time.sleep(0.05)
    assert server.robot.moves == 0


def test_a_timeout_leaves_start_cleared(plc):
    server, link = plc
    server.robot.move_s = 5.0  # never done within move_timeout_s
    with pytest.raises(AdapterError, match="no 'done' \\(M11\\) within move_timeout_s"):
        ModbusMotion(link).move_to(1.0, 2.0, 3.0)
    assert not server.bit("start") and server.robot.moves == 1


def test_link_lost_during_a_move_says_start_may_still_be_set():
    cfg = config()
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=5.0), cfg, port=0).start()
    link = ModbusLink(cfg.model_copy(update={"port": server.port}))
    try:
        import threading
        threading.Timer(0.15, server.close).start()  # the PLC goes away while the robot moves
        with pytest.raises(AdapterError) as e:
            ModbusMotion(link).move_to(1.0, 2.0, 3.0)
        msg = str(e.value)
        assert msg.startswith(f"modbus 127.0.0.1:{server.port}: START (M10) MAY STILL BE SET")
        assert "Clear M10 at the HMI before clearing any fault" in msg and "link lost" in msg
    finally:
        link.close()
        server.close()


def test_emulated_plc_acts_on_a_rising_start_not_on_a_start_held_set(plc):
    """hw/plc-register-map.md, handshake step 3: 'rising start, done off'."""
    server, link = plc
    raw = raw_client(server)
    start, done = 0x0800 + 10, 0x0800 + 11
    assert raw.write_coil(start, True, device_id=1).isError() is False
    t = time.monotonic()
    while not server.bit("done"):
        assert time.monotonic() - t < 1.0
        time.sleep(0.005)
    assert server.robot.moves == 1
    raw.write_coil(done, False, device_id=1)  # start stays set: no new move
    time.sleep(0.05)
    assert server.robot.moves == 1 and not server.bit("done")
    server.faults.fault_on_move = 1  # a held start across a fault and its reset: no move either
    raw.write_coil(start, False, device_id=1)
    time.sleep(0.03)  # a scan (5 ms) sees it off: the next on is an edge
    raw.write_coil(start, True, device_id=1)
    time.sleep(0.05)
    assert server.bit("fault") and server.robot.moves == 1
    server.clear_fault()
    time.sleep(0.05)
    assert server.robot.moves == 1
    raw.close()


def test_a_stuck_probe_trigger_is_rearmed_by_the_next_read(plc):
    server, link = plc
    ModbusMotion(link).move_to(0.0, 0.0, 0.2)
    server.faults.probe_silent = 1  # the PLC misses one trigger and leaves it set
    with pytest.raises(BadSample, match="stale"):
        ModbusProbe(link).read()
    assert server.bit("probe_trigger")
    count = server.words_of("probe_count", 1)[0]
    assert ModbusProbe(link).read().reading_mm > 0  # off then on: a rising edge again
    assert server.words_of("probe_count", 1)[0] == count + 1


def test_emulated_plc_ignores_a_trigger_held_set(plc):
    server, link = plc
    raw = raw_client(server)
    server.faults.probe_silent = 1
    raw.write_coil(0x0800 + 13, True, device_id=1)  # missed: stays set
    time.sleep(0.03)
    raw.write_coil(0x0800 + 13, True, device_id=1)  # written on again, never off: no edge
    time.sleep(0.03)
    assert server.bit("probe_trigger") and server.words_of("probe_count", 1)[0] == 0
    raw.close()


class JobMirrorPlc:
    """A modbus-tk server (an independent Modbus stack) with a ladder that copies the robot's
    done output OT#(1) into M11 every scan, and ACAL_TOUCH.JBI's logic: WAIT IN#(1)=ON; DOUT
    OT#(1) OFF; move; DOUT OT#(1) ON; WAIT IN#(1)=OFF -- done stays on until the next start."""

    def __init__(self):
        import socket
        import threading
        from modbus_tk import defines as cst, modbus_tcp
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.server = modbus_tcp.TcpServer(port=self.port, address="127.0.0.1")
        self.slave = self.server.add_slave(1)
        self.slave.add_block("m", cst.COILS, 0x0800, 32)
        self.slave.add_block("d", cst.HOLDING_REGISTERS, 0x1000, 256)
        self.server.start()
        self.io, self.moves, self.stop = {"in1": 0, "ot1": 0}, [], threading.Event()
        for f in (self.ladder, self.job):
            threading.Thread(target=f, daemon=True).start()
        wait_listening(self.port)

    def ladder(self):
        while not self.stop.wait(0.003):
            self.io["in1"] = self.slave.get_values("m", 0x0800 + 10, 1)[0]
            self.slave.set_values("m", 0x0800 + 11, [self.io["ot1"]])

    def job(self):
        while not self.stop.is_set():
            if not self.io["in1"]:
                time.sleep(0.002)
                continue
            self.io["ot1"] = 0
            d = self.slave.get_values("d", 0x1000 + 100, 6)
            self.moves.append(tuple(((d[2 * i + 1] << 16 | d[2 * i]) ^ 0x80000000) - 0x80000000
                                    for i in range(3)))
            time.sleep(0.05)
            self.io["ot1"] = 1
            while self.io["in1"] and not self.stop.is_set():
                time.sleep(0.002)

    def close(self):
        self.stop.set()
        self.server.stop()


def test_a_plc_that_mirrors_the_robots_done_is_refused_before_start():
    pytest.importorskip("modbus_tk")
    plc = JobMirrorPlc()  # it writes no actual_x/y/z: mapped, they would read 0
    regs = CELL.robot.modbus.registers.model_copy(
        update={"actual_x": None, "actual_y": None, "actual_z": None})
    link = ModbusLink(config(port=plc.port, watchdog_s=5.0, registers=regs,
                             parked_at_safe_height=True))
    try:
        motion = ModbusMotion(link)
        motion.move_to(10.0, 20.0, 15.0)
        assert plc.moves == [(100000, 200000, 150000)]  # 0.1 um counts
        with pytest.raises(AdapterError, match=r"'done' \(M11\) is set again after the PC "
                                               r"cleared it; start \(M10\) was not set"):
            motion.move_to(100.0, 50.0, 15.0)
        time.sleep(0.1)
        assert len(plc.moves) == 1 and plc.io["in1"] == 0  # nothing moved, start never set
        assert motion.position() == (10.0, 20.0, 15.0)  # where the robot still stands
    finally:
        link.close()
        plc.close()


def test_a_refusal_names_its_exception_code_and_what_to_check():
    """A wrong device_id behind a gateway answers exception 4 / 11; the message said 'check the
    register map'. Now the code, its name (Modbus Application Protocol s.7) and the device_id,
    with the key to check for each kind."""
    from pymodbus.pdu import ExceptionResponse

    from adaptive_cal.hardware.modbus.adapter import _refusal

    assert _refusal(ExceptionResponse(3, 2), 7) == (
        "exception 2 (illegal data address) from device_id 7; check the register map in "
        "robot.modbus.registers")
    for code, name in ((4, "server device failure"), (11, "gateway target device failed")):
        text = _refusal(ExceptionResponse(3, code), 7)
        assert text.startswith(f"exception {code} ({name}") and "robot.modbus.device_id" in text
        assert "register map" not in text


def test_two_devices_on_one_serial_line_share_one_port(monkeypatch):
    """An outside audit (2026-11-29): robot and probe on one RS-485 line with device ids 1 and 2
    opened the port twice -- two clients, two locks, two watchdogs whose frames could
    interleave on a line that takes one master. They now share the first link's client."""
    from adaptive_cal.hardware.modbus import adapter
    from adaptive_cal.run.devices import _modbus_links

    made = []

    class Link:
        def __init__(self, cfg, line=None):
            self.cfg, self.line = cfg, line
            made.append(self)

    monkeypatch.setattr(adapter, "ModbusLink", Link)
    line = {"transport": "rtu", "serial_port": "/dev/ttyUSB0", "host": None, "port": None}
    robot = CELL.robot.modbus.model_copy(update={**line, "device_id": 1})
    probe = CELL.robot.modbus.model_copy(update={**line, "device_id": 2})
    cell = CELL.model_copy(update={
        "robot": CELL.robot.model_copy(update={"modbus": robot}),
        "probe": CELL.probe.model_copy(update={"adapter": "modbus", "modbus": probe})})
    links = _modbus_links(cell, [])
    assert made[0].line is None and made[1].line is made[0]
    assert links["robot"] is made[0] and links["probe"] is made[1]
    other = probe.model_copy(update={"baudrate": 19200})
    cell = cell.model_copy(update={"probe": cell.probe.model_copy(update={"modbus": other})})
    with pytest.raises(AdapterError, match="different line settings \\(baudrate\\)"):
        _modbus_links(cell, [])


def test_a_link_on_another_links_line_uses_its_client_and_leaves_it_open(plc):
    server, link = plc
    second = ModbusLink(link.cfg, line=link)
    assert second.client is link.client and second.lock is link.lock
    second.close()
    assert link.client.connected
    ModbusMotion(link).move_to(0.0, 0.0, 0.2)  # the owner still talks over it
    assert ModbusProbe(link).read().reading_mm > 0


def test_device_id_0_on_a_serial_line_is_refused():
    from adaptive_cal.hardware.modbus.config import ModbusConfig
    with pytest.raises(ValueError, match="broadcast address"):
        ModbusConfig(transport="rtu", serial_port="/dev/ttyUSB0", device_id=0)
    ModbusConfig(transport="tcp", host="127.0.0.1", port=502, device_id=0)  # unit id 0 on TCP


@pytest.mark.parametrize("actual", [True, False])
def test_a_stopped_approachs_late_done_is_not_taken_for_the_retracts(actual):
    """An outside audit (2026-12-01), on a peer PLC written from the register map and on this
    emulator alike: an approach that timed out (or a Ctrl-C) left the job in its move; the
    retract's wait ended on the approach's late 'done', the PC put the tip at the safe height
    while it stood on the plate, and nothing said so. Now a retract after such a move is
    believed only where actual_x/y/z put the robot there, else not sent: either way the error
    says THE PROBE MAY BE DOWN first."""
    from adaptive_cal.hardware.base import ProbeLeftDown
    from adaptive_cal.hardware.cycle import ProbeCycle

    regs = CELL.robot.modbus.registers
    if not actual:
        regs = regs.model_copy(update={"actual_x": None, "actual_y": None, "actual_z": None})
    cfg = config(move_timeout_s=1.0, registers=regs, parked_at_safe_height=True)
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
    link = ModbusLink(cfg.model_copy(update={"port": server.port}))
    try:
        motion = ModbusMotion(link)
        cycle = ProbeCycle(motion, ModbusProbe(link), lambda x, y, z: True, safe_height_mm=15.0,
                           usable_mm=(0.5, 9.5))
        motion.move_to(10.0, 10.0, 15.0)
        move = motion.move_to

        def slow_approach(x, y, z):  # the approach (z 0) outlasts move_timeout_s
            server.robot.move_s = 1.5 if z < 5.0 else 0.01
            return move(x, y, z)
        motion.move_to = slow_approach
        with pytest.raises(ProbeLeftDown) as e:
            cycle.touch(10.0, 10.0, 0.0)
        assert str(e.value).startswith("THE PROBE MAY BE DOWN")
        said = "the stopped move's done" if actual else "was not sent"
        assert said in str(e.value), str(e.value)
        time.sleep(1.6)
        assert server.robot.pose()[2] == pytest.approx(0.0)  # it was: the PC does not say 15
        assert not motion.position()[2] > 1.0
    finally:
        link.close()
        server.close()


def test_the_emulated_job_pauses_with_done_off_on_a_target_outside_its_box():
    """ACAL_TOUCH holds the workspace box (D021..D026) and faults -- pauses with done off -- on a
    target outside it (hw/plc-register-map.md, step 3); the emulated PLC moved there and set
    done (an outside audit, 2026-12-01). The PC never sends such a target: this drives the
    registers directly, as another program on the PLC could."""
    cfg = config()
    box = ((-230.0, 230.0), (-190.0, 190.0), (-20.0, 60.0))
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0, box=box).start()
    try:
        server.write_mm("target_x", 5000.0)
        server.write_mm("target_y", 0.0)
        server.write_mm("target_z", 15.0)
        server.set_bit("start", False)
        time.sleep(0.05)
        server.set_bit("start", True)
        time.sleep(0.1)
        assert not server.bit("done") and server.robot.moves == 0
    finally:
        server.close()
