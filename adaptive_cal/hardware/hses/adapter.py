"""The ``hses`` motion adapter: a Yaskawa controller over the High Speed Ethernet Server (UDP).

Servo on at connect, linear absolute moves in the user (or base) frame, then status and position
polling until the robot stands at the target. The position read (0x75) answers in the base frame
(the manual), so the target is converted to the base frame with ``user_frame_in_base`` before
the two are compared. Every request carries a fresh request id; answers
with another id (late answers to earlier tries) are dropped. Unanswered requests are re-sent
``retries`` times, then the run stops with a message that says what to check.
"""
from __future__ import annotations

import logging
import math
import socket
import struct
import time

from adaptive_cal.hardware.hses import protocol as P
from adaptive_cal.hardware.hses.frames import base_to_user, user_to_base
from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.hses.config import HsesConfig

log = logging.getLogger(__name__)


class HsesError(AdapterError):
    """The controller refused a command; ``added`` is its added-status code."""

    def __init__(self, message: str, status: int = 0, added: int = 0):
        super().__init__(message)
        self.status, self.added = status, added


class HsesMotion:
    """Motion protocol over HSES. ``pose`` is kept in the workplane frame (mm)."""

    def __init__(self, cfg: HsesConfig, *, sleep=time.sleep, clock=time.monotonic):
        self.cfg, self.sleep, self.clock = cfg, sleep, clock
        self.where = f"robot.hses {cfg.host}:{cfg.port}"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((cfg.host, cfg.port))
        self._id = 0
        self.pose: tuple[float, float, float] | None = None
        self.dropped = 0
        d1, _ = self.status()
        if not d1 & P.REMOTE:
            raise AdapterError(f"{self.where}: command remote is off; set the pendant to REMOTE "
                               "and enable command remote")
        self.servo(True)

    # -- transport --------------------------------------------------------------------
    def request(self, command: int, instance: int, attribute: int, service: int,
                payload: bytes = b"") -> P.Answer:
        """Send one request and return the answer with its request id (re-sent on timeout)."""
        for attempt in range(self.cfg.retries + 1):
            self._id = (self._id + 1) % 256
            self.sock.send(P.encode_request(self._id, command, instance, attribute, service,
                                            payload))
            deadline = self.clock() + self.cfg.timeout_s
            while (left := deadline - self.clock()) > 0:
                self.sock.settimeout(left)
                try:
                    data = self.sock.recv(4096)
                except (socket.timeout, ConnectionRefusedError):
                    break
                try:
                    ans = P.decode_answer(data)
                except ValueError as e:
                    log.warning("%s: dropped a malformed packet: %s", self.where, e)
                    continue
                if ans.req_id != self._id:
                    self.dropped += 1
                    log.info("%s: dropped a late answer (id %d, waiting for %d)", self.where,
                             ans.req_id, self._id)
                    continue
                try:
                    return P.decode_answer(data, command, service)
                except ValueError as e:
                    raise AdapterError(f"{self.where}: the answer to command 0x{command:02X} "
                                       f"is in no known layout ({e}); is this an HSES "
                                       "server?") from None
            log.warning("%s: no answer to command 0x%02X (try %d of %d)", self.where, command,
                        attempt + 1, self.cfg.retries + 1)
        raise AdapterError(f"{self.where}: no answer to command 0x{command:02X} after "
                           f"{self.cfg.retries + 1} tries of {self.cfg.timeout_s} s; check the "
                           "network, the HSES option and the address, then continue with --resume")

    def call(self, command, instance, attribute, service, payload=b"") -> bytes:
        ans = self.request(command, instance, attribute, service, payload)
        if ans.status != 0:
            raise HsesError(f"{self.where}: command 0x{command:02X} refused, "
                            f"{P.explain(ans.status, ans.added)}", ans.status, ans.added)
        return ans.payload

    # -- controller -------------------------------------------------------------------
    def status(self) -> tuple[int, int]:
        data = self.call(P.CMD_STATUS, 1, 0, P.GET_ALL)
        if len(data) < 8:
            raise AdapterError(f"{self.where}: status answer of {len(data)} bytes, expected 8")
        return struct.unpack_from("<II", data)

    def servo(self, on: bool) -> None:
        self.call(P.CMD_SERVO, P.SERVO_POWER, 1, P.SET_ONE, struct.pack("<I", 1 if on else 2))

    def alarm(self) -> tuple[int, str]:
        """The latest alarm (0x70, instance 1): (code, name); code 0 when none stands."""
        try:
            return P.unpack_alarm(self.call(P.CMD_ALARM, 1, 0, P.GET_ALL))
        except ValueError as e:
            raise AdapterError(f"{self.where}: {e}") from None

    def reset_alarm(self) -> None:
        self.call(P.CMD_ALARM_RESET, 1, 1, P.SET_ONE, struct.pack("<I", 1))

    def robot_position(self) -> tuple[float, float, float]:
        """Position the controller reports: the base frame (data type 16), mm."""
        try:
            return P.unpack_position(self.call(P.CMD_POSITION, P.POSITION_INSTANCE, 0, P.GET_ALL))
        except ValueError as e:
            raise AdapterError(f"{self.where}: {e}") from None

    def to_base(self, p):
        """A point in the frame of the moves (user or base) -> the base frame."""
        u = self.cfg.user_frame_in_base
        return tuple(p) if self.cfg.frame == "base" else user_to_base(p, u.origin_mm,
                                                                      u.rotation_deg)

    def from_base(self, b):
        u = self.cfg.user_frame_in_base
        return tuple(b) if self.cfg.frame == "base" else base_to_user(b, u.origin_mm,
                                                                      u.rotation_deg)

    # -- Motion -----------------------------------------------------------------------
    def position(self) -> tuple[float, float, float]:
        if self.pose is not None or not self.cfg.check_position:
            return self.pose or (math.nan, math.nan, math.nan)
        ox, oy, oz = self.cfg.offset_mm
        x, y, z = self.from_base(self.robot_position())
        return x - ox, y - oy, z - oz

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        c = self.cfg
        target = tuple(v + o for v, o in zip((x_mm, y_mm, z_mm), c.offset_mm))
        payload = P.move_payload(target, c.orientation_deg, coord=P.COORD[c.frame],
                                 speed_mm_per_s=c.speed_mm_per_s, tool=c.tool,
                                 user_frame=c.user_frame if c.frame == "user" else 0)
        reset = c.reset_alarms
        for _ in range(c.retries + 2):
            try:
                self.call(P.CMD_MOVE, 2, 1, P.SET_ALL, payload)
                self._wait(target)
                self.pose = (x_mm, y_mm, z_mm)
                return
            except HsesError as e:
                if e.added in P.RETRYABLE:
                    self.sleep(c.poll_s)
                    continue
                if reset and (e.added == 0x2060 or e.status == 0xFF):
                    reset = False  # one reset per move; a second alarm stops the run
                    log.warning("%s: resetting a controller alarm (%s) and retrying", self.where, e)
                    self.reset_alarm()
                    self.servo(True)
                    continue
                self.pose = None  # where it stopped is not known: ask the controller next time
                raise
        raise AdapterError(f"{self.where}: the robot stayed busy; the move to "
                           f"({x_mm:.3f}, {y_mm:.3f}, {z_mm:.3f}) was not done")

    def _wait(self, target) -> None:
        c = self.cfg
        start = self.clock()
        while self.clock() - start < c.move_timeout_s:
            d1, d2 = self.status()
            if d2 & (P.ALARM | P.ERROR):
                code, name = self.alarm()
                what = f"alarm {code} {name!r}" if code else "an alarm"
                raise HsesError(f"{self.where}: the controller raised {what} during the move; "
                                f"{P.ADDED_STATUS[0x2060]}", 0xFF, 0x2060)
            if d2 & P.HOLD_MASK:
                raise HsesError(f"{self.where}: the robot is held; {P.ADDED_STATUS[0x2050]}",
                                0xFF, 0x2050)
            if not d2 & P.SERVO:
                raise HsesError(f"{self.where}: servo power went off; check the e-stops",
                                0xFF, 0x3010)
            if not d1 & P.RUNNING:
                if not c.check_position:
                    if self.clock() - start > 2 * c.poll_s:
                        return
                else:
                    got, want = self.robot_position(), self.to_base(target)
                    err = math.dist(got, want)
                    if err <= c.position_tolerance_mm:
                        return
                    if self.clock() - start > max(0.5, 10 * c.poll_s):
                        raise AdapterError(
                            f"{self.where}: the robot stopped {err:.3f} mm from the target "
                            f"{tuple(round(v, 3) for v in want)} (base frame; reported "
                            f"{tuple(round(v, 3) for v in got)}); check robot.hses.frame, "
                            "user_frame, user_frame_in_base and offset_mm, or set "
                            "check_position: false")
            self.sleep(c.poll_s)
        raise AdapterError(f"{self.where}: the move did not finish within "
                           f"robot.hses.move_timeout_s={c.move_timeout_s} s")

    def close(self) -> None:
        self.sock.close()
