"""An emulated digital indicator answering like the serial presets, over a TCP socket (for
``socket://host:port``) or a pty (a real serial device node). Each answer is one reading of the
EmulatedRobot at the pose it reached.
"""
from __future__ import annotations

import os
import socket
import threading
import time
from dataclasses import dataclass
from typing import Callable

from adaptive_cal.hardware.serial.adapter import PRESETS, unescape
from adaptive_cal.hardware.serial.config import SerialConfig


def answer_line(preset: str, reading_mm: float, scale: float = 1.0) -> bytes:
    """The line a gauge of ``preset`` sends for ``reading_mm``."""
    if preset == "mitutoyo":  # 99MAF600B: 01 A sign D5-D12 (8 characters, point included) CR
        return f"01A{reading_mm:+09.4f}\r".encode()
    if preset == "sylvac":
        return f"{reading_mm:+.4f}\r".encode()
    if preset == "keyence":
        return f"M0,{reading_mm:+08.4f},+000.0000\r\n".encode()
    return f"{reading_mm / scale:+.5f}\r\n".encode()


@dataclass
class GaugeFaults:
    silent: int = 0          # the next N requests get no answer (timeout)
    garbage: int = 0         # the next N requests get garbage
    error: int = 0           # the next N requests get ERR3 (Keyence: ER,M0,02)
    echo: bool = False       # the request is echoed before each answer
    late: int = 0            # the next N requests are answered late_s after the request
    late_s: float = 0.0


class GaugeResponder:
    """Answers requests read from a channel with lines built from ``reading()``."""

    def __init__(self, cfg: SerialConfig, reading: Callable[[], float]):
        self.cfg, self.reading = cfg, reading
        self.request = unescape(cfg.request) if cfg.request is not None else PRESETS[cfg.preset].request
        self.faults = GaugeFaults()
        self.answered = 0

    def reply(self) -> bytes:
        f = self.faults
        if f.silent > 0:
            f.silent -= 1
            return b""
        if f.garbage > 0:
            f.garbage -= 1
            return b"\x7f#?!garbage\r\n"
        echo = self.request if f.echo else b""
        if f.error > 0:
            f.error -= 1
            return echo + (b"ER,M0,02\r\n" if self.cfg.preset == "keyence" else b"ERR3\r")
        self.answered += 1
        return echo + answer_line(self.cfg.preset, self.reading(), self.cfg.scale)

    def serve(self, recv: Callable[[], bytes], send: Callable[[bytes], None],
              stop: threading.Event) -> None:
        buf = b""
        while not stop.is_set():
            if not self.request:  # a streaming gauge
                send(self.reply())
                time.sleep(0.05)
                continue
            try:
                chunk = recv()
            except OSError:
                return
            if chunk is None:
                continue
            if chunk == b"":
                return
            buf += chunk
            while self.request in buf:
                buf = buf.split(self.request, 1)[1]
                out = self.reply()
                if out and self.faults.late > 0:  # the answer of now, sent later
                    self.faults.late -= 1
                    threading.Timer(self.faults.late_s, send, (out,)).start()
                elif out:
                    send(out)


class GaugeServer:
    """TCP server for ``socket://127.0.0.1:port``; one client at a time; port 0 picks one."""

    def __init__(self, cfg: SerialConfig, reading: Callable[[], float], host="127.0.0.1", port=0):
        self.responder = GaugeResponder(cfg, reading)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(4)
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True, name="gauge-emulator")

    @property
    def faults(self) -> GaugeFaults:
        return self.responder.faults

    def start(self) -> "GaugeServer":
        self._thread.start()
        return self

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except (socket.timeout, OSError):
                continue
            conn.settimeout(0.05)

            def recv(c=conn):
                try:
                    return c.recv(256)
                except socket.timeout:
                    return None

            with conn:
                self.responder.serve(recv, conn.sendall, self._stop)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.sock.close()


class PtyGauge:
    """The gauge on a pty pair: open ``path`` with pyserial like a real port."""

    def __init__(self, cfg: SerialConfig, reading: Callable[[], float]):
        import select
        import tty

        self.responder = GaugeResponder(cfg, reading)
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self._stop = threading.Event()

        def recv():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            return os.read(self.master, 256) if ready else None

        self._thread = threading.Thread(
            target=self.responder.serve, args=(recv, lambda b: os.write(self.master, b),
                                               self._stop), daemon=True, name="pty-gauge")

    @property
    def faults(self) -> GaugeFaults:
        return self.responder.faults

    def start(self) -> "PtyGauge":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        os.close(self.master)
        os.close(self.slave)
