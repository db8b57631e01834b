"""Modbus wire facts against independent stacks from PyPI on 127.0.0.1: pyModbusTCP as a client
of the emulated PLC, and a modbus-tk server standing in for the PLC against the adapter."""
import socket
import struct
import threading
import time

import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.hardware.modbus.adapter import ModbusLink, ModbusMotion, ModbusProbe
from adaptive_cal.hardware.modbus.registers import resolve
from adaptive_cal.simulation.emulator.plc import PlcServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT
from tests.helpers import wait_listening

pyModbusTCP = pytest.importorskip("pyModbusTCP")
modbus_tk = pytest.importorskip("modbus_tk")
from modbus_tk import defines as cst, modbus_tcp  # noqa: E402
from pyModbusTCP.client import ModbusClient  # noqa: E402

CELL = load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml")
DOP = {"start": "$M10", "done": "$M11", "fault": "$M12", "probe_trigger": "$M13",
       "target_x": "$100", "target_y": "$102", "target_z": "$104", "probe_value": "$110",
       "probe_count": "$112", "watchdog": "$120"}


def config(**kw):
    kw = {"timeout_s": 0.3, "retries": 0, "poll_s": 0.002, "move_timeout_s": 1.0,
          "probe_timeout_s": 0.3, "watchdog_s": 0.4, **kw}
    return CELL.robot.modbus.model_copy(update=kw)


def peer_config(**kw):
    """The peer PLC below writes no actual_x/y/z (an unmapped register reads 0, a position that
    is not one): its map leaves them out and states the robot starts parked at the safe height."""
    regs = CELL.robot.modbus.registers.model_copy(
        update={"actual_x": None, "actual_y": None, "actual_z": None})
    return config(registers=regs, parked_at_safe_height=True, **kw)


def int32_words(v: int) -> list[int]:  # low word first (word_order little)
    lo, hi = struct.unpack("<HH", struct.pack("<i", v))
    return [lo, hi]


def test_dop_addresses_per_the_hmi_manual():
    assert resolve("$M0")[:2] == ("hr", 2000) and resolve("$M1023")[:2] == ("hr", 3023)
    assert resolve("$M7").word_flag and not resolve("$7").word_flag
    with pytest.raises(ValueError, match=r"\$M1023"):
        resolve("$M1024")
    assert resolve("D100")[:2] == ("hr", 4196) and resolve("M10")[:2] == ("coil", 2058)
    with pytest.raises(ValueError, match="D4095"):
        resolve("D4096")


@pytest.mark.parametrize("registers", [None, DOP], ids=["dvp", "dop"])
def test_pymodbustcp_client_drives_the_emulated_plc(registers):
    cfg = config() if registers is None else config(registers=CELL.robot.modbus.registers
                                                     .model_copy(update=registers))
    server = PlcServer(EmulatedRobot.from_cell(CELL, move_s=0.01), cfg, port=0).start()
    c = ModbusClient(host="127.0.0.1", port=server.port, unit_id=1, timeout=1.0, auto_open=True)
    try:
        dop = registers is not None
        tx, start, done = (100, 2010, 2011) if dop else (4196, 2058, 2059)
        assert c.write_multiple_registers(tx, int32_words(12500) + int32_words(-30000)
                                          + int32_words(2500))
        assert c.write_single_register(start, 1) if dop else c.write_single_coil(start, True)
        t = time.monotonic()
        while not (c.read_holding_registers(done, 1)[0] if dop else c.read_coils(done, 1)[0]):
            assert time.monotonic() - t < 2.0
            time.sleep(0.005)
        assert server.robot.pose() == pytest.approx((1.25, -3.0, 0.25))
        if dop:  # $Mn is a word: a coil read there is no flag
            assert c.read_holding_registers(2011, 1) == [1]
    finally:
        c.close()
        server.close()


class TkPlc:
    """A modbus-tk server with the Delta DVP map and a scan thread playing the PLC: start ->
    done; probe_trigger -> probe_value = a x + b y + c (the plate at the target, um)."""

    def __init__(self, plane=(0.002, -0.001, 5.0), scale=10000):
        self.plane, self.scale = plane, scale
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.server = modbus_tcp.TcpServer(port=self.port, address="127.0.0.1")
        slave = self.server.add_slave(1)
        slave.add_block("m", cst.COILS, 0x0800, 32)
        slave.add_block("d", cst.HOLDING_REGISTERS, 0x1000, 256)
        self.slave, self.stop, self.moves = slave, threading.Event(), []
        self.server.start()
        self.thread = threading.Thread(target=self.scan, daemon=True)
        self.thread.start()
        wait_listening(self.port)

    def mm(self, d):
        lo, hi = self.slave.get_values("d", 0x1000 + d, 2)
        return struct.unpack("<i", struct.pack("<HH", lo, hi))[0] / self.scale

    def scan(self):
        s, target = self.slave, None
        while not self.stop.wait(0.002):
            start, done, fault, trig = s.get_values("m", 0x0800 + 10, 4)
            if start and not done:
                target = (self.mm(100), self.mm(102), self.mm(104))
                self.moves.append(target)
                s.set_values("m", 0x0800 + 11, [1])
            if trig and target:
                self.sample(target)

    def sample(self, target):
        """The plate at ``target`` into D110, the count D112 + 1, the trigger M13 cleared."""
        s, (a, b, c) = self.slave, self.plane
        v = round((a * target[0] + b * target[1] + c) * self.scale)
        s.set_values("m", 0x0800 + 13, [0])
        count = s.get_values("d", 0x1000 + 112, 1)[0]
        s.set_values("d", 0x1000 + 110, struct.unpack("<HH", struct.pack("<i", v)))
        s.set_values("d", 0x1000 + 112, [(count + 1) & 0xFFFF])

    def close(self):
        self.stop.set()
        self.thread.join(1.0)
        self.server.stop()


def test_adapter_runs_a_survey_handshake_against_a_modbus_tk_plc():
    plc = TkPlc()
    link = ModbusLink(peer_config(port=plc.port))
    try:
        motion, probe = ModbusMotion(link), ModbusProbe(link)
        points = [(-200, -150), (200, -150), (0, 0), (-200, 150), (200, 150), (50, -80)]
        rows = []
        for x, y in points:
            motion.move_to(x, y, 15.0)   # safe height
            motion.move_to(x, y, 0.0)    # touch
            rows.append((x, y, probe.read().reading_mm))
            motion.move_to(x, y, 15.0)
        assert plc.moves[1] == pytest.approx((-200, -150, 0.0))
        assert len(plc.moves) == 3 * len(points)
        import numpy as np
        A = np.array([[x, y, 1.0] for x, y, _ in rows])
        fit = np.linalg.lstsq(A, np.array([r for *_, r in rows]), rcond=None)[0]
        assert fit == pytest.approx(plc.plane, abs=1e-4)  # the tilt recovered
    finally:
        link.close()
        plc.close()


class EdgeTkPlc(TkPlc):
    """A modbus-tk PLC that scans every ``scan_s`` and acts on edges as an LDP contact does:
    start and probe_trigger count when this scan sees them on and the scan before saw them off
    (its Modbus requests are served between scans, by modbus-tk's own thread). ``miss`` triggers
    are left set unanswered (a PLC that missed them)."""

    def __init__(self, scan_s, miss=0, **kw):
        self.scan_s, self.miss = scan_s, miss
        super().__init__(**kw)

    def scan(self):
        s, target, was = self.slave, None, (0, 0)
        while not self.stop.wait(self.scan_s):
            start, done, fault, trig = s.get_values("m", 0x0800 + 10, 4)
            if start and not was[0] and not done:
                target = (self.mm(100), self.mm(102), self.mm(104))
                self.moves.append(target)
                s.set_values("m", 0x0800 + 11, [1])
            if trig and not was[1] and target:
                if self.miss:
                    self.miss -= 1
                else:
                    self.sample(target)
            was = (start, trig)


@pytest.mark.parametrize("scan_s", [0.002, 0.02])
def test_samples_reach_an_edge_detecting_plc_that_scans_slower_than_the_pc_writes(scan_s):
    """An outside audit (2026-11-29): the trigger's off and on went back to back (about 1 ms
    apart), so a PLC scanning every 10 ms or slower never saw an edge again once a trigger had
    been left set, and every later sample was stale. The PC now holds the trigger off for
    scan_s (here 0.04 s, longer than the PLC's scan) before it sets it."""
    plc = EdgeTkPlc(scan_s, miss=1)
    link = ModbusLink(peer_config(port=plc.port, scan_s=0.04, probe_timeout_s=0.5))
    try:
        motion, probe = ModbusMotion(link), ModbusProbe(link)
        motion.move_to(100.0, -50.0, 0.0)
        with pytest.raises(Exception, match="stale"):
            probe.read()  # the missed one: the trigger stays set
        want = plc.plane[0] * 100 - plc.plane[1] * 50 + plc.plane[2]
        for _ in range(4):  # samples back to back, as a touch takes them
            assert probe.read().reading_mm == pytest.approx(want, abs=1e-4)
        motion.move_to(100.0, -50.0, 15.0)
        assert len(plc.moves) == 2
    finally:
        link.close()
        plc.close()
