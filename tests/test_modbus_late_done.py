"""Two quick Ctrl-Cs in a Modbus approach: the stopped approach's late 'done' came during the
retract's check that done stays off, and the message blamed the PLC program ("it must not copy
the robot's done output") -- a third outside audit, 2 of 6 timing-dependent trials. It now names
the stopped move; a PLC that mirrors done with no move stopped is still named as such."""
from types import SimpleNamespace

import pytest

from adaptive_cal.hardware.base import AdapterError
from adaptive_cal.hardware.modbus.motion import ModbusMotion


class Link:
    """A PLC seen through the link's calls: ``done`` comes back ``late`` s after the PC clears
    it (the robot job finishing a move the PC stopped waiting for), or never."""

    def __init__(self, late=None, actuals=True):
        names = {"start": "M10", "done": "M11", "target_x": "D100", "target_y": "D102",
                 "target_z": "D104"}
        if actuals:
            names.update(actual_x="D110", actual_y="D112", actual_z="D114")
        self.map = {role: SimpleNamespace(name=n) for role, n in names.items()}
        self.cfg = SimpleNamespace(done_settle_s=0.05, scan_s=0.01, poll_s=0.01,
                                   move_timeout_s=1.0, parked_at_safe_height=True)
        self.where, self.words, self.t = "PLC 127.0.0.1:502", 1, 0.0
        self.late, self.cleared_at, self.bits, self.regs = late, None, {}, {}
        self.starts = 0

    def clock(self):
        return self.t

    def sleep(self, s):
        self.t += s

    def check_fault(self):
        pass

    def to_words(self, role, v):
        return [round(v * 1000)]

    def from_words(self, words):
        return words[0] / 1000

    def write_words(self, role, words):
        self.regs[role] = list(words)

    def read_words(self, role, n):
        return self.regs.get(role, [0])

    def write_bit(self, role, value):
        if role == "done" and not value:
            self.cleared_at = self.t
        if role == "start" and value:
            self.starts += 1
        self.bits[role] = value

    def read_bit(self, role):
        if role == "done" and self.late is not None and self.cleared_at is not None:
            return self.t - self.cleared_at >= self.late
        return bool(self.bits.get(role))


def test_the_stopped_moves_late_done_is_named_not_the_plc_program():
    link = Link(late=0.02)
    motion = ModbusMotion(link)
    motion.started, motion.first_done_checked = True, True
    motion.unfinished = "KeyboardInterrupt"  # the approach stopped by the first Ctrl-C
    with pytest.raises(AdapterError) as e:
        motion.move_to(10.0, 20.0, 15.0)  # the retract
    said = str(e.value)
    assert "most likely the late done of the move stopped before (KeyboardInterrupt)" in said
    assert "Start (M10) was not set and nothing was sent" in said
    assert "See where the robot stands" in said
    assert "must not copy" not in said and link.starts == 0


def test_a_connections_first_done_is_named_as_an_earlier_runs_move():
    link = Link(late=0.02)
    motion = ModbusMotion(link)
    with pytest.raises(AdapterError, match="a move the robot job was still in when this "
                                           "connection began"):
        motion.move_to(10.0, 20.0, 15.0)
    assert link.starts == 0


def test_a_plc_that_mirrors_done_with_no_move_stopped_is_still_named():
    link = Link(late=0.02, actuals=False)  # no actuals: the first done is not in doubt
    motion = ModbusMotion(link)
    motion.started = True
    with pytest.raises(AdapterError, match="it must not copy the robot's done output"):
        motion.move_to(10.0, 20.0, 15.0)
    assert link.starts == 0
