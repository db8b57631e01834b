"""The robodk adapter through the unmodified robodk client against a fake RoboDK server on
127.0.0.1 (tests/fake_robodk.py: the binary protocol of robodk 6.0.2, real TCP). Without a
server it fails fast with a clear message and never tries to launch the app. What the fake
cannot tell about a real RoboDK is listed in docs/adapters/robodk.md."""
import math
import socket
import struct
import threading
import time
from importlib.metadata import version

import numpy as np
import pytest

from adaptive_cal.hardware.base import (
    AdapterError,
    BadSample,
    Sample,
    UnsafeTarget,
)
from adaptive_cal.hardware.cycle import ProbeCycle
from adaptive_cal.run.devices import open_cell, safety_check
from adaptive_cal.hardware.manual.adapter import ManualCell
from adaptive_cal.hardware.robodk.adapter import RobodkMotion
from adaptive_cal.hardware.robodk.config import RobodkConfig
from tests.fake_robodk import ROBODK_VERSION, FakeRoboDK, _xyz
from tests.helpers import sim_cell

ROBOT, FRAME, TOOL = "Yaskawa MH5LF", "Workplane", "Probe"
FRAME_POSE = _xyz(600.0, -100.0, 250.0)


@pytest.fixture
def fake():
    server = FakeRoboDK(ROBOT, {FRAME: FRAME_POSE, "Workplane old": _xyz(0, 0, 0)}).start()
    yield server
    server.close()
    assert server.errors == []  # no unknown command, no error in the fake


def connect(server, *, timeout_s=2.0, move_timeout_s=2.0, **kw):
    kw = {"robot_name": ROBOT, "frame_name": FRAME, "tool_name": TOOL, **kw}
    cfg = RobodkConfig(host="127.0.0.1", port=server.port, **kw)
    return RobodkMotion(cfg, timeout_s=timeout_s, move_timeout_s=move_timeout_s)


def test_the_fake_speaks_the_pinned_client():
    assert version("robodk") == ROBODK_VERSION  # update tests/fake_robodk.py with the client


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost"])
def test_no_robodk_is_a_clean_error(host):
    t = time.monotonic()
    with pytest.raises(AdapterError, match="RoboDK is not answering|cannot connect"):
        RobodkMotion(RobodkConfig(host=host, port=9, frame_name=FRAME, robot_name=ROBOT,
                                  tool_name=TOOL))
    assert time.monotonic() - t < 5.0


def test_connects_and_selects_robot_and_frame_by_name(fake):
    m = connect(fake, speed_mm_per_s=35.0)
    assert fake.names() == ["RDK_API", "G_Item2", "G_Name", "G_Item2", "G_Name", "G_Item2",
                            "G_Name", "S_Link_ptr", "S_Tool_ptr", "S_RunMode", "S_Speed4",
                            "G_Hlocal"]
    items = [c.args for c in fake.log if c.name == "G_Item2"]
    assert items == [{"query": ROBOT, "type": 2, "found": fake.robot.ptr},
                     {"query": FRAME, "type": 3, "found": fake.by_name(FRAME, 3).ptr},
                     {"query": TOOL, "type": 4, "found": fake.by_name(TOOL, 4).ptr}]
    assert fake.active_frame.name == FRAME and fake.active_tool.name == TOOL
    assert fake.speed == [35.0, -1.0, -1.0, -1.0]
    assert m.position() == pytest.approx((0.0, 0.0, 50.0))  # the fake's start, in the frame
    m.close()


@pytest.mark.parametrize("key, name, said", [
    ("robot_name", "KUKA KR6", "no robot named 'KUKA KR6'.*robot_name"),
    ("frame_name", "Plate", "no reference frame named 'Plate'.*frame_name"),
    # RoboDK answers the closest match; the adapter insists on the exact name
    ("frame_name", "Work", "no reference frame named exactly 'Work'.*closest is 'Workplane'"),
    ("tool_name", "Gripper", "no tool named 'Gripper'.*tool_name"),
    ("tool_name", "Pro", "no tool named exactly 'Pro'.*closest is 'Probe'"),
])
def test_unknown_item_names_the_item_and_sends_no_move(fake, key, name, said):
    with pytest.raises(AdapterError, match=said):
        connect(fake, **{key: name})
    assert "S_Link_ptr" not in fake.names() and not fake.moves()


def test_an_empty_frame_name_is_refused_when_the_cell_file_is_read(fake):
    """Refused at load since 2026-11-29 (before, only when the adapter connected: an outside
    audit found docs/config.md showing a default of '' for a key the adapter page calls
    required)."""
    from pydantic import ValidationError
    for empty in ("", "  "):
        with pytest.raises(ValidationError, match="frame_name is empty"):
            connect(fake, frame_name=empty)
    with pytest.raises(ValidationError, match="frame_name"):
        RobodkConfig(host="127.0.0.1", port=fake.port)
    assert fake.log == []


def test_move_sends_a_linear_pose_in_the_workplane_frame(fake):
    m = connect(fake)
    m.move_to(12.5, -30.25, 7.0)
    move = fake.moves()[-1]
    assert fake.names()[-2:] == ["WaitMove", "MoveXb"]
    assert move.args["movetype"] == 2 and move.args["robot"] == fake.robot.ptr  # MOVE_TYPE_LINEAR
    assert move.args["frame_name"] == FRAME
    d = move.args["pose16"]  # column-major 4x4: rotation columns, then the translation
    assert d[12:16] == (12.5, -30.25, 7.0, 1.0)  # exactly the coordinates, in mm
    assert (d[3], d[7], d[11]) == (0.0, 0.0, 0.0)
    assert d[0:3] == pytest.approx((1, 0, 0)) and d[4:7] == pytest.approx((0, -1, 0), abs=1e-12)
    assert d[8:11] == pytest.approx((0, 0, -1), abs=1e-12)  # orientation (180, 0, 0): tool down
    # the fake placed the tool at frame @ target in the station and reads it back in the frame
    assert fake.robot.pose[:3, 3] == pytest.approx((612.5, -130.25, 257.0))
    assert m.position() == pytest.approx((12.5, -30.25, 7.0))
    m.close()


def test_orientation_is_rz_ry_rx_in_degrees(fake):
    m = connect(fake, orientation_deg=(180.0, 10.0, 90.0))
    m.move_to(1.0, 2.0, 3.0)
    got = np.array(fake.moves()[-1].args["pose16"]).reshape(4, 4, order="F")

    def rot(axis, deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        r = np.eye(3)
        r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
        return r

    assert got[:3, :3] == pytest.approx(rot(2, 90) @ rot(1, 10) @ rot(0, 180), abs=1e-12)
    assert tuple(got[:3, 3]) == (1.0, 2.0, 3.0)
    m.close()


def test_position_is_the_fakes_pose_in_the_configured_frame(fake):
    tilt = FRAME_POSE.copy()
    a = math.radians(0.8)
    tilt[:3, :3] = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    fake.by_name(FRAME, 3).pose = tilt  # a frame corrected for the plate's tilt
    m = connect(fake)
    fake.robot.pose = tilt @ _xyz(-40.0, 25.0, 15.5)  # moved by someone else (the pendant)
    assert m.position() == pytest.approx((-40.0, 25.0, 15.5), abs=1e-9)
    m.move_to(3.0, 4.0, 5.0)
    assert fake.frame_xyz() == pytest.approx((3.0, 4.0, 5.0), abs=1e-9)
    assert m.position() == pytest.approx((3.0, 4.0, 5.0), abs=1e-9)
    m.close()


@pytest.mark.parametrize("on_robot", [False, True])
def test_run_mode_follows_run_on_robot(fake, on_robot):
    m = connect(fake, run_on_robot=on_robot)
    modes = [c.args["mode"] for c in fake.log if c.name == "S_RunMode"]
    assert modes == [6 if on_robot else 1]
    assert ("Connect2" in fake.names()) == on_robot and fake.connected == on_robot
    m.move_to(0.0, 0.0, 20.0)
    assert fake.moves()[-1].run_mode == (6 if on_robot else 1)
    m.close()


def test_a_robot_driver_that_does_not_connect_is_an_error(fake):
    fake.driver_connects = False
    with pytest.raises(AdapterError, match="could not connect the robot driver.*run_on_robot"):
        connect(fake, run_on_robot=True)
    assert not fake.moves()


def test_unreachable_target_is_a_clear_error_and_the_link_stays_usable(fake):
    m = connect(fake)
    fake.unreachable = lambda xyz: xyz[2] < -5
    with pytest.raises(AdapterError, match=r"\(1.000, 2.000, -9.000\) mm cannot be reached"):
        m.move_to(1.0, 2.0, -9.0)
    m.move_to(1.0, 2.0, 9.0)
    assert m.position() == pytest.approx((1.0, 2.0, 9.0))
    m.close()


def test_answers_in_one_byte_pieces_are_read_whole(fake):
    fake.split_replies = True
    m = connect(fake)
    m.move_to(5.0, 6.0, 7.0)
    assert m.position() == pytest.approx((5.0, 6.0, 7.0))
    m.close()


def test_connection_dropped_mid_move_is_a_clean_error_without_hanging(fake):
    m = connect(fake)
    m.move_to(0.0, 0.0, 20.0)
    fake.drop_on = ("MoveXb", 2)  # RoboDK quits while the second move runs
    t = time.monotonic()
    with pytest.raises(AdapterError, match="closed the connection .*during the move to "
                       r"\(10.000, 0.000, 20.000\).*jog the probe clear.*--resume"):
        m.move_to(10.0, 0.0, 20.0)
    with pytest.raises(AdapterError, match="lost earlier.*nothing was sent"):
        m.move_to(0.0, 0.0, 30.0)
    with pytest.raises(AdapterError, match="lost earlier"):
        m.position()
    assert time.monotonic() - t < 2.0
    assert len(fake.moves()) == 2
    m.close()


def test_no_answer_mid_move_ends_within_the_move_timeout(fake):
    m = connect(fake, timeout_s=0.5, move_timeout_s=0.5)
    fake.hang_on = ("MoveXb", 1)  # the connection stays open, RoboDK never reports the end
    t = time.monotonic()
    with pytest.raises(AdapterError, match="did not answer in time.*--resume"):
        m.move_to(10.0, 0.0, 20.0)
    assert time.monotonic() - t < 2.0
    m.close()


def _listener() -> socket.socket:
    """A local server socket that accepts connections and says nothing (until told)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    return srv


def test_a_server_that_accepts_and_says_nothing_times_out():
    srv = _listener()
    try:
        t = time.monotonic()
        with pytest.raises(AdapterError, match="cannot connect.*TimeoutError"):
            RobodkMotion(RobodkConfig(port=srv.getsockname()[1], frame_name=FRAME,
                                      robot_name=ROBOT, tool_name=TOOL),
                         timeout_s=0.3)
        assert time.monotonic() - t < 2.0
    finally:
        srv.close()


def test_a_server_that_hangs_up_during_the_handshake_does_not_hang_the_client():
    # the bare client reads a line byte by byte until LF and spins forever on a closed socket
    srv = _listener()
    srv.settimeout(2.0)

    def hang_up():
        conn, _ = srv.accept()
        got = b""
        while len(got) < 36:  # "RDK_API\n", int 3, 3 doubles
            got += conn.recv(100)
        conn.sendall(b"RDK")  # part of a line, then gone
        conn.close()

    th = threading.Thread(target=hang_up, daemon=True)
    th.start()
    try:
        t = time.monotonic()
        with pytest.raises(AdapterError, match="cannot connect.*closed the connection"):
            RobodkMotion(RobodkConfig(port=srv.getsockname()[1], frame_name=FRAME,
                                      robot_name=ROBOT, tool_name=TOOL),
                         timeout_s=1.0)
        assert time.monotonic() - t < 2.0
    finally:
        th.join(timeout=2.0)
        srv.close()


def test_unknown_commands_fail_loudly_in_the_fake(fake):
    with socket.create_connection(("127.0.0.1", fake.port), timeout=2) as s:
        s.sendall(b"CMD_START\n1 0\n")  # the pre-6.x handshake: not what the client sends
        assert s.recv(100) == b""  # the fake hung up
    for _ in range(100):
        if fake.errors:
            break
        time.sleep(0.01)
    assert fake.errors == ["unknown command 'CMD_START'"]
    fake.errors.clear()


class PlateProbe:
    """A probe over the fake: the plate surface at z = 0.01 * x / 10 mm in the workplane frame,
    indication 5 mm with the tip at the surface; samples refused where ``bad(x, y)``."""

    def __init__(self, server, bad=lambda x, y: False):
        self.server, self.bad, self.reads = server, bad, []

    def read(self) -> Sample:
        x, y, z = self.server.frame_xyz()
        if self.bad(x, y):
            raise BadSample("garbage", b"??")
        self.reads.append((x, y, z))
        return Sample(5.0 + 0.001 * x - z, time.monotonic())

    def close(self) -> None:
        pass


def test_probe_cycle_over_robodk_never_sends_a_refused_target(fake):
    cell = sim_cell()
    allowed = safety_check(cell)
    m = connect(fake)
    probe = PlateProbe(fake, bad=lambda x, y: (x, y) == (150.0, -150.0))
    cycle = ProbeCycle(m, probe, allowed, cell.robot.safe_height_mm, cell.probe.usable_mm,
                       samples=3, retries=1, sleep=lambda s: None)
    points = [(0.0, 0.0), (-20.0, 80.0),  # the clamp keep-out
              (200.0, 100.0), (300.0, 0.0),  # outside the workplane
              (-210.0, -170.0), (150.0, -150.0),  # the probe gives garbage here
              (100.0, 50.0)]
    done, refused = [], []
    for x, y in points:
        sent = len(fake.moves())
        try:
            done.append(cycle.touch(x, y, 0.0))
        except UnsafeTarget:
            refused.append((x, y))
            assert len(fake.moves()) == sent  # nothing of a refused touch was sent
        except BadSample:
            refused.append((x, y))
            assert fake.frame_xyz() == pytest.approx((x, y, 15.0))  # retracted after the error
    assert refused == [(-20.0, 80.0), (300.0, 0.0), (150.0, -150.0)]
    assert [(t.x_mm, t.y_mm) for t in done] == [(0.0, 0.0), (200.0, 100.0), (-210.0, -170.0),
                                                (100.0, 50.0)]
    for t in done:
        assert t.reading_mm == pytest.approx(5.0 + 0.001 * t.x_mm)
    targets = [c.args["pose16"][12:15] for c in fake.moves()]
    assert targets and all(allowed(*p) for p in targets)
    assert all(c.args["frame_name"] == FRAME and c.args["movetype"] == 2 for c in fake.moves())
    assert {p[2] for p in targets} == {0.0, 15.0}  # travel at the safe height, touch at z = 0
    assert m.position() == pytest.approx((100.0, 50.0, 15.0))
    m.close()


def test_open_cell_drives_robodk_from_the_cell_file(fake):
    cell = sim_cell(robot={"adapter": "robodk", "robodk": {
                        "port": fake.port, "robot_name": ROBOT, "frame_name": FRAME,
                        "tool_name": TOOL}},
                    probe={"adapter": "manual", "settle_s": 0.0})
    opened = open_cell(cell, manual=ManualCell(ask=lambda text: "5.012"))
    try:
        touch = opened.cycle.touch(10.0, -20.0, 0.0)
    finally:
        opened.close()
    assert touch.reading_mm == pytest.approx(5.012)
    assert [c.args["pose16"][12:15] for c in fake.moves()] == [
        (10.0, -20.0, 15.0), (10.0, -20.0, 0.0), (10.0, -20.0, 15.0)]  # from z = 50: no lift


# -- an outside audit against the robodk client's source (2026-11-29) -------------------------
def test_the_probe_tool_is_active_before_any_move(fake):
    """Targets and Pose() are of the active tool (robolink Item.Pose): the adapter set none, so
    with the flange active every touch would land a tool length lower than checked."""
    m = connect(fake)
    m.move_to(10.0, 20.0, 15.0)
    names = fake.names()
    assert names.index("S_Tool_ptr") < names.index("MoveXb")
    assert all(c.args["tool_name"] == TOOL for c in fake.moves())
    m.close()


@pytest.mark.parametrize("key", ["robot_name", "tool_name", "frame_name"])
def test_every_name_is_required_when_the_cell_file_is_read(key):
    from pydantic import ValidationError
    kw = {"robot_name": ROBOT, "frame_name": FRAME, "tool_name": TOOL, key: " "}
    with pytest.raises(ValidationError, match=f"{key} is empty"):
        RobodkConfig(**kw)


def test_speed_has_the_hses_limit():
    from pydantic import ValidationError
    with pytest.raises(ValidationError, match="less than or equal to 1000"):
        RobodkConfig(robot_name=ROBOT, frame_name=FRAME, tool_name=TOOL, speed_mm_per_s=1e6)


def test_a_driver_that_dropped_between_moves_stops_the_run_before_the_next(fake):
    m = connect(fake, run_on_robot=True)
    m.move_to(10.0, 20.0, 15.0)
    sent = len(fake.moves())
    fake.driver_state = (-2, "Disconnected")
    with pytest.raises(AdapterError, match="robot driver is not ready .*Disconnected.*not sent"):
        m.move_to(10.0, 20.0, 0.0)
    assert len(fake.moves()) == sent
    m.close()


def test_a_status_the_client_cannot_place_is_a_lost_link(fake):
    """Status 4242 (>= 100: 'Problems running function', no message read) may leave the stream
    out of step: the link is dropped, not reused."""
    m = connect(fake)
    orig = fake._cmd_MoveXb
    fake._cmd_MoveXb = lambda c, name, n: (orig(c, name, n), struct.pack(">i", 4242))[1]
    with pytest.raises(AdapterError, match="Problems running function.*--resume"):
        m.move_to(10.0, 20.0, 15.0)
    with pytest.raises(AdapterError, match="lost earlier.*nothing was sent"):
        m.move_to(10.0, 20.0, 0.0)
    m.close()
