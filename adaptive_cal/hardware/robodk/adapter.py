"""The ``robodk`` motion adapter: linear moves through the RoboDK API (robodk package, 6.x).

The workplane frame is a RoboDK reference frame (``frame_name``, corrected by the tilt that a
run reports); targets are poses in it with the tool orientation ``orientation_deg``, and the
station's active tool must be the probe tip. With ``run_on_robot`` the station drives the real
robot (RUNMODE_RUN_ROBOT through its driver); otherwise RoboDK only simulates the moves.

The robodk client is used unmodified, through its ``com_object`` hook: the socket it gets reads
exact byte counts (the client unpacks whatever one ``recv`` returns and loops forever on a closed
socket while reading a line), sends everything, and bounds the client's waits (up to 100 h while
a move runs) by ``timeout_s`` and a per-move timeout. A lost link is reported once, closed, and
every later call fails at once instead of talking into a desynchronised stream.
Tested against a fake RoboDK server (tests/fake_robodk.py), not against the RoboDK app:
see docs/adapters/robodk.md.
"""
from __future__ import annotations

import logging
import math
import socket
import struct
import warnings

from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.robodk.config import RobodkConfig

log = logging.getLogger(__name__)

# the client asks for timeouts this long (or none) only while it waits for a move to finish
_LONG_WAIT_S = 3600.0


class _LinkSocket(socket.socket):
    """The TCP socket the robodk client talks through (see the module docstring)."""

    def __init__(self, io_s: float, wait_s: float):
        super().__init__(socket.AF_INET, socket.SOCK_STREAM)
        # the client writes each command in several small pieces: without this, every call
        # waits on Nagle's algorithm and the peer's delayed ACK (RoboDK's -API_NODELAY)
        self.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.io_s, self.wait_s = io_s, wait_s

    def settimeout(self, t):
        super().settimeout(self.wait_s if t is None or t >= _LONG_WAIT_S else min(t, self.io_s))

    def recv(self, n, flags=0):
        if n <= 0:
            return super().recv(n, flags)
        parts, got = [], 0
        while got < n:
            part = super().recv(n - got, flags)
            if not part:
                raise ConnectionResetError("RoboDK closed the connection")
            parts.append(part)
            got += len(part)
        return b"".join(parts)

    def send(self, data, flags=0):
        self.sendall(data, flags)
        return len(data)


# what a broken link looks like from inside the client: the stream is no longer in step
_LINK_ERRORS = (OSError, struct.error, UnicodeDecodeError)
# statuses after which the client reads no message line, and the stream may be out of step:
# -1 and 100 or more (robolink's _check_status); the rest come with their message or none
_DESYNC = ("Communication problems", "Problems running function")


def _broken(e: Exception) -> bool:
    """Whether ``e`` leaves the link out of step: a socket error, or a status the client
    cannot place; any other error status comes whole, and the link stays usable."""
    return isinstance(e, _LINK_ERRORS) or str(e) in _DESYNC


class RobodkMotion:
    """Motion protocol over the RoboDK API.

    ``timeout_s`` bounds every answer but a move's end; a move may take
    ``move_timeout_s`` or, when that is None, 30 s + 3x its length at ``speed_mm_per_s``.
    """

    def __init__(self, cfg: RobodkConfig, *, timeout_s: float = 10.0,
                 move_timeout_s: float | None = None):
        with warnings.catch_warnings():  # robodk warns on any import of the package
            warnings.simplefilter("ignore", PendingDeprecationWarning)
            from robodk import robolink, robomath

        self.cfg, self.rm, self.rl = cfg, robomath, robolink
        self.where = f"robot.robodk {cfg.host}:{cfg.port}"
        self.timeout_s, self.move_timeout_s = float(timeout_s), move_timeout_s
        self._lost: str | None = None
        self._at: tuple[float, float, float] | None = None
        self._sock: _LinkSocket | None = None
        self.rdk = None

        def com() -> _LinkSocket:
            self._sock = _LinkSocket(self.timeout_s, self.timeout_s)
            return self._sock

        # an IP, never 'localhost': a failed connect must not try to launch the RoboDK app
        host = "127.0.0.1" if cfg.host.lower() == "localhost" else cfg.host
        try:
            self.rdk = robolink.Robolink(robodk_ip=host, port=cfg.port, close_std_out=True,
                                         com_object=com)
        except Exception as e:
            self._drop()
            raise AdapterError(f"{self.where}: cannot connect ({type(e).__name__}: {e}); start "
                               "RoboDK with the API enabled (Tools > Options > Other > RoboDK "
                               "API) and check host and port") from e
        if self.rdk.PORT == -1 or self.rdk.BUILD == 0:  # a failed connect does not raise
            self._drop()
            raise AdapterError(f"{self.where}: RoboDK is not answering; start RoboDK with the "
                               "API enabled (Tools > Options > Other > RoboDK API)")
        try:
            self.robot = self._item(cfg.robot_name, robolink.ITEM_TYPE_ROBOT, "robot",
                                    "robot_name")
            self.frame = self._item(cfg.frame_name, robolink.ITEM_TYPE_FRAME, "reference frame",
                                    "frame_name")
            self.tool = self._item(cfg.tool_name, robolink.ITEM_TYPE_TOOL, "tool", "tool_name")
            self.robot.setPoseFrame(self.frame)
            self.robot.setPoseTool(self.tool)  # targets and Pose() are of the active tool
            self.rdk.setRunMode(robolink.RUNMODE_RUN_ROBOT if cfg.run_on_robot
                                else robolink.RUNMODE_SIMULATE)
            if cfg.run_on_robot and self.robot.Connect() != 1:
                raise AdapterError(f"{self.where}: RoboDK could not connect the robot driver of "
                                   f"{cfg.robot_name!r}; check the robot's IP in RoboDK's "
                                   "connection panel (right-click the robot > Connect to "
                                   "robot) or set run_on_robot: false to simulate")
            self.robot.setSpeed(cfg.speed_mm_per_s)
            self._at = self._read_position()
        except AdapterError:
            self._drop()
            raise
        except Exception as e:
            self._drop()
            raise AdapterError(f"{self.where}: setting up the station failed "
                               f"({type(e).__name__}: {e}); check that RoboDK answers on this "
                               "port and the station is open") from e
        log.info("%s: robot %r, frame %r, %s", self.where, cfg.robot_name, cfg.frame_name,
                 "RUN ON ROBOT" if cfg.run_on_robot else "simulation")

    def _item(self, name: str, kind: int, what: str, key: str):
        item = self.rdk.Item(name, kind)
        if not item.Valid():
            raise AdapterError(f"{self.where}: no {what} named {name!r} in the RoboDK station; "
                               f"set robot.robodk.{key} to its name in the station tree")
        got = item.Name()
        if name and got != name:  # RoboDK answers the closest match when none is exact
            raise AdapterError(f"{self.where}: no {what} named exactly {name!r} in the RoboDK "
                               f"station (the closest is {got!r}); set robot.robodk.{key} to "
                               "its name in the station tree")
        return item

    def _drop(self) -> None:
        if self.rdk is not None:
            try:
                self.rdk.Disconnect()
            except Exception:  # already gone; nothing left to release
                pass
        elif self._sock is not None:
            self._sock.close()

    def _lose(self, what: str, e: BaseException) -> AdapterError:
        if isinstance(e, TimeoutError):
            why = "RoboDK did not answer in time"
        elif isinstance(e, ConnectionError):
            why = "RoboDK closed the connection (it quit or its API was restarted)"
        else:
            why = f"the link to RoboDK broke ({type(e).__name__}: {e})"
        self._lost = f"{why} during {what}"
        self._drop()
        return AdapterError(f"{self.where}: {self._lost}. The robot may be stopped anywhere or "
                            "still moving: check it in RoboDK and on the pendant, jog the probe "
                            "clear, restart RoboDK's API, then continue with --resume")

    def _alive(self) -> None:
        if self._lost:
            raise AdapterError(f"{self.where}: the link to RoboDK was lost earlier ({self._lost});"
                               " nothing was sent. Jog the probe clear, restart RoboDK's API, "
                               "then continue with --resume")

    def _pose(self, x, y, z):
        rx, ry, rz = (math.radians(a) for a in self.cfg.orientation_deg)
        return self.rm.transl(x, y, z) * self.rm.rotz(rz) * self.rm.roty(ry) * self.rm.rotx(rx)

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        self._alive()
        what = f"the move to ({x_mm:.3f}, {y_mm:.3f}, {z_mm:.3f}) mm"
        if not all(map(math.isfinite, (x_mm, y_mm, z_mm))):
            raise AdapterError(f"{self.where}: {what} is not a finite target; nothing was sent")
        if self._at is None:
            self._at = self.position()
        if self.move_timeout_s is not None:
            wait = float(self.move_timeout_s)
        else:
            wait = 30.0 + 3.0 * math.dist(self._at, (x_mm, y_mm, z_mm)) / self.cfg.speed_mm_per_s
        if self.cfg.run_on_robot:
            self._driver_ready(what)
        self._sock.wait_s = max(wait, self.timeout_s)
        try:
            self.robot.MoveL(self._pose(x_mm, y_mm, z_mm))
        except self.rl.TargetReachError as e:
            raise AdapterError(f"{self.where}: {what} cannot be reached: {e}; check the frame "
                               "and orientation_deg") from e
        except self.rl.StoppedError as e:
            self._at = None
            raise AdapterError(f"{self.where}: {what} was stopped: {e}; check the robot, then "
                               "continue with --resume") from e
        except Exception as e:  # RoboDK refused it (an error status): the link is still in step
            if _broken(e):  # a socket error, -1 or >= 100: what follows is not known
                raise self._lose(what, e) from e
            self._at = None
            raise AdapterError(f"{self.where}: {what} failed: {e}") from e
        finally:
            if self._sock is not None:
                self._sock.wait_s = self.timeout_s
        self._at = (float(x_mm), float(y_mm), float(z_mm))

    def _driver_ready(self, what: str) -> None:
        """With run_on_robot: the robot driver must still be connected and ready before a move
        (a driver that dropped between moves would leave RoboDK simulating the rest)."""
        try:
            state, msg = self.robot.ConnectedState()
        except Exception as e:
            if _broken(e):
                raise self._lose("asking the robot driver's state", e) from e
            raise AdapterError(f"{self.where}: asking the robot driver's state failed: {e}; "
                               f"{what} was not sent") from e
        if state != self.rl.ROBOTCOM_READY:
            raise AdapterError(f"{self.where}: the robot driver is not ready (state {state}: "
                               f"{msg!r}); {what} was not sent. Reconnect the robot in RoboDK "
                               "(right-click the robot > Connect to robot), then continue with "
                               "--resume")

    def _read_position(self) -> tuple[float, float, float]:
        p = self.robot.Pose().Pos()  # the active tool in the active (workplane) frame
        return float(p[0]), float(p[1]), float(p[2])

    def position(self) -> tuple[float, float, float]:
        self._alive()
        try:
            return self._read_position()
        except Exception as e:
            if _broken(e):
                raise self._lose("reading the pose", e) from e
            raise AdapterError(f"{self.where}: reading the pose failed: {e}") from e

    def close(self) -> None:
        self._lost = self._lost or "the adapter was closed"
        self._drop()
