"""An emulated Yaskawa controller speaking HSES on UDP, backed by an EmulatedRobot.

It answers alarm (0x70), status (0x72), position (0x75, base frame, data type 16, as the manual
says, of the tool of the last move), hold / servo / HLOCK (0x83 instances 1 / 2 / 3), alarm reset
/ error cancel (0x82 instances 1 / 2) and linear moves (0x8A instance 2, in the base or the user
frame) with the packet layout of ``hardware.hses.protocol``. Refusals as the manual's table: a
command hold 0x2050, external 0x2040, pendant 0x2020; status 0x1F with B003 for a data size
error, A001 for an instance a command does not have, B004 for a value out of range; status 0x28
for a data instance not emulated, 0x08 for a command not defined; a move for another robot than 1
(B008), in another speed class than V (B009) or another user frame than ``user_frame_no`` (B00E);
a get-one (0x0E) of attribute 0 (A002). A request whose header names another division than the
robot's (1) or another reserved field than '99999999' is not answered, as a controller would not
vouch for it (an outside audit, 2026-11-29: the emulator had taken every one of these, so a
regression in those words would have passed every test against it). The plate lies at ``offset_mm`` in the
user frame (``plate_frame='user'``) or the base frame; the user frame lies at ``user_frame``
(origin mm, Rx Ry Rz deg) in the base frame. Faults for tests are set on ``faults``.
"""
from __future__ import annotations

import logging
import socket
import struct
import threading
import time
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
    alarm_on_move: int = 0     # the next N moves stop with an alarm (0x82 instance 1 resets it)
    error_on_move: int = 0     # the next N moves stop with an error (0x82 instance 2 cancels it)
    hold_bits: int = 0         # status data 2 hold bits set from outside: 0x02 pendant, 0x04 external
    remote: bool = True        # command remote on
    report_error_mm: float = 0.0  # reported x differs (another frame, or stopped short)
    servo_delay_s: float = 0.0  # servo power shows (and moves are taken) this long after 0x83
    servo_never: bool = False   # servo power never comes on (an e-stop the PC cannot see)


class HsesServer:
    """Serve HSES on (host, port); port 0 picks a free one (see ``port``)."""

    def __init__(self, robot: EmulatedRobot, host: str = "127.0.0.1", port: int = 0,
                 offset_mm=(0.0, 0.0, 0.0), user_frame=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                 plate_frame: str = "user", user_frame_no: int = 1):
        self.robot, self.offset = robot, tuple(offset_mm)
        self.user_frame_no = user_frame_no  # the user frame the plate's frame is taught as
        self.user_frame, self.plate_frame = (tuple(user_frame[0]), tuple(user_frame[1])), plate_frame
        self.faults = HsesFaults()
        self.servo = self.hold = self.hlock = self.error = False
        self._servo_at = 0.0  # monotonic time from which a switched-on servo power shows
        self.tool = 0  # the tool of the last move: the position answer is of it
        self.form = 0  # the arm's configuration bits the position answer gives (word 1)
        self.expanded_form = 0  # and its expanded form (word 4: axes past 180 deg)
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
                _, _, _, _, division, _, _, _, reserved = P.HEAD.unpack_from(data)
                if division != 1 or reserved != P.RESERVED:
                    raise ValueError(f"division {division} (the robot's is 1), reserved field "
                                     f"{reserved!r} (the manual's is b'99999999')")
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

    def _status(self, req: P.Request, status: int) -> bytes:
        """A refusal with a status byte and no added status (0x08 command not defined, 0x28
        instance not present: the manual's status codes)."""
        return P.encode_answer(req.req_id, req.service, status, 0)

    def _set_one(self, req: P.Request, instances) -> tuple[int | None, bytes | None]:
        """(u32 value, None) of a set-one request, or (None, the manual's refusal): B003 for a
        size error, A001 for an instance this command does not have, B004 for a value not 1/2."""
        if req.instance not in instances:
            return None, self._error(req, 0xA001)
        if req.service != P.SET_ONE or len(req.payload) != 4:
            return None, self._error(req, 0xB003)
        value = struct.unpack_from("<I", req.payload)[0]
        if value not in (1, 2):
            return None, self._error(req, 0xB004)
        return value, None

    def to_base(self, workplane_xyz) -> tuple:
        p = tuple(v + o for v, o in zip(workplane_xyz, self.offset))
        return user_to_base(p, *self.user_frame) if self.plate_frame == "user" else p

    def servo_shows(self) -> bool:
        """Servo power is on and has come up (``faults.servo_delay_s`` after it was switched)."""
        return (self.servo and not self.faults.servo_never
                and time.monotonic() >= self._servo_at)

    def to_workplane(self, base_xyz) -> tuple:
        p = base_to_user(base_xyz, *self.user_frame) if self.plate_frame == "user" else base_xyz
        return tuple(v - o for v, o in zip(p, self.offset))

    def _switch(self, req: P.Request) -> bytes:
        """0x83: instance 1 hold, 2 servo power, 3 HLOCK; data 1 on, 2 off."""
        value, refused = self._set_one(req, (P.HOLD, P.SERVO_POWER, P.HLOCK))
        if refused:
            return refused
        on = value == 1
        if req.instance == P.SERVO_POWER:
            if on and (self.robot.alarm or self.error):
                return self._error(req, 0x2060)
            self.servo = on
            self._servo_at = time.monotonic() + (self.faults.servo_delay_s if on else 0.0)
        elif req.instance == P.HOLD:
            self.hold = on
            if on:
                self.robot.stop()
        else:
            self.hlock = on
        return P.encode_answer(req.req_id, req.service, 0, 0)

    def _reset(self, req: P.Request) -> bytes:
        """0x82: instance 1 resets the alarms, instance 2 cancels an error; data 1."""
        value, refused = self._set_one(req, (P.ALARM_RESET, P.ERROR_CANCEL))
        if refused:
            return refused
        if req.instance == P.ALARM_RESET:
            self.robot.alarm = False
        else:
            self.error = False
        return P.encode_answer(req.req_id, req.service, 0, 0)

    def handle(self, req: P.Request) -> bytes:
        r, ok = self.robot, (lambda payload=b"": P.encode_answer(req.req_id, req.service, 0, 0,
                                                                  payload))
        if req.service == P.GET_ONE and req.attribute == 0:
            return self._error(req, 0xA002)  # a get-one names its attribute
        if req.command == P.CMD_STATUS:
            d1 = P.PLAY | (P.REMOTE if self.faults.remote else 0)
            d1 |= P.RUNNING if r.moving() else 0
            d2 = (P.SERVO if self.servo_shows() else 0) | (P.ALARM if r.alarm else 0)
            d2 |= (P.ERROR if self.error else 0) | (self.faults.hold_bits & 0x06)
            d2 |= 0x08 if self.hold else 0  # hold by command
            if req.service == P.GET_ONE:  # one word: attribute 1 data 1, 2 data 2
                return (ok(struct.pack("<I", (d1, d2)[req.attribute - 1]))
                        if req.attribute in (1, 2) else self._error(req, 0xA002))
            return ok(struct.pack("<II", d1, d2))
        if req.command == P.CMD_ALARM:
            if not 1 <= req.instance <= 4:
                return self._status(req, 0x28)
            if r.alarm and req.instance == 1:
                return ok(P.alarm_payload(4100, 1, 1, "2026/01/01 00:00", "EMULATED ALARM"))
            return ok(P.alarm_payload())
        if req.command == P.CMD_POSITION:
            if req.instance != P.POSITION_INSTANCE:  # pulse and other groups: not emulated
                return self._status(req, 0x28)
            x, y, z = self.to_base(r.pose())
            x += self.faults.report_error_mm
            return ok(P.position_payload((x, y, z), (180.0, 0.0, 0.0), self.tool, self.form,
                                         self.expanded_form))
        if req.command == P.CMD_ALARM_RESET:
            return self._reset(req)
        if req.command == P.CMD_SERVO:
            return self._switch(req)
        if req.command == P.CMD_MOVE:
            if req.instance != 2:  # 1 (joint/link) and 3 (increment) are not emulated
                return self._status(req, 0x28)
            if not self.faults.remote:
                return self._error(req, 0x2100)
            if r.alarm or self.error:
                return self._error(req, 0x2060)
            if self.faults.hold_bits & 0x02:
                return self._error(req, 0x2020)  # hold by the programming pendant
            if self.faults.hold_bits & 0x04:
                return self._error(req, 0x2040)  # external hold
            if self.hold:
                return self._error(req, 0x2050)  # command hold (0x83 instance 1)
            if not self.servo_shows():
                return self._error(req, 0x2070)
            if r.moving():
                return self._error(req, 0x2010)
            if req.service != P.SET_ALL or len(req.payload) != 104:
                return self._error(req, 0xB003)  # data size error
            m = P.unpack_move(req.payload)
            if m["group"] != 1:
                return self._error(req, 0xB008)  # one robot here
            if m["coord"] not in (P.COORD["base"], P.COORD["user"]):
                return self._error(req, 0xB00B)
            if m["speed_class"] != 1 or not 0 < m["speed_mm_per_s"] <= 1000:
                return self._error(req, 0xB009)  # a linear move's speed: class 1, V
            if m["coord"] == P.COORD["user"] and m["user_frame"] != self.user_frame_no:
                return self._error(req, 0xB00E)
            base = (m["xyz_mm"] if m["coord"] == P.COORD["base"]
                    else user_to_base(m["xyz_mm"], *self.user_frame))
            r.command(*self.to_workplane(base))
            self.tool = m["tool"]
            if self.faults.alarm_on_move > 0:  # the move starts, then the controller alarms
                self.faults.alarm_on_move -= 1
                r.stop()
                r.alarm, self.servo = True, False
            elif self.faults.error_on_move > 0:  # an error stops the move; servo stays on
                self.faults.error_on_move -= 1
                r.stop()
                self.error = True
            return ok()
        return self._status(req, 0x08)  # command not defined
