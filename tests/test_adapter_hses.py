"""The hses adapter against the emulated controller on 127.0.0.1 (real UDP packets)."""
import struct
import time

import pytest

from adaptive_cal.hardware.hses import protocol as P
from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.hses.adapter import HsesError
from tests.devices import connect, controller  # noqa: F401 (controller: a fixture)




def test_header_layout_matches_the_manual():
    pkt = P.encode_request(7, P.CMD_MOVE, 2, 1, P.SET_ALL, b"\0" * 104)
    assert len(pkt) == 32 + 104 and pkt[:4] == b"YERC"
    assert struct.unpack_from("<HHBBBBI8s", pkt, 4) == (0x20, 104, 3, 1, 0, 7, 0, b"99999999")
    assert struct.unpack_from("<HHBBH", pkt, 24) == (0x8A, 2, 1, 0x02, 0)
    ans = P.decode_answer(P.encode_answer(7, 0x02, 0x1F, 0x2060))
    assert (ans.req_id, ans.service, ans.status, ans.added) == (7, 0x02, 0x1F, 0x2060)
    words = struct.unpack("<26i", P.move_payload((1.5, -2, 3), (180, 0, 0), coord=18,
                                                 speed_mm_per_s=50, tool=0, user_frame=1))
    assert words[:11] == (1, 0, 1, 500, 18, 1500, -2000, 3000, 1800000, 0, 0)
    assert words[16] == 1


def test_servo_on_and_linear_move_in_the_user_frame(controller):
    m = connect(controller)
    assert controller.servo
    m.move_to(10.0, 20.0, 5.0)
    assert controller.robot.pose() == pytest.approx((10.0, 20.0, 5.0))
    move = [r for r in controller.requests if r.command == P.CMD_MOVE][-1]
    got = P.unpack_move(move.payload)
    assert got["coord"] == 18 and got["user_frame"] == 1
    assert got["xyz_mm"] == pytest.approx((110.0, 20.0, 305.0))  # offset applied
    assert m.position() == (10.0, 20.0, 5.0)
    m.close()


def test_dropped_answer_is_resent_and_late_answer_dropped(controller):
    m = connect(controller, retries=2)
    controller.faults.delay_answers, controller.faults.delay_s = 1, 0.15  # late for try 1
    d1, _ = m.status()
    assert d1 & P.REMOTE
    time.sleep(0.2)
    m.status()  # the late answer to the first try arrives now and must be dropped
    assert m.dropped >= 1
    controller.faults.drop_answers = 2
    m.move_to(1.0, 2.0, 3.0)
    assert controller.robot.pose() == pytest.approx((1.0, 2.0, 3.0))
    m.close()


def test_no_answer_ends_in_a_clear_error_quickly(controller):
    m = connect(controller, retries=1)
    controller.faults.drop_answers = 100
    t = time.monotonic()
    with pytest.raises(AdapterError, match="no answer to command 0x72 after 2 tries"):
        m.status()
    assert time.monotonic() - t < 1.0
    m.close()


def test_alarm_during_move_reset_once_then_succeeds(controller):
    m = connect(controller, reset_alarms=True)
    controller.faults.alarm_on_move = 1
    m.move_to(5.0, 5.0, 5.0)
    assert controller.robot.pose() == pytest.approx((5.0, 5.0, 5.0)) and not controller.robot.alarm
    assert any(r.command == P.CMD_ALARM_RESET for r in controller.requests)
    m.close()


def test_alarm_without_reset_stops_with_what_to_do(controller):
    m = connect(controller)
    controller.faults.alarm_on_move = 1
    with pytest.raises(HsesError, match="reset it") as e:
        m.move_to(5.0, 5.0, 5.0)
    assert e.value.added == 0x2060
    with pytest.raises(HsesError, match="added status 0x2060"):  # refused while the alarm stands
        m.move_to(5.0, 5.0, 5.0)
    m.close()


def test_remote_off_refused_at_connect(controller):
    controller.faults.remote = False
    with pytest.raises(AdapterError, match="REMOTE"):
        connect(controller)


def test_position_mismatch_is_reported(controller):
    m = connect(controller)
    controller.faults.report_error_mm = 100.0  # e.g. it reports another frame
    with pytest.raises(AdapterError, match="stopped 100.000 mm from the target"):
        m.move_to(1.0, 1.0, 1.0)
    m.close()


@pytest.mark.parametrize("added, words", [(0x2070, "servo power on"), (0x3350, "user_frame"),
                                          (0x2030, "release"), (0x1234, "manual")])
def test_added_status_messages(added, words):
    assert words in P.explain(0x1F, added)
