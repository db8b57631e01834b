"""An emulated PLC: a real pymodbus ``ModbusTcpServer`` whose register map is the cell file's,
with a scan loop (every ``scan_s``) that runs the handshake of ``hardware.modbus.adapter`` against an
EmulatedRobot: rising start (done off) -> move -> done, rising probe_trigger ->
probe_value/probe_count, watchdog -> fault; with actual_x/y/z in the map, the robot's reached
position every scan. A start or trigger that stays set does nothing more. An edge is what a
scan sees, as an LDP contact does: a flag the PC writes off and on again between two scans is
no edge (before 2026-11-29 the emulator counted it one, which no PLC can, and so hid an adapter
that held the off for one round trip only). Runs its asyncio loop in a background thread.
32-bit values are combined with the cell file's own ``word_order`` (the PC's, through the same
pymodbus conversion): the emulator always agrees with the PC, so it cannot reveal a word-order
mismatch -- see the commissioning check in docs/adapters/modbus.md.
"""
from __future__ import annotations

import asyncio
import logging
import threading
from dataclasses import dataclass

from pymodbus.client import ModbusTcpClient
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from adaptive_cal.hardware.modbus.registers import check_map, width
from adaptive_cal.hardware.modbus.config import ModbusConfig
from adaptive_cal.simulation.emulator.robot import EmulatedRobot

log = logging.getLogger(__name__)
DT = ModbusTcpClient.DATATYPE


@dataclass
class PlcFaults:
    """Injected faults: a fault flag on the next move, connections closed, probe silent."""

    fault_on_move: int = 0
    close_connections: int = 0   # the next N requests close the client connection instead
    probe_silent: int = 0        # the next N probe triggers are ignored (stale counter)


class PlcServer:
    """Serve the register map of ``cfg`` on (host, port); port 0 picks a free one."""

    def __init__(self, robot: EmulatedRobot, cfg: ModbusConfig, host: str = "127.0.0.1",
                 port: int = 0, scan_s: float = 0.005, box=None):
        self.robot, self.cfg, self.host, self.want_port, self.scan_s = robot, cfg, host, port, scan_s
        # the box ACAL_TOUCH holds (D021..D026, the cell's workspace): a target outside it
        # pauses the job with done off (hw/plc-register-map.md, step 3); None: no box
        self.box = box
        self.words = 1 if cfg.number == "int16" else 2
        self.map = check_map(cfg.registers.roles(), self.words)
        self.faults = PlcFaults()
        self.busy = False
        self.watchdog_fault = False
        self.port = 0
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = threading.Thread(target=self._run, daemon=True, name="plc-emulator")
        self._wd_value, self._wd_time = None, 0.0
        # start and probe_trigger act on a rising edge (hw/plc-register-map.md): a flag acts
        # once a scan saw it off and a later scan sees it on
        self._low_seen = {"start": False, "probe_trigger": False}

    # -- memory layout ---------------------------------------------------------------------
    def _device(self) -> SimDevice:
        tables: dict[str, list[int]] = {t: [] for t in ("coil", "di", "hr", "ir")}
        for role, a in self.map.items():
            n = width(role, self.words)
            tables[a.table] += range(a.address, a.address + n)

        def block(table, bits):
            addrs = tables[table] or [0]
            lo, hi = min(addrs), max(addrs)
            if bits:
                return [SimData(lo, values=[False] * (hi - lo + 1), datatype=DataType.BITS)]
            return [SimData(lo, values=[0] * (hi - lo + 1), datatype=DataType.REGISTERS)]

        return SimDevice(self.cfg.device_id, simdata=(block("coil", True), block("di", True),
                                                      block("hr", False), block("ir", False)),
                         action=self._action)

    async def _action(self, fc, start, address, count, registers, values):
        if self.faults.close_connections > 0:
            self.faults.close_connections -= 1
            for conn in list(self.server.active_connections.values()):
                conn.close()
        return None

    def _mem(self, role):
        a = self.map[role]
        key = {"coil": "c", "di": "d", "hr": "h", "ir": "i"}[a.table]
        start, _, regs, _ = self.runtime.block[key]
        return a, start, regs

    def bit(self, role: str) -> bool:
        a, start, regs = self._mem(role)
        if a.word_flag:  # DOP $Mn: a whole holding register
            return bool(regs[a.address - start])
        return bool(regs[a.address // 16 - start] >> (a.address % 16) & 1)

    def set_bit(self, role: str, value: bool) -> None:
        a, start, regs = self._mem(role)
        if a.word_flag:
            regs[a.address - start] = 1 if value else 0
            return
        i, m = a.address // 16 - start, 1 << (a.address % 16)
        regs[i] = regs[i] | m if value else regs[i] & ~m

    def words_of(self, role: str, n: int) -> list[int]:
        a, start, regs = self._mem(role)
        return regs[a.address - start:a.address - start + n]

    def set_words(self, role: str, words: list[int]) -> None:
        a, start, regs = self._mem(role)
        regs[a.address - start:a.address - start + len(words)] = words

    def read_mm(self, role: str) -> float:
        c, w = self.cfg, self.words_of(role, self.words)
        if c.number == "int16":
            return (w[0] - 65536 if w[0] > 32767 else w[0]) / c.scale
        dt = DT.FLOAT32 if c.number == "float32" else DT.INT32
        return float(ModbusTcpClient.convert_from_registers(w, dt, word_order=c.word_order)) / c.scale

    def write_mm(self, role: str, mm: float) -> None:
        c = self.cfg
        if c.number == "float32":
            w = ModbusTcpClient.convert_to_registers(mm * c.scale, DT.FLOAT32, word_order=c.word_order)
        elif c.number == "int16":
            w = [round(mm * c.scale) & 0xFFFF]
        else:
            w = ModbusTcpClient.convert_to_registers(round(mm * c.scale), DT.INT32,
                                                     word_order=c.word_order)
        self.set_words(role, w)

    # -- the PLC program (one scan) --------------------------------------------------------
    def scan(self) -> None:
        now = self.robot.clock()
        if "actual_x" in self.map and not self.busy:  # the job writes where the tip is while
            # it waits for start, not during a move (hw/ACAL_TOUCH.JBI): until 2026-12-01 the
            # emulator wrote them every scan, and hid a late done an audit's peer PLC showed
            for role, mm in zip(("actual_x", "actual_y", "actual_z"), self.robot.pose()):
                self.write_mm(role, mm)
        wd = self.words_of("watchdog", 1)[0]
        if wd != self._wd_value:
            if self.watchdog_fault and self._wd_value is not None:
                # a new PC session: the bench operator would reset the fault at the HMI
                log.warning("plc emulator: watchdog alive again, watchdog fault reset")
                self.watchdog_fault = False
                self.set_bit("fault", False)
            self._wd_value, self._wd_time = wd, now
        elif self._wd_value not in (None, 0) and now - self._wd_time > self.cfg.watchdog_s:
            if not self.bit("fault"):
                log.warning("plc emulator: watchdog expired, fault set")
                self.watchdog_fault = True
            self.set_bit("fault", True)
        if self.bit("fault"):
            self.robot.stop()
            self.busy = False
            return
        if self.busy and not self.robot.moving():
            self.busy = False
            self.set_bit("done", True)
        if self.rising("start") and not self.bit("done") and not self.busy:
            if self.faults.fault_on_move > 0:
                self.faults.fault_on_move -= 1
                self.set_bit("fault", True)
                return
            xyz = [self.read_mm(r) for r in ("target_x", "target_y", "target_z")]
            if self.box is not None and not all(lo <= v <= hi for v, (lo, hi) in zip(xyz, self.box)):
                log.warning("plc emulator: target %s outside the job's box: paused, done off", xyz)
                return
            self.robot.command(*xyz)
            self.busy = True
        if self.rising("probe_trigger"):
            if self.faults.probe_silent > 0:  # not acted on: the trigger stays set (stuck)
                self.faults.probe_silent -= 1
                return
            self.set_bit("probe_trigger", False)
            self.write_mm("probe_value", self.robot.read().reading_mm)
            count = self.words_of("probe_count", 1)[0]
            self.set_words("probe_count", [(count + 1) & 0xFFFF])

    def rising(self, role: str) -> bool:
        """True once per off -> on of ``role``'s flag (the edge is consumed)."""
        if not self.bit(role):
            self._low_seen[role] = True
            return False
        if self._low_seen[role]:
            self._low_seen[role] = False
            return True
        return False

    def clear_fault(self) -> None:
        self.set_bit("fault", False)
        self._wd_value = None

    # -- lifecycle ---------------------------------------------------------------------------
    def _run(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._loop.run_until_complete(self._main())

    async def _main(self) -> None:
        self.server = ModbusTcpServer(self._device(), address=(self.host, self.want_port))
        await self.server.serve_forever(background=True)
        self.port = self.server.transport.sockets[0].getsockname()[1]
        self.runtime = self.server.context.devices[self.cfg.device_id]
        self._stopping = asyncio.Event()
        self._ready.set()
        while not self._stopping.is_set():
            try:
                self.scan()
            except Exception:  # a bug in the emulator must not hang the client
                log.exception("plc emulator scan failed")
            try:
                await asyncio.wait_for(self._stopping.wait(), self.scan_s)
            except asyncio.TimeoutError:
                pass
        await self.server.shutdown()

    def start(self) -> "PlcServer":
        self._thread.start()
        if not self._ready.wait(5.0):
            raise RuntimeError("the PLC emulator did not start within 5 s")
        return self

    def close(self) -> None:
        if self._loop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopping.set)
            self._thread.join(timeout=2.0)
