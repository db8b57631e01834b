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
    m.move_to(0.0, 0.0, 5.0)
    controller.faults.alarm_on_move = 1
    m.move_to(5.0, 5.0, 5.0)  # a level move (a travel at the safe height)
    assert controller.robot.pose() == pytest.approx((5.0, 5.0, 5.0)) and not controller.robot.alarm
    assert any(r.command == P.CMD_ALARM_RESET for r in controller.requests)
    m.close()


@pytest.mark.parametrize("lost", [0, 1])
@pytest.mark.parametrize("fault", ["alarm_on_move", "error_on_move"])
def test_an_alarm_during_a_descent_is_never_reset_or_the_move_sent_again(controller, fault,
                                                                         lost):
    """An outside audit (2026-12-01): with reset_alarms an alarm during an approach (a
    collision with the plate or a fixture) was reset and the same move sent again, into
    whatever stopped it. A second audit: where the answer to the descent was lost (``lost``),
    its re-send was refused for the alarm and the alarm was reset all the same."""
    m = connect(controller, reset_alarms=True)
    m.move_to(5.0, 5.0, 15.0)
    setattr(controller.faults, fault, 1)
    controller.faults.drop_answers = lost
    n = len(controller.requests)
    with pytest.raises(HsesError, match="not reset: it came while the robot moved down"):
        m.move_to(5.0, 5.0, 0.0)
    after = requests_after(controller, n)
    assert sum(c == (P.CMD_MOVE, 2) for c in after) == 1 + lost  # the one re-send, no more
    assert not [c for c in after if c[0] == P.CMD_ALARM_RESET]
    # a third audit: the retract after it found the alarm standing and reset it
    with pytest.raises(HsesError, match="not reset: an alarm came during an earlier descent"):
        m.move_to(5.0, 5.0, 15.0)
    assert not [c for c in requests_after(controller, n) if c[0] == P.CMD_ALARM_RESET]
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


# -- holds, alarms, errors, lost answers (the manual's tables; yrcom's as a second reading) -----

MANUAL_HOLDS = {0x2020: "programming pendant", 0x2030: "playback panel", 0x2040: "external",
                0x2050: "command"}  # the manual's "Operation status (2000s)" table


def raw(controller, command, instance, attribute, service, payload=b""):
    """One request to the emulator, its answer decoded with the manual's layout."""
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(1.0)
        s.sendto(P.encode_request(9, command, instance, attribute, service, payload),
                 ("127.0.0.1", controller.port))
        return P.decode_answer(s.recv(4096))


def requests_after(controller, n):
    return [(r.command, r.instance) for r in controller.requests[n:]]


def test_hold_codes_are_the_manuals():
    for code, who in MANUAL_HOLDS.items():
        assert who in P.ADDED_STATUS[code] and who in P.HOLDS[code]
    assert dict(P.HOLD_BITS) == {0x02: 0x2020, 0x04: 0x2040, 0x08: 0x2050}  # fs100 get_status
    yr = pytest.importorskip("yrcom.hses_errors")
    for code, who in MANUAL_HOLDS.items():
        assert who in yr.ADDED_STATUS_CODES[code].lower()


def test_emulator_answers_a_command_hold_with_2050(controller):
    m = connect(controller)
    assert raw(controller, P.CMD_SERVO, P.HOLD, 1, P.SET_ONE, struct.pack("<I", 1)).status == 0
    with pytest.raises(HsesError, match="command hold") as e:
        m.move_to(1.0, 1.0, 1.0)
    assert e.value.added == 0x2050
    m.close()


@pytest.mark.parametrize("bits, added, who", [(0x04, 0x2040, "external hold"),
                                              (0x02, 0x2020, "programming pendant")])
def test_a_held_robot_is_never_reset_or_released(controller, bits, added, who):
    m = connect(controller, reset_alarms=True)
    n = len(controller.requests)
    controller.faults.hold_bits = bits
    with pytest.raises(HsesError, match=who) as e:
        m.move_to(1.0, 1.0, 1.0)
    assert e.value.added == added
    assert requests_after(controller, n) == [(P.CMD_MOVE, 2)]  # no reset, no servo, no re-send
    m.close()


def test_a_hold_during_a_move_stops_the_run_without_a_reset(controller):
    import threading
    m = connect(controller, reset_alarms=True)
    controller.robot.move_s = 0.5
    threading.Timer(0.1, lambda: raw(controller, P.CMD_SERVO, P.HOLD, 1, P.SET_ONE,
                                     struct.pack("<I", 1))).start()
    n = len(controller.requests)
    with pytest.raises(HsesError, match="THE ROBOT IS HELD by a hold command"):
        m.move_to(100.0, 50.0, 15.0)
    assert not [c for c in requests_after(controller, n)  # (the hold itself came from raw())
                if c[0] == P.CMD_ALARM_RESET or c == (P.CMD_SERVO, P.SERVO_POWER)]
    assert sum(c == (P.CMD_MOVE, 2) for c in requests_after(controller, n)) == 1
    m.close()


def test_servo_off_during_a_move_is_not_switched_on_again(controller):
    import threading

    def servo_off():
        controller.servo = False
        controller.robot.stop()

    m = connect(controller, reset_alarms=True)
    controller.robot.move_s = 0.5
    threading.Timer(0.1, servo_off).start()
    n = len(controller.requests)
    with pytest.raises(HsesError, match="SERVO POWER IS OFF during the move"):
        m.move_to(100.0, 50.0, 15.0)
    assert not controller.servo
    assert not [c for c in requests_after(controller, n)
                if c[0] in (P.CMD_ALARM_RESET, P.CMD_SERVO)]
    assert m.position() != (100.0, 50.0, 15.0)  # the controller is asked: not the target
    m.close()


def test_an_error_is_cancelled_with_instance_2_an_alarm_reset_with_instance_1(controller):
    m = connect(controller, reset_alarms=True)
    m.move_to(0.0, 0.0, 5.0)
    controller.faults.error_on_move = 1
    n = len(controller.requests)
    m.move_to(5.0, 5.0, 5.0)
    resets = [c for c in requests_after(controller, n) if c[0] == P.CMD_ALARM_RESET]
    assert resets == [(P.CMD_ALARM_RESET, P.ERROR_CANCEL)] and not controller.error
    controller.faults.alarm_on_move = 1
    n = len(controller.requests)
    m.move_to(6.0, 6.0, 5.0)
    resets = [c for c in requests_after(controller, n) if c[0] == P.CMD_ALARM_RESET]
    assert resets == [(P.CMD_ALARM_RESET, P.ALARM_RESET)]
    assert controller.robot.pose() == pytest.approx((6.0, 6.0, 5.0))
    m.close()


def test_emulator_resets_only_what_the_instance_names(controller):
    controller.robot.alarm, controller.error = True, True
    one = struct.pack("<I", 1)
    assert raw(controller, P.CMD_ALARM_RESET, P.ERROR_CANCEL, 1, P.SET_ONE, one).status == 0
    assert controller.robot.alarm and not controller.error
    assert raw(controller, P.CMD_ALARM_RESET, P.ALARM_RESET, 1, P.SET_ONE, one).status == 0
    assert not controller.robot.alarm


@pytest.mark.parametrize("request_, status, added", [
    ((P.CMD_SERVO, 4, 1, P.SET_ONE, struct.pack("<I", 1)), 0x1F, 0xA001),  # no such instance
    ((P.CMD_SERVO, 2, 1, P.SET_ONE, b"\1\0"), 0x1F, 0xB003),               # data size
    ((P.CMD_SERVO, 2, 1, P.SET_ONE, struct.pack("<I", 3)), 0x1F, 0xB004),  # value out of range
    ((P.CMD_MOVE, 2, 1, P.SET_ALL, b"\0" * 100), 0x1F, 0xB003),
    ((P.CMD_POSITION, 1, 0, P.GET_ALL), 0x28, 0),                          # pulse: not emulated
    ((P.CMD_ALARM, 9, 0, P.GET_ALL), 0x28, 0),
    ((0x99, 1, 0, P.GET_ALL), 0x08, 0)])                                   # command not defined
def test_emulator_refusals_are_the_manuals_codes(controller, request_, status, added):
    controller.servo = True
    ans = raw(controller, *request_)
    assert (ans.status, ans.added) == (status, added)
    assert "see the HSES manual" not in P.explain(ans.status, ans.added)  # each has a message


def test_a_bare_status_1_refusal_is_explained_from_the_status(controller):
    """yrcom's note: a live YRC1000 refuses a move in the wrong state with status 0x01 and
    added status 0 instead of the manual's codes (most likely yrcom's misreading of a 0x1F
    refusal, protocol.STATUS; kept as a refusal either way)."""
    m = connect(controller)
    orig = controller.handle

    def handle(req):
        if req.command == P.CMD_MOVE:
            return P.encode_answer(req.req_id, req.service, 0x01, 0)
        return orig(req)

    controller.handle = handle
    controller.servo = False
    with pytest.raises(HsesError, match="SERVO POWER IS OFF.*status 0x01, added status 0x0000"):
        m.move_to(1.0, 1.0, 1.0)
    controller.servo = True
    with pytest.raises(HsesError, match="status 0x01, added status 0x0000: the controller "
                                        "cannot carry out the request"):
        m.move_to(1.0, 1.0, 1.0)
    m.close()


def test_a_lost_move_answer_waits_for_the_robot_and_checks_where_it_stopped(controller):
    m = connect(controller, retries=2)
    m.move_to(0.0, 0.0, 15.0)
    controller.robot.move_s = 0.4  # longer than the re-send: the re-sent move gets 0x2010
    controller.faults.drop_answers = 1
    m.move_to(100.0, 50.0, 15.0)
    assert not controller.robot.moving()
    assert controller.robot.pose() == pytest.approx((100.0, 50.0, 15.0))
    assert m.position() == (100.0, 50.0, 15.0)
    controller.faults.drop_answers, controller.faults.report_error_mm = 1, 3.0
    with pytest.raises(AdapterError, match="stopped 3.000 mm from the target"):
        m.move_to(0.0, 0.0, 15.0)
    assert m.pose is None  # not the stale target: position() asks the controller
    m.close()


def test_without_check_position_a_move_is_not_done_before_the_robot_ran(controller):
    """A controller that sets RUNNING a moment after it accepted the move."""
    m = connect(controller, check_position=False)
    m.move_to(0.0, 0.0, 15.0)
    controller.robot.move_s = 0.3
    orig, accepted = controller.handle, []

    def handle(req):
        ans = orig(req)
        if req.command == P.CMD_MOVE and ans[25] == 0:
            accepted.append(time.monotonic())
        if req.command == P.CMD_STATUS and accepted and time.monotonic() - accepted[-1] < 0.1:
            d1, d2 = struct.unpack_from("<II", ans, 32)
            return P.encode_answer(req.req_id, req.service, 0, 0,
                                   struct.pack("<II", d1 & ~P.RUNNING, d2))
        return ans

    controller.handle = handle
    m.move_to(100.0, 50.0, 15.0)
    assert not controller.robot.moving()
    assert controller.robot.pose() == pytest.approx((100.0, 50.0, 15.0))
    m.close()


def test_a_position_of_another_tool_is_refused(controller):
    """The manual: word 2 of the position answer is the tool number."""
    assert struct.unpack("<13i", P.position_payload((1, 2, 3), (0, 0, 0), 5))[2] == 5
    with pytest.raises(ValueError, match="tool 5, but robot.hses.tool is 0"):
        P.unpack_position(P.position_payload((1, 2, 3), (0, 0, 0), 5), tool=0)
    m = connect(controller)
    m.move_to(1.0, 1.0, 1.0)
    controller.tool = 3  # the pendant selected another tool
    with pytest.raises(AdapterError, match="tool 3, but robot.hses.tool is 0"):
        m.robot_position()
    m.close()


def test_every_move_keeps_the_arms_configuration_it_stood_in():
    """The move's type word (the arm's configuration: front / back, upper / lower arm, flip)
    was always 0 -- 'flip' by the manual's bits, as transcribed by moto-hses -- whatever the
    robot stood in. Now the form the position answer gives at connect (word 1), or the number
    robot.hses.form says."""
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.simulation.emulator.hses_server import HsesServer
    from adaptive_cal.simulation.emulator.robot import EmulatedRobot
    from tests.devices import ROOT, UFRAME

    assert struct.unpack("<26i", P.move_payload((0, 0, 0), (180, 0, 0), coord=18,
                                                speed_mm_per_s=50, tool=0, user_frame=1,
                                                form=5))[13] == 5
    cell = load_cell(ROOT / "configs" / "cell-hses-emulated.yaml")
    # "current": the answer's expanded form (word 4: an axis turned past 180 deg) goes back in
    # the move's expanded type (word 14) too -- it was always 0 (an outside audit, 2026-11-30)
    for form, expect in (("current", (4, 3)), (1, (1, 0))):
        server = HsesServer(EmulatedRobot.from_cell(cell, move_s=0.01), offset_mm=(100, 0, 300),
                            user_frame=UFRAME).start()
        server.form, server.expanded_form = 4, 3  # no flip (bit 2), front, upper arm; 2 axes
        try:
            m = connect(server, form=form)
            m.move_to(10.0, 20.0, 5.0)
            move = [r for r in server.requests if r.command == P.CMD_MOVE][-1]
            sent = P.unpack_move(move.payload)
            assert (sent["form"], sent["expanded_form"]) == expect
            assert struct.unpack("<26i", move.payload)[14] == expect[1]
            m.close()
        finally:
            server.close()


def test_a_move_sent_while_an_earlier_one_still_runs_waits_for_it(controller):
    """A Ctrl-C that cut short the wait for a move left it running; the retract sent next got
    0x2010 (busy) and was given up after a few polls (0.1 s) -- the probe left down. A busy
    robot is now waited for, as long as a move may take (move_timeout_s)."""
    import threading

    m = connect(controller)
    m.move_to(0.0, 0.0, 15.0)
    controller.robot.move_s = 0.5
    other = connect(controller)  # sends a move and does not wait for it
    t = threading.Thread(target=lambda: other.call(P.CMD_MOVE, 2, 1, P.SET_ALL, P.move_payload(
        other.to_base((100.0, 0.0, 300.0)), (180.0, 0.0, 0.0), coord=P.COORD["base"],
        speed_mm_per_s=50.0, tool=0, user_frame=0)))
    t.start()
    t.join()
    assert controller.robot.moving()
    m.move_to(0.0, 0.0, 15.0)  # refused as busy at first, sent once the robot stopped
    assert controller.robot.pose() == pytest.approx((0.0, 0.0, 15.0))
    m.close()
    other.close()


# -- where the probe stands before the first move, and servo power coming up --------------
class _Gauge:
    def read(self):
        from adaptive_cal.hardware.base import Sample
        return Sample(5.0, 0.0)

    def close(self):
        pass


def test_without_check_position_the_first_touch_lifts_from_where_the_robot_stands(controller):
    """An outside audit (2026-11-29): with check_position false position() answered NaN, so a
    run's first touch (every start, every --resume) went sideways at the safe height with no
    lift first while the tip could still be down. The position is read whenever it can be
    converted, with or without the check."""
    from adaptive_cal.hardware.cycle import ProbeCycle
    m = connect(controller)
    m.move_to(100.0, 50.0, 2.0)  # a run stopped with the tip down
    m.close()
    m = connect(controller, check_position=False)
    assert m.position() == pytest.approx((100.0, 50.0, 2.0), abs=1e-3)
    sent = []
    move = m.move_to
    m.move_to = lambda *p: (sent.append(p), move(*p))
    ProbeCycle(m, _Gauge(), lambda x, y, z: True, safe_height_mm=15.0,
               usable_mm=(0.5, 9.5)).touch(-100.0, -50.0, 2.0)
    assert sent[0] == pytest.approx((100.0, 50.0, 15.0), abs=1e-3)  # straight up first
    assert sent[1] == (-100.0, -50.0, 15.0)
    m.close()


def test_a_position_that_cannot_be_converted_needs_the_robot_parked():
    from adaptive_cal.hardware.hses.config import HsesConfig
    with pytest.raises(ValueError, match="parked_at_safe_height: true"):
        HsesConfig(host="127.0.0.1", port=10040, check_position=False)
    assert not HsesConfig(host="127.0.0.1", port=10040, check_position=False,
                          parked_at_safe_height=True).can_locate
    assert HsesConfig(host="127.0.0.1", port=10040, check_position=False, frame="base").can_locate


def test_a_move_waits_for_servo_power_to_come_up(controller):
    """An outside audit: the servo bit came on 0.8 s after 0x83, the first move was refused
    with 0x2070 'servo is off: switch servo power on' -- which the adapter had just done."""
    controller.faults.servo_delay_s = 0.3
    t0 = time.monotonic()
    m = connect(controller)
    assert time.monotonic() - t0 >= 0.25
    m.move_to(10.0, 20.0, 5.0)
    assert controller.robot.pose() == pytest.approx((10.0, 20.0, 5.0))
    m.close()


def test_servo_power_that_never_comes_up_stops_with_what_to_check(controller):
    controller.faults.servo_never = True
    with pytest.raises(AdapterError, match="servo power did not come on within .*0.2 s.*"
                                           "emergency stops"):
        connect(controller, servo_timeout_s=0.2)
    assert not [r for r in controller.requests if r.command == P.CMD_MOVE]


def _move(**words):
    """A valid linear move's payload (the adapter's own layout), with ``words`` (index -> value)
    changed."""
    w = list(struct.unpack("<26i", P.move_payload((10.0, 20.0, 5.0), (180.0, 0.0, 0.0),
                                                  coord=P.COORD["user"], speed_mm_per_s=50.0,
                                                  tool=0, user_frame=1)))
    for i, v in words.items():
        w[int(i[1:])] = v
    return struct.pack("<26i", *w)


@pytest.mark.parametrize("words, added", [
    ({"w0": 2}, 0xB008),   # robot 2: a control group this controller has not
    ({"w2": 0}, 0xB009),   # speed class 0 (%): a link move's, not a linear move's
    ({"w16": 0}, 0xB00E),  # user frame 0
    ({"w16": 3}, 0xB00E),  # another user frame than the plate's
    ({}, 0)])              # the adapter's own words: taken
def test_the_emulator_refuses_move_words_a_controller_refuses(controller, words, added):
    """An outside audit (2026-11-29): the emulator took a move for robot 2, speed class 0 or
    user frame 0, so a regression in those words of ``move_payload`` passed every emulator
    test. The manual's codes: B008 control group, B009 speed, B00E user frame number."""
    controller.servo = True
    ans = raw(controller, P.CMD_MOVE, 2, 1, P.SET_ALL, _move(**words))
    assert (ans.status, ans.added) == ((0x1F, added) if added else (0, 0))


def test_the_emulator_reads_one_status_word_and_refuses_attribute_0_of_a_get_one(controller):
    whole = raw(controller, P.CMD_STATUS, 1, 0, P.GET_ALL).payload
    assert len(whole) == 8
    for attribute in (1, 2):
        one = raw(controller, P.CMD_STATUS, 1, attribute, P.GET_ONE)
        assert one.status == 0 and one.payload == whole[4 * attribute - 4:4 * attribute]
    for command, instance in ((P.CMD_STATUS, 1), (P.CMD_POSITION, P.POSITION_INSTANCE)):
        ans = raw(controller, command, instance, 0, P.GET_ONE)
        assert (ans.status, ans.added) == (0x1F, 0xA002)


@pytest.mark.parametrize("division, reserved", [(2, P.RESERVED), (1, b"00000000")])
def test_the_emulator_does_not_answer_a_header_a_controller_would_not(controller, division,
                                                                       reserved):
    import socket

    head = P.HEAD.pack(P.MAGIC, P.HEADER_SIZE, 0, 3, division, 0, 9, 0, reserved)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(0.3)
        s.sendto(head + P.REQ_SUB.pack(P.CMD_STATUS, 1, 0, P.GET_ALL, 0),
                 ("127.0.0.1", controller.port))
        with pytest.raises(socket.timeout):
            s.recv(4096)
    assert raw(controller, P.CMD_STATUS, 1, 0, P.GET_ALL).status == 0  # the right one is
