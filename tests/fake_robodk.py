"""A small stateful fake of the RoboDK API server, for testing the unmodified ``robodk`` client.

It listens on 127.0.0.1 (an ephemeral port) in a background thread and speaks the binary
protocol of robodk 6.0.2 (``robodk/robolink.py``): ASCII command lines ending in LF, big-endian
int32, doubles, 64-bit item pointers, poses as 16 doubles column-major, and a status int32 after
each call (0 ok; 10 TargetReachError, 11 StoppedError, ... followed by a message line).

Only the commands the ``robodk`` adapter sends are implemented:

========== ======================================= ===========================================
command    client call                             received -> answered
========== ======================================= ===========================================
RDK_API    Robolink() handshake                    int n + n doubles -> line, int api, int
                                                   build, status
G_Item2    Robolink.Item(name, type)               line, int -> item ptr (u64), int type, status
G_Name     Item.Name()                             item -> line, status
S_Link_ptr Item.setPoseFrame(frame item)           item frame, item robot -> status
S_Tool_ptr Item.setPoseTool(tool item)             item tool, item robot -> status
ConnectedState Item.ConnectedState()               item -> int state, line message, status
S_RunMode  Robolink.setRunMode(mode)               int -> status
Connect2   Item.Connect() (robot driver)           item, line ip, int blocking -> int, status
S_Speed4   Item.setSpeed(...)                      item, int 4 + 4 doubles -> status
WaitMove   Item.WaitMove() (before every move)     item -> status, status
MoveXb     Item.MoveL(pose) (blocking)             int type, int 2, int 16 + 16 doubles,
                                                   item 0, item robot -> status, status
G_Hlocal   Item.Pose()                             item -> 16 doubles, status
========== ======================================= ===========================================

Anything else (``CMD_START`` included: the 6.x client never sends it) is an error: it is recorded
in ``errors`` and the connection is closed, so a test that forgets to assert on ``errors`` still
fails on the client side.

State: items by name (one robot, its tools, one or more frames), each frame's pose in the
station (world), the robot's active tool (MoveXb and G_Hlocal answer for it: a pose is of the
tool's centre point, the flange's without one set),
the robot's tool pose in the station, the robot's active frame, the run mode, whether the robot
driver is connected, the speed. A pose target is taken relative to the robot's active frame
(world = frame @ target) and ``G_Hlocal`` on the robot answers inv(frame) @ world, as RoboDK does.
``log`` keeps every command with what it received (the 16 doubles of each move included).

Faults for tests: ``unreachable(xyz) -> bool`` (answer status 10), ``drop_on`` / ``hang_on``
= (command, n): on the n-th such command (1-based) close the connection, or stop answering,
after its first status. ``split_replies`` sends every answer in 1-byte pieces.
"""
from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np

ROBODK_VERSION = "6.0.2"  # the client whose protocol this fake speaks (pinned by the tests)

ITEM_TYPE_ROBOT, ITEM_TYPE_FRAME, ITEM_TYPE_TOOL = 2, 3, 4
RUNMODE_SIMULATE, RUNMODE_RUN_ROBOT = 1, 6
MOVE_TYPE_LINEAR = 2


class _Closed(Exception):
    """The client went away or the server is stopping."""


class _Unknown(Exception):
    """A command or argument this fake does not implement."""


@dataclass
class Cmd:
    """One command received: its name, what came with it, and the run mode at the time."""

    name: str
    args: dict = field(default_factory=dict)
    run_mode: int = RUNMODE_SIMULATE


@dataclass
class FakeItem:
    ptr: int
    name: str
    type: int
    pose: np.ndarray  # in the station (world)


def _xyz(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


class _Conn:
    """Reads exact byte counts and lines from one client, checking the stop flag."""

    def __init__(self, sock: socket.socket, stop: threading.Event):
        self.sock, self.stop, self.buf = sock, stop, b""
        sock.settimeout(0.05)

    def _fill(self) -> None:
        while True:
            if self.stop.is_set():
                raise _Closed("server stopping")
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as e:
                raise _Closed(str(e)) from e
            if not data:
                raise _Closed("client closed")
            self.buf += data
            return

    def exact(self, n: int) -> bytes:
        while len(self.buf) < n:
            self._fill()
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def line(self) -> str:
        while b"\n" not in self.buf:
            if len(self.buf) > 4096:
                raise _Unknown(f"line longer than 4096 bytes: {self.buf[:40]!r}...")
            self._fill()
        out, _, self.buf = self.buf.partition(b"\n")
        return out.decode("utf-8")

    def int(self) -> int:
        return struct.unpack(">i", self.exact(4))[0]

    def item(self) -> int:
        return struct.unpack(">Q", self.exact(8))[0]

    def array(self) -> list[float]:
        n = self.int()
        if not 0 <= n <= 1000:
            raise _Unknown(f"array of {n} doubles")
        return list(struct.unpack(f">{n}d", self.exact(8 * n))) if n else []


class FakeRoboDK:
    """The fake server. ``start()`` it, point the adapter at ``port``, ``close()`` it."""

    def __init__(self, robot_name: str = "Yaskawa MH5LF",
                 frames: dict[str, np.ndarray] | None = None,
                 start_xyz: tuple[float, float, float] = (0.0, 0.0, 50.0),
                 start_frame: str | None = None, build: int = 27000,
                 driver_connects: bool = True, move_s: float = 0.0,
                 tools: dict[str, float] | None = None):
        frames = {"Workplane": _xyz(600.0, -100.0, 250.0)} if frames is None else frames
        self.items: dict[int, FakeItem] = {}
        ptr = 0x5000
        self.robot = FakeItem(ptr, robot_name, ITEM_TYPE_ROBOT, np.eye(4))
        self.items[ptr] = self.robot
        for name, pose in frames.items():
            ptr += 0x10
            self.items[ptr] = FakeItem(ptr, name, ITEM_TYPE_FRAME, np.array(pose, float))
        # tools by name: the tip's length along the flange's z (mm); none active at first
        for name, length in ({"Probe": 120.0} if tools is None else tools).items():
            ptr += 0x10
            self.items[ptr] = FakeItem(ptr, name, ITEM_TYPE_TOOL, _xyz(0.0, 0.0, length))
        self.active_tool: FakeItem | None = None
        self.driver_state = (0, "Ready")  # ConnectedState's answer once connected
        first = start_frame or next(iter(frames))
        frame = self.by_name(first, ITEM_TYPE_FRAME)
        # the station's own active frame for the robot before any client sets one: the base
        self.active_frame: FakeItem | None = None
        self.robot.pose = frame.pose @ _xyz(*start_xyz) @ _rotx180()
        self.build, self.driver_connects, self.move_s = build, driver_connects, move_s
        self.run_mode = RUNMODE_SIMULATE
        self.connected = False
        self.speed: list[float] = []
        self.log: list[Cmd] = []
        self.errors: list[str] = []
        self.unreachable = lambda xyz: False
        self.drop_on: tuple[str, int] | None = None
        self.hang_on: tuple[str, int] | None = None
        self.split_replies = False
        self.connections = 0
        self._counts: dict[str, int] = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._socks: list[socket.socket] = []
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(("127.0.0.1", 0))
        self._srv.listen(4)
        self._srv.settimeout(0.05)
        self.port = self._srv.getsockname()[1]

    # ---- state helpers for tests ---------------------------------------------------------
    def by_name(self, name: str, kind: int) -> FakeItem:
        return next(i for i in self.items.values() if i.name == name and i.type == kind)

    def frame_xyz(self) -> tuple[float, float, float]:
        """The robot's tool position in its active frame (what Pose() answers), mm."""
        return tuple(float(v) for v in self._local(self.robot)[:3, 3])

    def moves(self) -> list[Cmd]:
        return [c for c in self.log if c.name == "MoveXb"]

    def names(self) -> list[str]:
        return [c.name for c in self.log]

    # ---- lifecycle -----------------------------------------------------------------------
    def start(self) -> FakeRoboDK:
        t = threading.Thread(target=self._accept, name="fake-robodk", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def close(self) -> None:
        self._stop.set()
        for t in list(self._threads):
            t.join(timeout=2.0)
        alive = [t.name for t in self._threads if t.is_alive()]
        for s in [self._srv, *self._socks]:
            try:
                s.close()
            except OSError:
                pass
        if alive:
            self.errors.append(f"threads did not stop: {alive}")

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = self._srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._socks.append(sock)
            t = threading.Thread(target=self._serve, args=(sock,), daemon=True,
                                 name=f"fake-robodk-conn{self.connections}")
            self._threads.append(t)
            t.start()

    # ---- protocol ------------------------------------------------------------------------
    def _send(self, sock: socket.socket, data: bytes) -> None:
        if self.split_replies:
            for i in range(len(data)):
                sock.sendall(data[i:i + 1])
        else:
            sock.sendall(data)

    def _serve(self, sock: socket.socket) -> None:
        conn = _Conn(sock, self._stop)
        try:
            while True:
                name = conn.line()
                n = self._counts[name] = self._counts.get(name, 0) + 1
                handler = getattr(self, f"_cmd_{name}", None)
                if handler is None:
                    raise _Unknown(f"unknown command {name!r}")
                out = handler(conn, name, n)
                if out is not None:
                    self._send(sock, out)
        except (_Closed, OSError):  # the client went away (or the adapter dropped the link)
            pass
        except _Hang:
            self._stop.wait()  # answer nothing until the test ends
        except _Unknown as e:
            self.errors.append(str(e))
        except Exception as e:  # a bug in the fake: make it visible
            self.errors.append(f"fake failed: {type(e).__name__}: {e}")
        finally:
            try:
                sock.close()
            except OSError:
                pass

    def _record(self, name: str, **args) -> Cmd:
        with self._lock:
            cmd = Cmd(name, args, self.run_mode)
            self.log.append(cmd)
            return cmd

    def _item(self, ptr: int, kind: int | None = None) -> FakeItem:
        it = self.items.get(ptr)
        if it is None or (kind is not None and it.type != kind):
            what = {ITEM_TYPE_ROBOT: "robot", ITEM_TYPE_FRAME: "frame"}.get(kind, "tool")
            raise _Unknown(f"item {ptr:#x} is not a {what}")
        return it

    def _local(self, it: FakeItem) -> np.ndarray:
        if it.type == ITEM_TYPE_ROBOT:
            ref = self.active_frame.pose if self.active_frame else np.eye(4)
            return np.linalg.inv(ref) @ it.pose
        return it.pose

    @staticmethod
    def _status(code: int = 0, msg: str = "") -> bytes:
        """A status and, where robolink's _check_status reads one, its message line: after 2,
        3, 10-99 and negatives other than -1 (not after 1, 4-9, -1 or 100 and more)."""
        line = code in (2, 3) or 10 <= code < 100 or code < -1
        return struct.pack(">i", code) + ((msg + "\n").encode() if line else b"")

    def _cmd_RDK_API(self, c: _Conn, name, n):
        flags = c.array()
        self._record(name, flags=flags)
        return b"RDK_API\n" + struct.pack(">ii", 1, self.build) + self._status()

    def _cmd_G_Item2(self, c: _Conn, name, n):
        query, kind = c.line(), c.int()
        found = [i for i in self.items.values() if i.type == kind]
        exact = [i for i in found if i.name == query]
        # RoboDK: "if there is no exact match it will return the last closest match"
        close = [i for i in found if query and i.name.startswith(query)]
        hit = (exact or close or (found if query == "" else []) or [None])[0]
        self._record(name, query=query, type=kind, found=hit.ptr if hit else 0)
        ptr, typ = (hit.ptr, hit.type) if hit else (0, -1)
        return struct.pack(">Qi", ptr, typ) + self._status()

    def _cmd_G_Name(self, c: _Conn, name, n):
        it = self._item(c.item())
        self._record(name, item=it.ptr)
        return (it.name + "\n").encode() + self._status()

    def _cmd_S_Link_ptr(self, c: _Conn, name, n):
        frame, robot = self._item(c.item(), ITEM_TYPE_FRAME), self._item(c.item(), ITEM_TYPE_ROBOT)
        self._record(name, frame=frame.ptr, robot=robot.ptr)
        self.active_frame = frame
        return self._status()

    def _cmd_S_Tool_ptr(self, c: _Conn, name, n):
        tool, robot = self._item(c.item(), ITEM_TYPE_TOOL), self._item(c.item(), ITEM_TYPE_ROBOT)
        self._record(name, tool=tool.ptr, robot=robot.ptr)
        self.active_tool = tool
        return self._status()

    def _cmd_ConnectedState(self, c: _Conn, name, n):
        robot = self._item(c.item(), ITEM_TYPE_ROBOT)
        state, msg = self.driver_state if self.connected else (-2, "Disconnected")
        self._record(name, robot=robot.ptr, state=state)
        return struct.pack(">i", state) + (msg + "\n").encode() + self._status()

    def _cmd_S_RunMode(self, c: _Conn, name, n):
        mode = c.int()
        if mode not in (1, 2, 3, 4, 5, 6):
            raise _Unknown(f"run mode {mode}")
        self.run_mode = mode
        self._record(name, mode=mode)
        return self._status()

    def _cmd_Connect2(self, c: _Conn, name, n):
        robot, ip, blocking = self._item(c.item(), ITEM_TYPE_ROBOT), c.line(), c.int()
        self._record(name, robot=robot.ptr, ip=ip, blocking=blocking)
        self.connected = self.driver_connects
        if self.connected:
            self.run_mode = RUNMODE_RUN_ROBOT  # RoboDK: Connect() switches to run mode
        return struct.pack(">i", 1 if self.connected else 0) + self._status()

    def _cmd_S_Speed4(self, c: _Conn, name, n):
        robot, values = self._item(c.item(), ITEM_TYPE_ROBOT), c.array()
        if len(values) != 4:
            raise _Unknown(f"S_Speed4 with {len(values)} values")
        self.speed = values
        self._record(name, robot=robot.ptr, values=values)
        return self._status()

    def _cmd_WaitMove(self, c: _Conn, name, n):
        robot = self._item(c.item(), ITEM_TYPE_ROBOT)
        self._record(name, robot=robot.ptr)
        return self._status() + self._status()

    def _cmd_G_Hlocal(self, c: _Conn, name, n):
        it = self._item(c.item())
        pose = self._local(it)
        self._record(name, item=it.ptr, pose16=tuple(pose.flatten(order="F")))
        return struct.pack(">16d", *pose.flatten(order="F")) + self._status()

    def _cmd_MoveXb(self, c: _Conn, name, n):
        movetype, kind, values = c.int(), c.int(), c.array()
        target, robot = c.item(), self._item(c.item(), ITEM_TYPE_ROBOT)
        if kind != 2 or target != 0 or len(values) != 16:
            raise _Unknown(f"MoveXb target kind {kind} ({len(values)} values, item {target:#x});"
                           " only a pose target is implemented")
        pose = np.array(values, float).reshape(4, 4, order="F")
        frame = self.active_frame
        self._record(name, movetype=movetype, pose16=tuple(values), robot=robot.ptr,
                     frame=frame.ptr if frame else 0, frame_name=frame.name if frame else "",
                     connected=self.connected,
                     tool_name=self.active_tool.name if self.active_tool else "")
        xyz = tuple(pose[:3, 3])
        if self.unreachable(xyz):
            return self._status(10, f"Target not reachable: {xyz}")
        first = self._status()
        if self.drop_on == (name, n):
            self._send(c.sock, first)
            raise _Closed("dropped on purpose")
        if self.hang_on == (name, n):
            self._send(c.sock, first)
            raise _Hang()
        if self.move_s:
            time.sleep(self.move_s)
        ref = frame.pose if frame else np.eye(4)
        robot.pose = ref @ pose
        return first + self._status()


class _Hang(Exception):
    """Stop answering on purpose (the connection stays open)."""


def _rotx180() -> np.ndarray:
    return np.diag([1.0, -1.0, -1.0, 1.0])
