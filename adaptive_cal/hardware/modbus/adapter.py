"""The ``modbus`` adapter: a PLC or HMI over Modbus TCP or serial (pymodbus >=3.16,<4): the link
and the probe here, the motion in ``motion`` (re-exported here).

Relays cannot carry coordinates, so the PC writes the target into data registers that a robot
job copies into a position variable (hw/plc-register-map.md). Handshake, per move: PC writes
target_x/y/z and reads them back (another value there refuses the move), clears ``done`` and
checks that it stays off (a PLC that copies the robot's done output into it is refused before
``start``), sets ``start``; the PLC (on the rising edge) has the robot move and sets ``done``;
the PC clears ``start``, also when the wait ends any other way (fault, timeout, lost link: else
a level-triggered PLC or job moves the robot when the fault is cleared). ``fault`` set by the
PLC stops the run. A probe sample: PC sets ``probe_trigger`` (a rising edge) once it has been
off for ``scan_s`` -- since the PLC cleared it, or since the PC wrote off one found still set --
so that a scan sees it off; the PLC stores the value, increments ``probe_count`` and clears the
trigger; a counter that does not move means a stale value, which is rejected. A background
thread increments ``watchdog`` every watchdog_s / 4 so the PLC can stop the cell when the PC or
the link dies.
"""
from __future__ import annotations

import logging
import math
import struct
import threading
import time

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from adaptive_cal.hardware.base import AdapterError, BadSample, Sample
from adaptive_cal.hardware.modbus.registers import check_map
from adaptive_cal.hardware.modbus.config import ModbusConfig
from adaptive_cal.hardware.modbus.motion import ModbusMotion  # noqa: F401 (its home before)

log = logging.getLogger(__name__)
DT = ModbusTcpClient.DATATYPE


class ModbusLink:
    """One connection to a PLC, shared by motion and probe; thread-safe; one reconnect per op.
    ``line``: another device's link on the same serial line, whose client and lock this one
    uses (Modbus over Serial Line allows one master per line: one port, one client)."""

    def __init__(self, cfg: ModbusConfig, *, clock=time.monotonic, sleep=time.sleep,
                 line: "ModbusLink | None" = None):
        self.cfg, self.clock, self.sleep = cfg, clock, sleep
        self.map = check_map(cfg.registers.roles(), 1 if cfg.number == "int16" else 2)
        self.words = 1 if cfg.number == "int16" else 2
        self.owns_client = line is None
        if line is not None:
            self.where = f"{line.where} device {cfg.device_id}"
            self.client = line.client
        elif cfg.transport == "tcp":
            self.where = f"modbus {cfg.host}:{cfg.port}"
            self.client = ModbusTcpClient(cfg.host, port=cfg.port, timeout=cfg.timeout_s,
                                          retries=cfg.retries, reconnect_delay=0)
        else:
            self.where = f"modbus {cfg.serial_port}"
            self.client = ModbusSerialClient(
                cfg.serial_port, framer=FramerType.ASCII if cfg.transport == "ascii"
                else FramerType.RTU, baudrate=cfg.baudrate, bytesize=cfg.bytesize,
                parity=cfg.parity, stopbits=cfg.stopbits, timeout=cfg.timeout_s,
                retries=cfg.retries, reconnect_delay=0)
        self.lock = threading.RLock() if line is None else line.lock
        if line is None and not self.client.connect():
            raise AdapterError(f"{self.where}: cannot connect; check the PLC address, port and "
                               "cable (robot.modbus/probe.modbus host, port)")
        self._wd = 0
        self.kick()  # first sign of life; give the PLC two scans to see it
        self.sleep(2 * cfg.poll_s)
        self._stop = threading.Event()
        self._dog = threading.Thread(target=self._watchdog, daemon=True, name="modbus-watchdog")
        self._dog.start()

    # -- raw operations ------------------------------------------------------------------
    def _op(self, what: str, fn):
        with self.lock:
            for attempt in (0, 1):
                try:
                    resp = fn()
                except (ModbusException, OSError) as e:
                    if attempt == 0:
                        log.warning("%s: %s failed (%s); reconnecting once", self.where, what, e)
                        self.client.close()
                        if self.client.connect():
                            continue
                    raise AdapterError(f"{self.where}: link lost during {what} ({e}); check the "
                                       f"PLC, the cable and device_id {self.cfg.device_id} (the "
                                       "PLC's station number: a device that is not there does "
                                       "not answer), then continue with --resume") from e
                if resp.isError():
                    raise AdapterError(f"{self.where}: the PLC refused {what}: "
                                       f"{_refusal(resp, self.cfg.device_id)}")
                return resp
        raise AssertionError("unreachable")

    def read_bit(self, role: str) -> bool:
        a, dev = self.map[role], self.cfg.device_id
        if a.word_flag:  # DOP $Mn: a holding register, set when non-zero
            return bool(self.read_words(role, 1)[0])
        f = self.client.read_coils if a.table == "coil" else self.client.read_discrete_inputs
        return bool(self._op(f"read {role} ({a.name})",
                             lambda: f(a.address, count=1, device_id=dev)).bits[0])

    def write_bit(self, role: str, value: bool) -> None:
        a = self.map[role]
        if a.word_flag:
            return self.write_words(role, [1 if value else 0])
        self._op(f"write {role} ({a.name})", lambda: self.client.write_coil(
            a.address, value, device_id=self.cfg.device_id))

    def read_words(self, role: str, count: int) -> list[int]:
        a, dev = self.map[role], self.cfg.device_id
        f = self.client.read_holding_registers if a.table == "hr" else self.client.read_input_registers
        return list(self._op(f"read {role} ({a.name})",
                             lambda: f(a.address, count=count, device_id=dev)).registers)

    def write_words(self, role: str, words: list[int]) -> None:
        a = self.map[role]
        self._op(f"write {role} ({a.name})", lambda: self.client.write_registers(
            a.address, words, device_id=self.cfg.device_id))

    # -- values in mm --------------------------------------------------------------------
    def to_words(self, role: str, mm: float) -> list[int]:
        c, v = self.cfg, mm * self.cfg.scale
        if c.number == "float32":
            return self.client.convert_to_registers(v, DT.FLOAT32, word_order=c.word_order)
        n, bits = round(v), (16 if c.number == "int16" else 32)
        if not -(2 ** (bits - 1)) <= n < 2 ** (bits - 1):
            raise AdapterError(f"{self.where}: {role}={mm} mm x scale {c.scale:g} does not fit "
                               f"in {c.number}; start was not set (check modbus.scale and "
                               "modbus.number against the workspace)")
        if c.number == "int16":
            return [n & 0xFFFF]
        return self.client.convert_to_registers(n, DT.INT32, word_order=c.word_order)

    def from_words(self, words: list[int]) -> float:
        c = self.cfg
        if c.number == "int16":
            return struct.unpack("<h", struct.pack("<H", words[0]))[0] / c.scale
        dt = DT.FLOAT32 if c.number == "float32" else DT.INT32
        return float(self.client.convert_from_registers(words, dt, word_order=c.word_order)) / c.scale

    def write_mm(self, role: str, mm: float) -> None:
        self.write_words(role, self.to_words(role, mm))

    def read_mm(self, role: str) -> tuple[float, list[int]]:
        words = self.read_words(role, self.words)
        return self.from_words(words), words

    # -- supervision ---------------------------------------------------------------------
    def kick(self) -> None:
        self._wd = (self._wd + 1) & 0xFFFF
        self.write_words("watchdog", [self._wd])

    def _watchdog(self) -> None:
        while not self._stop.wait(self.cfg.watchdog_s / 4):
            try:
                self.kick()
            except AdapterError as e:  # the main thread sees the lost link on its next call
                log.warning("%s: watchdog write failed: %s", self.where, e)

    def check_fault(self) -> None:
        if self.read_bit("fault"):
            a = self.map["fault"].name
            raise AdapterError(f"{self.where}: the PLC fault flag {a} is set (e-stop, door, "
                               "watchdog or robot alarm); clear it at the HMI, then continue "
                               "with --resume")

    def close(self) -> None:
        self._stop.set()
        self._dog.join(timeout=1.0)
        if self.owns_client:  # a link on another's line leaves the port to it
            with self.lock:
                self.client.close()


class ModbusProbe:
    """Probe samples from a PLC/HMI register, triggered, with a staleness counter."""

    def __init__(self, link: ModbusLink):
        self.link = link
        self.off_since: float | None = None  # since when the trigger is known to be off

    def read(self) -> Sample:
        k = self.link
        k.check_fault()
        before = k.read_words("probe_count", 1)[0]
        # a rising edge is what one scan sees against the one before: the trigger must have been
        # off for a whole scan when it is set -- written off where it was left set (a PLC that
        # missed it), and after the PLC cleared it (with the count), a scan must see it off
        if k.read_bit("probe_trigger"):
            k.write_bit("probe_trigger", False)
            self.off_since = k.clock()
        elif self.off_since is None:  # off, since when unknown: count from now
            self.off_since = k.clock()
        if (wait := self.off_since + k.cfg.scan_s - k.clock()) > 0:
            k.sleep(wait)
        k.write_bit("probe_trigger", True)
        self.off_since = None
        start = k.clock()
        while k.read_words("probe_count", 1)[0] == before:
            if k.clock() - start > k.cfg.probe_timeout_s:
                raise BadSample(f"{k.where}: probe_count ({k.map['probe_count'].name}) did not "
                                f"advance within {k.cfg.probe_timeout_s} s: the value is stale")
            k.sleep(k.cfg.poll_s)
        self.off_since = k.clock()  # the PLC clears the trigger in the scan that counts
        value, words = k.read_mm("probe_value")
        raw = struct.pack(f">{len(words)}H", *words)
        if not math.isfinite(value):
            raise BadSample(f"{k.where}: probe value {value} is not a number", raw)
        return Sample(value, k.clock(), raw)

    def close(self) -> None:
        self.link.close()


# Modbus Application Protocol V1.1b3, s.7: exception codes
EXCEPTIONS = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
              4: "server device failure", 5: "acknowledge", 6: "server device busy",
              8: "memory parity error", 10: "gateway path unavailable",
              11: "gateway target device failed to respond"}


def _refusal(resp, device_id: int) -> str:
    """A refusal in words: its exception code and what to check."""
    code = getattr(resp, "exception_code", None)
    if code is None:
        return f"{resp}; check the register map in robot.modbus.registers"
    said = f"exception {code} ({EXCEPTIONS.get(code, 'unknown')}) from device_id {device_id}"
    if code in (2, 3):
        return f"{said}; check the register map in robot.modbus.registers"
    if code in (4, 10, 11):
        return (f"{said}; check robot.modbus.device_id (the PLC's station number, or the unit "
                "behind a gateway) and that the PLC is running")
    return f"{said}; check the PLC"
