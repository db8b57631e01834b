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
    """The controller refused a command or stopped a move; ``added`` is its added-status code;
    ``alarm`` / ``error``: status data 2 showed an alarm / an error (only these may be reset)."""

    def __init__(self, message: str, status: int = 0, added: int = 0, *, alarm: bool = False,
                 error: bool = False):
        super().__init__(message)
        self.status, self.added, self.alarm, self.error = status, added, alarm, error


class HsesMotion:
    """Motion protocol over HSES. ``pose`` is kept in the workplane frame (mm)."""

    def __init__(self, cfg: HsesConfig, *, sleep=time.sleep, clock=time.monotonic):
        self.cfg, self.sleep, self.clock = cfg, sleep, clock
        self.where = f"robot.hses {cfg.host}:{cfg.port}"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((cfg.host, cfg.port))
        self._id = self.sends = 0
        self.pose: tuple[float, float, float] | None = None
        self.dropped, self.descent_alarm = 0, False  # an alarm in a descent: none reset after
        d1, _ = self.status()
        if not d1 & P.REMOTE:
            raise AdapterError(f"{self.where}: command remote is off; set the pendant to REMOTE "
                               "and enable command remote")
        # the arm's configuration as it stands ("current"; the expanded form with it), or
        # the number robot.hses.form gives (expanded form 0)
        self.form, self.expanded_form = ((cfg.form, 0) if cfg.form != "current"
                                         else self._current_form())
        self.servo_on()

    # -- transport --------------------------------------------------------------------
    def request(self, command: int, instance: int, attribute: int, service: int,
                payload: bytes = b"") -> P.Answer:
        """Send one request and return the answer with its request id (re-sent on timeout)."""
        for attempt in range(self.cfg.retries + 1):
            self.sends = attempt + 1  # > 1: an earlier send may have reached the controller
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

    def servo_on(self) -> None:
        """Switch servo power on and wait until status data 2 shows it (a controller takes a
        moment; a move before that is refused with 0x2070)."""
        self.servo(True)
        deadline = self.clock() + self.cfg.servo_timeout_s
        while not self.status()[1] & P.SERVO:
            if self.clock() > deadline:
                raise AdapterError(
                    f"{self.where}: servo power did not come on within robot.hses."
                    f"servo_timeout_s = {self.cfg.servo_timeout_s:g} s of switching it on "
                    "(0x83 instance 2 was accepted): check the emergency stops, the door and "
                    "the safety fence, then continue with --resume; nothing moved")
            self.sleep(self.cfg.poll_s)

    def alarm(self) -> tuple[int, str]:
        """The latest alarm (0x70, instance 1): (code, name); code 0 when none stands."""
        try:
            return P.unpack_alarm(self.call(P.CMD_ALARM, 1, 0, P.GET_ALL))
        except ValueError as e:
            raise AdapterError(f"{self.where}: {e}") from None

    def reset_alarm(self) -> None:
        """0x82 instance 1: reset the alarms."""
        self.call(P.CMD_ALARM_RESET, P.ALARM_RESET, 1, P.SET_ONE, struct.pack("<I", 1))

    def cancel_error(self) -> None:
        """0x82 instance 2: cancel an error (the manual; fs100's RESET_ALARM_TYPE_ERROR)."""
        self.call(P.CMD_ALARM_RESET, P.ERROR_CANCEL, 1, P.SET_ONE, struct.pack("<I", 1))

    def _current_form(self) -> tuple[int, int]:
        """The form (configuration bits) and expanded form of the robot's pose now, from a 0x75
        answer."""
        try:
            return P.unpack_form(self.call(P.CMD_POSITION, P.POSITION_INSTANCE, 0, P.GET_ALL))
        except ValueError as e:
            raise AdapterError(f"{self.where}: {e}") from None

    def robot_position(self) -> tuple[float, float, float]:
        """Position the controller reports: base frame (data type 16), mm, of robot.hses.tool."""
        try:
            return P.unpack_position(self.call(P.CMD_POSITION, P.POSITION_INSTANCE, 0, P.GET_ALL),
                                     tool=self.cfg.tool)
        except ValueError as e:
            raise AdapterError(f"{self.where}: {e}") from None

    def stopped_by(self, d1: int, d2: int, during: str) -> HsesError | None:
        """What in status (d1, d2) stops a move, as the error to raise; None when nothing does.
        Only an alarm or an error is marked resettable; a hold or servo off never is."""
        if d2 & (P.ALARM | P.ERROR):
            code, name = self.alarm() if d2 & P.ALARM else (0, "")
            what = (f"alarm {code} {name!r}" if code else "an alarm") if d2 & P.ALARM else ""
            if d2 & P.ERROR:
                what = f"{what} and an error" if what else "an error"
            return HsesError(f"{self.where}: the controller raised {what} {during}; "
                             f"{P.ADDED_STATUS[0x2060]}", 0xFF, 0x2060,
                             alarm=bool(d2 & P.ALARM), error=bool(d2 & P.ERROR))
        for bit, added in P.HOLD_BITS:
            if d2 & bit:
                return HsesError(f"{self.where}: THE ROBOT IS HELD by {P.HOLDS[added]} {during}; "
                                 f"it stays where it stopped. {P.ADDED_STATUS[added]}, then "
                                 "continue with --resume (a hold is never released from here)",
                                 0xFF, added)
        if not d2 & P.SERVO:
            return HsesError(f"{self.where}: SERVO POWER IS OFF {during} (e-stop, door, safety "
                             "fence, or switched off): find why and clear it, then continue "
                             "with --resume, which switches servo power on as every start does "
                             "(nothing here switches it on during a run)", 0xFF, 0x3010)
        return None

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
        """Where the tip is (mm, workplane frame): the last target reached; before the first
        move or after a stop, the position the controller reports, converted (with or without
        check_position), NaN only where no conversion is known (parked_at_safe_height)."""
        if self.pose is not None or not self.cfg.can_locate:
            return self.pose or (math.nan, math.nan, math.nan)
        ox, oy, oz = self.cfg.offset_mm
        x, y, z = self.from_base(self.robot_position())
        return x - ox, y - oy, z - oz

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        c = self.cfg
        target = tuple(v + o for v, o in zip((x_mm, y_mm, z_mm), c.offset_mm))
        payload = P.move_payload(target, c.orientation_deg, coord=P.COORD[c.frame],
                                 speed_mm_per_s=c.speed_mm_per_s, tool=c.tool,
                                 user_frame=c.user_frame if c.frame == "user" else 0,
                                 form=self.form, expanded_form=self.expanded_form)
        before, self.pose = self.pose, None  # unknown while moving: ask the controller
        reset, sent = c.reset_alarms, False
        # busy (0x2010: an earlier move still running) clears by itself: wait as long as a move
        deadline = self.clock() + c.move_timeout_s
        while True:
            try:
                try:
                    self.call(P.CMD_MOVE, 2, 1, P.SET_ALL, payload)
                except HsesError as e:
                    sent = sent or self.sends > 1  # a lost answer: an earlier send may move it
                    if e.added in P.RETRYABLE and self.sends > 1:
                        # the answer to an earlier send was lost: that send moves the robot now
                        log.warning("%s: the answer to the move was lost and the robot moves: "
                                    "waiting for it to stop, then reading where", self.where)
                        self._wait(target, before, confirm=True)
                        self.pose = (x_mm, y_mm, z_mm)
                        return
                    raise self._refusal(e) from None
                sent = True  # an alarm from here on came while the robot moved
                self._wait(target, before)
                self.pose = (x_mm, y_mm, z_mm)
                return
            except HsesError as e:
                if e.added in P.RETRYABLE and self.clock() < deadline:
                    self.sleep(c.poll_s)
                    continue
                if e.added in P.RETRYABLE:
                    break
                if reset and (e.alarm or e.error):
                    if self.descent_alarm or (sent and not self._rises(target, before)):
                        when = ("an alarm came during an earlier descent" if self.descent_alarm else
                                "it came while the robot moved down or from an unknown start")
                        self.descent_alarm = True  # nor the retract's (an audit): a collision?
                        raise HsesError(f"{e} -- not reset: {when} (reset_alarms never resets "
                                        "one during a descent: it may be a collision; reset it "
                                        "at the pendant)", e.status, e.added) from None
                    reset, sent = False, False  # one reset per move; a second alarm stops
                    self._reset(e)
                    continue
                raise
        raise AdapterError(f"{self.where}: the robot stayed busy (added status 0x2010) for "
                           f"move_timeout_s = {c.move_timeout_s:g} s; the move to ({x_mm:.3f}, "
                           f"{y_mm:.3f}, {z_mm:.3f}) was not sent")

    def _refusal(self, e: HsesError) -> HsesError:
        """A refused move, with alarm/error read from the status when the code is 0x2060 or the
        bare status 0x01 (yrcom's reading of a refusal, ``protocol.STATUS``: without a why)."""
        if e.added != 0x2060 and not (e.status == 0x01 and not e.added):
            return e
        d1, d2 = self.status()
        why = self.stopped_by(d1, d2, f"(the move was refused: status 0x{e.status:02X}, "
                                      f"added status 0x{e.added:04X})")
        if why is not None:
            return why
        if e.added == 0x2060:  # the bits cleared in between: take the code's word for it
            return HsesError(str(e), e.status, e.added, alarm=True)
        return e

    def _rises(self, target, before) -> bool:
        """Whether a move to ``target`` (frame of the moves) does not descend from the last
        pose reached, else from where the controller reports; False where neither is known."""
        if before is None and not self.cfg.can_locate:
            return False
        z0 = (before[2] + self.cfg.offset_mm[2] if before is not None
              else self.from_base(self.robot_position())[2])
        return target[2] >= z0 - 0.01

    def _reset(self, e: HsesError) -> None:
        """Reset a genuine alarm (0x82 instance 1) and/or cancel an error (instance 2); servo
        on again only when an alarm switched it off."""
        log.warning("%s: resetting (reset_alarms: true, once per move) and retrying: %s",
                    self.where, e)
        if e.alarm:
            self.reset_alarm()
        if e.error:
            self.cancel_error()
        d1, d2 = self.status()
        if d2 & (P.ALARM | P.ERROR):
            raise HsesError(f"{self.where}: the reset did not clear it ({e}); "
                            f"{P.ADDED_STATUS[0x2060]}", 0xFF, 0x2060) from e
        if not d2 & P.SERVO:
            if not e.alarm:
                raise self.stopped_by(d1, d2, "after an error was cancelled") or e
            self.servo_on()

    def _travel_s(self, target, before) -> float | None:
        """Straight-line time from where the move starts to ``target`` at the commanded speed,
        plus a margin; None where the start is not known."""
        c = self.cfg
        if before is not None:
            ox, oy, oz = c.offset_mm
            start = (before[0] + ox, before[1] + oy, before[2] + oz)
            d = math.dist(start, target)
        elif c.can_locate:
            d = math.dist(self.robot_position(), self.to_base(target))
        else:
            return None
        return d / c.speed_mm_per_s + max(0.5, 10 * c.poll_s)

    def _wait(self, target, before=None, confirm: bool = False) -> None:
        """Until the robot stands at ``target``: with check_position (or ``confirm``) the
        reported position must be there; without, the running bit must have come and gone, or
        the straight-line travel time at the commanded speed (plus a margin) have passed."""
        c = self.cfg
        check = c.check_position or confirm
        if check and not c.can_locate:
            raise AdapterError(
                f"{self.where}: the answer to the move was lost and the robot was already moving "
                "when it was re-sent; where it stopped cannot be checked without "
                "robot.hses.user_frame_in_base (check_position is false). Check the robot's "
                "position on the pendant, then continue with --resume")
        travel = None if check else self._travel_s(target, before)
        start, seen = self.clock(), False
        while self.clock() - start < c.move_timeout_s:
            d1, d2 = self.status()
            why = self.stopped_by(d1, d2, "during the move")
            if why is not None:
                raise why
            if d1 & P.RUNNING:
                seen = True
            elif not check:
                if seen or (travel is not None and self.clock() - start > travel):
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
