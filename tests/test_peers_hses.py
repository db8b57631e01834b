"""HSES wire facts against the manual's layout (golden bytes) and against yrcom 0.3.1, an
independent client from PyPI, on 127.0.0.1."""
import math
import struct

import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.hardware.hses import protocol as P
from adaptive_cal.hardware.hses.adapter import HsesError
from adaptive_cal.hardware.hses.config import HsesConfig
from adaptive_cal.hardware.hses.frames import base_to_user, user_to_base
from adaptive_cal.simulation.emulator.hses_server import HsesServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT
from tests.devices import UFRAME, connect, controller  # noqa: F401 (fixtures)

yrcom = pytest.importorskip("yrcom")
from yrcom.hses_client import CartesianMove, HsesClient, _decode_position  # noqa: E402
from yrcom.hses_server_codec import encode_error, encode_response  # noqa: E402

HEAD = "59455243 2000 {size:02x}00 03 01 {ack:02x} {rid:02x} {block} 3939393939393939"


def golden(hexstr: str) -> bytes:
    return bytes.fromhex(hexstr.replace(" ", ""))


# -- golden frames from the manual's layout ------------------------------------------------
def test_servo_on_request_is_the_manuals_bytes_and_yrcoms():
    want = golden(HEAD.format(size=4, ack=0, rid=5, block="00000000")
                  + "8300 0200 01 10 0000" + "01000000")
    assert P.encode_request(5, P.CMD_SERVO, P.SERVO_POWER, 1, P.SET_ONE,
                            struct.pack("<I", 1)) == want
    assert HsesClient._build(0x83, 2, 1, 0x10, 5, struct.pack("<I", 1)) == want


@pytest.mark.parametrize("cmd, inst, attr, svc, payload", [
    (0x72, 1, 0, 0x01, b""), (0x75, 101, 0, 0x01, b""), (0x70, 1, 0, 0x01, b""),
    (0x82, 1, 1, 0x10, struct.pack("<I", 1)), (0x83, 1, 1, 0x10, struct.pack("<I", 2)),
    (0x8A, 2, 1, 0x02, P.move_payload((1, 2, 3), (180, 0, 0), coord=18, speed_mm_per_s=50,
                                      tool=0, user_frame=1))])
def test_requests_match_yrcom_byte_for_byte(cmd, inst, attr, svc, payload):
    assert P.encode_request(9, cmd, inst, attr, svc, payload) == \
        HsesClient._build(cmd, inst, attr, svc, 9, payload)


def test_move_payload_matches_yrcoms_cartesian_move():
    ours = P.move_payload((1.5, -2, 3), (180, 0, 0), coord=18, speed_mm_per_s=50, tool=0,
                          user_frame=1)
    theirs = CartesianMove(x=1500, y=-2000, z=3000, rx=1800000, speed=500, coord=18,
                           user_coord_no=1).to_bytes()
    assert ours == theirs


def test_refusal_answer_golden_bytes_one_added_status_word():
    want = golden(HEAD.format(size=0, ack=1, rid=7, block="00000080")
                  + "90 1f 01 00 7020 0000")  # service 0x10|0x80, 0x1F, size 1, 0x2070
    assert P.encode_answer(7, P.SET_ONE, 0x1F, 0x2070) == want
    assert P.decode_answer(want, P.CMD_SERVO, P.SET_ONE)[1:4] == (P.SET_ONE, 0x1F, 0x2070)


def test_an_added_status_is_read_only_where_its_size_says_one_is_there():
    """The manual: 0x1F carries an added status of size 1 or 2, any other status size 0. A 0x1F
    with size 0 and 0x2010 left in bytes 28-29 was read busy, and the adapter retried to its move
    timeout instead of stopping (an outside audit, 2026-11-29)."""
    stale = golden(HEAD.format(size=0, ack=1, rid=7, block="00000080")
                   + "90 1f 00 00 1020 0000")  # size 0: bytes 28-29 are not an added status
    assert P.decode_answer(stale, P.CMD_SERVO, P.SET_ONE)[1:4] == (P.SET_ONE, 0x1F, 0)


def test_a_refusal_framed_the_yrcom_way_is_a_refusal():
    ans = P.decode_answer(encode_error(0x8A, 3, 0x1F, 0x2070), P.CMD_MOVE, P.SET_ALL)
    assert (ans.status, ans.added) == (0x1F, 0x2070)
    ok = P.decode_answer(encode_response(0x72, 3, b"\0" * 8), P.CMD_STATUS, P.GET_ALL)
    assert ok.status == 0 and len(ok.payload) == 8
    with pytest.raises(ValueError, match="echoes neither"):
        P.decode_answer(encode_error(0x8A, 3, 0x1F, 0x2070), P.CMD_STATUS, P.GET_ALL)


class YrcomFramedController(HsesServer):
    """Answers with yrcom's answer layout (command echoed, status at byte 26)."""

    def handle(self, req):
        ans = P.decode_answer(super().handle(req))
        if ans.status:
            return encode_error(req.command, req.req_id, ans.status, ans.added)
        return encode_response(req.command, req.req_id, ans.payload)


def test_adapter_stops_on_a_yrcom_framed_refusal():
    cell = load_cell(ROOT / "configs" / "cell-hses-emulated.yaml")
    server = YrcomFramedController(EmulatedRobot.from_cell(cell, move_s=0.01),
                                   offset_mm=(100, 0, 300), user_frame=UFRAME).start()
    try:
        m = connect(server)
        server.faults.alarm_on_move = 1
        with pytest.raises(HsesError) as e:
            m.move_to(1.0, 1.0, 1.0)  # the alarm stops the move, then the retry is refused
        m.servo(False)
        with pytest.raises(HsesError, match="0x2070") as e:
            server.robot.alarm = False
            m.move_to(1.0, 1.0, 1.0)
        assert e.value.status == 0x1F and e.value.added == 0x2070
    finally:
        server.close()


# -- the position read answers in the base frame ---------------------------------------
def test_user_frame_conversion_round_trips_and_rotates():
    assert user_to_base((10, 0, 0), (650, -20, 300), (0, 0, 90)) == pytest.approx((650, -10, 300))
    p = (12.5, -7.0, 3.0)
    for rot in [(0, 0, 0), (10, -20, 30), (180, 0, -90)]:
        assert base_to_user(user_to_base(p, (1, 2, 3), rot), (1, 2, 3), rot) == pytest.approx(p)


def test_position_answer_is_base_frame_data_type_16(controller):
    m = connect(controller)
    m.move_to(10.0, 20.0, 5.0)
    raw = m.call(P.CMD_POSITION, 101, 0, P.GET_ALL)
    assert struct.unpack_from("<i", raw)[0] == 16
    theirs = _decode_position(raw)
    want = user_to_base((110.0, 20.0, 305.0), *UFRAME)
    assert (theirs["pos_X"], theirs["pos_Y"], theirs["pos_Z"]) == pytest.approx(want, abs=1e-3)
    m.pose = None  # ask the controller: base -> user -> workplane
    assert m.position() == pytest.approx((10.0, 20.0, 5.0), abs=1e-3)
    m.close()


def test_a_wrong_user_frame_in_the_cell_file_fails_the_position_check(controller):
    m = connect(controller, user_frame_in_base={"origin_mm": UFRAME[0], "rotation_deg": (0, 0, 0)})
    with pytest.raises(Exception, match="base frame; reported"):
        m.move_to(10.0, 20.0, 5.0)
    m.close()


def test_other_data_types_are_refused():
    with pytest.raises(ValueError, match="data type 18"):
        P.unpack_position(struct.pack("<13i", 18, *[0] * 12))


@pytest.mark.parametrize("kw, words", [
    ({}, "needs user_frame_in_base"),
    ({"user_frame_in_base": {"origin_mm": (math.nan, 0, 0)}}, "origin_mm"),
    ({"user_frame_in_base": {"origin_mm": (0, 0, 0), "rotation_deg": (0, 0, 270)}}, "180")])
def test_config_needs_a_finite_user_frame_for_the_check(kw, words):
    with pytest.raises(ValueError, match=words):
        HsesConfig(host="127.0.0.1", port=10040, **kw)
    HsesConfig(host="127.0.0.1", port=10040, check_position=False, parked_at_safe_height=True)
    HsesConfig(host="127.0.0.1", port=10040, frame="base")


# -- yrcom as a client against the emulator ---------------------------------------------
def test_yrcom_client_against_the_emulator(controller):
    c = HsesClient("127.0.0.1", controller.port, timeout=1.0)
    c.open()
    try:
        s = c.read_status()
        assert s["cmd_remote"] and s["play"] and not s["servo_on"]
        c.hold(True)  # instance 1: hold, not servo power
        assert controller.hold and not controller.servo
        assert c.read_status()["hold_cmd"] and not c.read_status()["servo_on"]
        with pytest.raises(yrcom.HsesError):  # held: the move is refused
            c.move_cartesian(CartesianMove(x=110000, y=0, z=305000, rx=1800000, speed=500,
                                           coord=18, user_coord_no=1))
        c.hold(False)
        c.servo(True)
        assert controller.servo and c.read_status()["servo_on"]
        c.move_cartesian(CartesianMove(x=110000, y=20000, z=305000, rx=1800000, speed=500,
                                       coord=18, user_coord_no=1))
        while c.read_status()["running"]:
            pass
        assert controller.robot.pose() == pytest.approx((10.0, 20.0, 5.0))
        pos = c.read_position(101)
        assert (pos["pos_X"], pos["pos_Y"]) == pytest.approx(
            user_to_base((110, 20, 305), *UFRAME)[:2], abs=1e-3)
        assert c.read_alarm(1)["alarm_code"] == 0
        controller.robot.alarm = True
        assert c.read_alarm(1)["alarm_code"] == 4100
        c.reset_alarm()
        assert not controller.robot.alarm
    finally:
        c.close()


def test_adapter_names_the_alarm_it_read(controller):
    m = connect(controller)
    controller.faults.alarm_on_move = 1
    with pytest.raises(HsesError, match="alarm 4100 'EMULATED ALARM'"):
        m.move_to(5.0, 5.0, 5.0)
    m.close()
