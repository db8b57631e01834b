"""An emulated Yaskawa controller speaking HSES on UDP, backed by an EmulatedRobot.

It answers alarm (0x70), status (0x72), position (0x75, base frame, data type 16, as the manual
says), hold / servo / HLOCK (0x83 instances 1 / 2 / 3), alarm reset (0x82) and linear moves
(0x8A, in the base or the user frame) with the packet layout of ``hardware.hses.protocol``;
anything else gets status 0x08 (command not defined). The plate lies at ``offset_mm`` in the
user frame (``plate_frame='user'``) or the base frame; the user frame lies at ``user_frame``
(origin mm, Rx Ry Rz deg) in the base frame. Faults for tests are set on ``faults``.
"""
from __future__ import annotations

import logging
import socket
import struct
import threading
from dataclasses import dataclass

from adaptive_cal.hardware.hses import protocol as P
from adaptive_cal.hardware.hses.frames import base_to_user, user_to_base
from adaptive_cal.simulation.emulator.robot import EmulatedRobot

log = logging.getLogger(__name__)


@dataclass
class HsesFaults:
    """Injected faults: answers dropped or delayed, an alarm raised during a move."""

    drop_answers: int = 0      # the next N answers are not sent
    delay_answers: int = 0     # the next N answers are sent late, after delay_s
    delay_s: float = 0.0
    alarm_on_move: int = 0     # the next N moves stop with an alarm (reset clears it)
    remote: bool = True        # command remote on
    report_error_mm: float = 0.0  # reported x differs (another frame, or stopped short)


class HsesServer:
    """Serve HSES on (host, port); port 0 picks a free one (see ``port``)."""

    def __init__(self, robot: EmulatedRobot, host: str = "127.0.0.1", port: int = 0,
                 offset_mm=(0.0, 0.0, 0.0), user_frame=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                 plate_frame: str = "user"):
        self.robot, self.offset = robot, tuple(offset_mm)
        self.user_frame, self.plate_frame = (tuple(user_frame[0]), tuple(user_frame[1])), plate_frame
        self.faults = HsesFaults()
        self.servo = self.hold = self.hlock = False
        self.requests: list[P.Request] = []
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="hses-emulator")

    def start(self) -> "HsesServer":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.sock.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, peer = self.sock.recvfrom(4096)
            except (socket.timeout, OSError):
                continue
            try:
                req = P.decode_request(data)
            except ValueError as e:
                log.warning("hses emulator: dropped a malformed request: %s", e)
                continue
            self.requests.append(req)
            answer = self.handle(req)
            f = self.faults
            if f.drop_answers > 0:
                f.drop_answers -= 1
                continue
            if f.delay_answers > 0:
                f.delay_answers -= 1
                threading.Timer(f.delay_s, self._send, (answer, peer)).start()
                continue
            self._send(answer, peer)

    def _send(self, answer: bytes, peer) -> None:
        try:
            self.sock.sendto(answer, peer)
        except OSError:
            pass

    # -- the controller ------------------------------------------------------------------
    def _error(self, req: P.Request, added: int) -> bytes:
        return P.encode_answer(req.req_id, req.service, 0x1F, added)

    def to_base(self, workplane_xyz) -> tuple:
        p = tuple(v + o for v, o in zip(workplane_xyz, self.offset))
        return user_to_base(p, *self.user_frame) if self.plate_frame == "user" else p

    def to_workplane(self, base_xyz) -> tuple:
        p = base_to_user(base_xyz, *self.user_frame) if self.plate_frame == "user" else base_xyz
        return tuple(v - o for v, o in zip(p, self.offset))

    def _switch(self, req: P.Request) -> bytes:
        """0x83: instance 1 hold, 2 servo power, 3 HLOCK; data 1 on, 2 off."""
        if req.service != P.SET_ONE or len(req.payload) < 4:
            return P.encode_answer(req.req_id, req.service, 0x09, 0)  # bad data size
        value = struct.unpack_from("<I", req.payload)[0]
        if value not in (1, 2) or req.instance not in (P.HOLD, P.SERVO_POWER, P.HLOCK):
            return P.encode_answer(req.req_id, req.service, 0x05, 0)  # instance/data out of range
        on = value == 1
        if req.instance == P.SERVO_POWER:
            if on and self.robot.alarm:
                return self._error(req, 0x2060)
            self.servo = on
        elif req.instance == P.HOLD:
            self.hold = on
            if on:
                self.robot.stop()
        else:
            self.hlock = on
        return P.encode_answer(req.req_id, req.service, 0, 0)

    def handle(self, req: P.Request) -> bytes:
        r, ok = self.robot, (lambda payload=b"": P.encode_answer(req.req_id, req.service, 0, 0,
                                                                  payload))
        if req.command == P.CMD_STATUS:
            d1 = P.PLAY | (P.REMOTE if self.faults.remote else 0)
            d1 |= P.RUNNING if r.moving() else 0
            d2 = (P.SERVO if self.servo else 0) | (P.ALARM if r.alarm else 0)
            d2 |= 0x08 if self.hold else 0  # hold by command
            return ok(struct.pack("<II", d1, d2))
        if req.command == P.CMD_ALARM and req.service == P.GET_ALL and 1 <= req.instance <= 4:
            if r.alarm and req.instance == 1:
                return ok(P.alarm_payload(4100, 1, 1, "2026/01/01 00:00", "EMULATED ALARM"))
            return ok(P.alarm_payload())
        if req.command == P.CMD_POSITION and req.instance == P.POSITION_INSTANCE:
            x, y, z = self.to_base(r.pose())
            x += self.faults.report_error_mm
            return ok(P.position_payload((x, y, z), (180.0, 0.0, 0.0)))
        if req.command == P.CMD_ALARM_RESET:
            r.alarm = False
            return ok()
        if req.command == P.CMD_SERVO:
            return self._switch(req)
        if req.command == P.CMD_MOVE and req.instance == 2 and req.service == P.SET_ALL:
            if not self.faults.remote:
                return self._error(req, 0x2100)
            if r.alarm:
                return self._error(req, 0x2060)
            if self.hold:
                return self._error(req, 0x2040)
            if not self.servo:
                return self._error(req, 0x2070)
            if r.moving():
                return self._error(req, 0x2010)
            try:
                m = P.unpack_move(req.payload)
            except struct.error:
                return P.encode_answer(req.req_id, req.service, 0x09, 0)  # bad data size
            if m["coord"] not in (P.COORD["base"], P.COORD["user"]):
                return self._error(req, 0xB00B)
            if not 0 < m["speed_mm_per_s"] <= 1000:
                return self._error(req, 0xB009)
            base = (m["xyz_mm"] if m["coord"] == P.COORD["base"]
                    else user_to_base(m["xyz_mm"], *self.user_frame))
            r.command(*self.to_workplane(base))
            if self.faults.alarm_on_move > 0:  # the move starts, then the controller alarms
                self.faults.alarm_on_move -= 1
                r.stop()
                r.alarm, self.servo = True, False
            return ok()
        return P.encode_answer(req.req_id, req.service, 0x08, 0)  # command not defined
