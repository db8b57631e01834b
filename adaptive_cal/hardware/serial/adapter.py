"""The ``serial`` probe adapter: digital indicators over pyserial.

Presets (HARDWARE.md; request strings marked verify were not confirmed on a device):

| preset | line | request | answer |
|---|---|---|---|
| mitutoyo | 9600 8N1 | ``1\\r`` (verify) | ``01A+0000.123\\r`` |
| sylvac | 4800 7E2, two-way cable: DTR on, RTS off | ``?\\r`` | ``+0.1234\\r``; tolerance mode ``+0.1234=`` (``<`` below, ``>`` above the limits); errors ``ERR<n>\\r`` |
| keyence | 9600 8N1 (verify) | ``M0\\r\\n`` | ``M0,+012.3456,...\\r\\n``; errors ``ER,M0,<code>\\r\\n`` |

A gauge that echoes the request sends it back before the answer: the echo is skipped. The Sylvac
one-way cable (a value requested by dropping DTR for >= 110 ms) is not supported.
| custom | from the config | ``request`` | ``pattern`` with one group, times ``scale`` |
"""
from __future__ import annotations

import codecs
import math
import re
import time
from dataclasses import dataclass

import serial

from adaptive_cal.hardware.base import AdapterError, BadSample, Sample
from adaptive_cal.hardware.serial.config import SerialConfig


@dataclass(frozen=True)
class Preset:
    baudrate: int
    bytesize: int
    parity: str
    stopbits: int
    request: bytes
    pattern: str
    dtr: bool | None = None
    rts: bool | None = None


PRESETS = {
    # Mitutoyo's output always carries the decimal point: 01A+00000123 is no reading
    "mitutoyo": Preset(9600, 8, "N", 1, b"1\r", r"^\d{2}A([-+]\s*\d+\.\d+)\s*$"),
    "sylvac": Preset(4800, 7, "E", 2, b"?\r", r"^([-+]?\s*\d+(?:\.\d+)?)\s*[<=>]?\s*$",
                     True, False),
    "keyence": Preset(9600, 8, "N", 1, b"M0\r\n", r"^M0,([-+]?\d+(?:\.\d+)?)(?:,.*)?$"),
    "custom": Preset(9600, 8, "N", 1, b"", ""),
}
ERROR = re.compile(rb"^(ERR\s*\d*|E\d+)", re.I)
KEYENCE_ERROR = re.compile(rb"^ER,(\w+),(\d+)")  # ER,<command>,<error code>
# the DL-RS1A manual: readouts that are no value -- letters in place of the digits (+EE.EEE: the
# amplifier's error) or the display range's end (+-99.999: the value is there or beyond); a run
# of F (an outside audit's over-range readout, not in the manual pages found) is refused too
KEYENCE_NO_VALUE = re.compile(rb"^M\d,\s*([-+]?(?:[EF]+\.?[EF]*|0*99\.9+))\s*(?:,|$)")


def unescape(text: str) -> bytes:
    """``"?\\r"`` as written in YAML -> the bytes ``?`` CR."""
    return codecs.decode(text, "unicode_escape").encode("latin-1")


def parse(line: bytes, pattern: str, scale: float, decimals: int | None = None) -> float:
    """One answer line -> value in mm; BadSample (with the raw bytes) when it does not parse,
    or, with ``decimals``, when its number has another count of digits after the point."""
    text = line.decode("ascii", "replace").strip()
    if m := KEYENCE_ERROR.match(line.strip()):
        cmd, code = (g.decode("ascii", "replace") for g in m.groups())
        raise BadSample(f"gauge reported error code {code} to command {cmd} ({text!r}); see "
                        "the gauge manual's error table", line)
    if m := KEYENCE_NO_VALUE.match(line.strip()):
        raise BadSample(f"gauge answer {text!r}: {m.group(1).decode()} is no reading but the "
                        "amplifier's out-of-range or error readout (DL-RS1A manual: +EE.EEE an "
                        "amplifier error, +-99.999 at or beyond the display range); check the "
                        "sensor head's position and the amplifier", line)
    if ERROR.match(line.strip()):
        raise BadSample(f"gauge reported an error {text!r} (out of range or not zeroed?)", line)
    m = re.search(pattern, text)
    if not m:
        raise BadSample(f"gauge answer {text!r} does not match the expected format {pattern!r}; "
                        "check the preset, baud rate and parity", line)
    group = m.group("value") if "value" in m.re.groupindex else m.group(1)
    if decimals is not None:
        got = len(group.split(".", 1)[1]) if "." in group else 0
        if got != decimals:
            raise BadSample(f"gauge answer {text!r} has {got} digits after the point, "
                            f"probe.serial.decimals is {decimals}: a gauge switched to inches, or "
                            "digits lost on the line", line)
    try:
        value = float(group.replace(" ", "")) * scale
    except ValueError:
        raise BadSample(f"gauge answer {text!r}: {group!r} is not a number", line) from None
    if not math.isfinite(value):
        raise BadSample(f"gauge answer {text!r} is not a finite number", line)
    return value


class SerialProbe:
    """A gauge on a serial port or a pyserial URL (``socket://host:port``)."""

    def __init__(self, cfg: SerialConfig, *, clock=time.monotonic):
        p = PRESETS[cfg.preset]
        self.cfg, self.clock = cfg, clock
        self.request = unescape(cfg.request) if cfg.request is not None else p.request
        self.pattern = cfg.pattern or p.pattern
        self.scale = cfg.scale
        self._suspect = False  # a request went unanswered: its answer may still come
        self._pending = b""  # a byte read past a CR that was not its LF
        try:
            self.port = serial.serial_for_url(
                cfg.port, do_not_open=True, baudrate=cfg.baudrate or p.baudrate,
                bytesize=cfg.bytesize or p.bytesize, parity=cfg.parity or p.parity,
                stopbits=cfg.stopbits or p.stopbits, timeout=cfg.timeout_s,
                write_timeout=cfg.timeout_s)
            dtr = cfg.dtr if cfg.dtr is not None else p.dtr
            rts = cfg.rts if cfg.rts is not None else p.rts
            if dtr is not None:
                self.port.dtr = dtr
            if rts is not None:
                self.port.rts = rts
            self.port.open()
        except (serial.SerialException, ValueError, OSError) as e:
            raise AdapterError(f"probe.serial.port={cfg.port!r}: cannot open ({e}); check the "
                               "cable, the device name and that no other program holds it") from e

    def read(self) -> Sample:
        late = b""
        try:
            self.port.reset_input_buffer()  # a late answer to an earlier request is stale
            self._pending = b""
            if self.request:
                self.port.write(self.request)
            else:  # a streaming gauge is mid-line now: its tail ("1.2345" of "-1.2345") is
                self._line()  # no value -- drop it, read the next whole line
            line = self._line()
            if self.request and line.strip() == self.request.strip():
                line = self._line()  # the gauge echoed the request: skip it
            if self._suspect and self.request and line.endswith((b"\r", b"\n")):
                late = self._line()  # a second answer: one of the two is a late one
        except (serial.SerialException, OSError) as e:
            raise AdapterError(f"probe.serial.port={self.cfg.port!r}: link lost ({e}); "
                               "reconnect the gauge and continue with --resume") from e
        t = self.clock()
        if not line or not line.endswith((b"\r", b"\n")):
            if self.request:
                self._drain()
            raise BadSample(f"gauge on {self.cfg.port} did not answer within "
                            f"{self.cfg.timeout_s} s (got {line!r}); check power (DTR/RTS), "
                            "baud rate and the request string", line)
        if late.strip():
            raise BadSample(f"gauge on {self.cfg.port} sent two answers to one request "
                            f"({line!r}, then {late!r}) after an earlier request went "
                            "unanswered: one is that request's late answer, so neither is used",
                            line + late)
        self._suspect = False
        value = parse(line, self.pattern, self.scale, self.cfg.decimals)
        rng = self.cfg.range_mm
        if rng and not rng[0] <= value <= rng[1]:
            raise BadSample(f"gauge value {value} mm is outside probe.serial.range_mm "
                            f"{list(rng)}", line)
        return Sample(value, t, line)

    def _line(self) -> bytes:
        """One answer line, ended by CR or LF, whichever the gauge sends (the line end guessed
        from the request made a gauge answering a CR request with LF wait timeout_s for every
        sample); empty lines (the LF of a CR LF pair) skipped. What came within about
        timeout_s when no line end did."""
        deadline, out = time.monotonic() + self.cfg.timeout_s, bytearray()
        while time.monotonic() < deadline:
            b, self._pending = (self._pending[:1], self._pending[1:]) if self._pending \
                else (self.port.read(1), b"")
            if not b:
                break
            if b not in (b"\r", b"\n"):
                out += b
            elif not out.strip():
                out.clear()
            else:  # a CR LF pair is one line end (the raw bytes keep both)
                if b == b"\r" and (self.port.in_waiting or self.request.endswith(b"\r\n")):
                    after = self.port.read(1)
                    if after == b"\n":
                        return bytes(out + b + after)
                    self._pending = after  # the next line's first byte
                return bytes(out + b)
        return bytes(out)

    def _drain(self) -> None:
        """After a request that timed out: its answer may still come, and the next request
        would take it for its own (reset_input_buffer drops only what has arrived). Drop what
        arrives until the line has been quiet for timeout_s (at most 3 x timeout_s); an answer
        later than that is caught by the next read, which then waits for a second line
        (``_suspect``) and uses neither when one comes."""
        self._suspect = True
        end = time.monotonic() + 3 * self.cfg.timeout_s
        try:
            while time.monotonic() < end and self.port.read(max(1, self.port.in_waiting)):
                pass
        except (serial.SerialException, OSError):
            pass  # the next read says the link is lost

    def close(self) -> None:
        self.port.close()
