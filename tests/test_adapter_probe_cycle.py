"""The probe cycle's first move when the adapter cannot say where the probe is (NaN position:
Modbus and manual adapters before their first move, HSES without check_position after a stop)."""
import logging
import math

import pytest

from adaptive_cal.hardware.base import Sample, UnsafeTarget
from adaptive_cal.hardware.cycle import ProbeCycle


class Motion:
    def __init__(self, pose=(math.nan,) * 3):
        self.pose, self.sent = pose, []

    def position(self):
        return self.pose

    def move_to(self, *p):
        self.sent.append(p)
        self.pose = p

    def close(self):
        pass


class Probe:
    def read(self):
        return Sample(5.0, 0.0)

    def close(self):
        pass


def cycle(motion, allowed=lambda x, y, z: True):
    return ProbeCycle(motion, Probe(), allowed, safe_height_mm=15.0, usable_mm=(0.5, 9.5))


@pytest.mark.parametrize("pose", [(math.nan,) * 3, (math.nan, math.nan, 3.0)])
def test_unknown_position_is_said_and_the_first_move_is_the_safe_height(pose, caplog):
    m = Motion(pose)
    with caplog.at_level(logging.WARNING, logger="adaptive_cal.hardware.cycle"):
        cycle(m).touch(100.0, 50.0, 2.0)
    assert m.sent == [(100.0, 50.0, 15.0), (100.0, 50.0, 2.0), (100.0, 50.0, 15.0)]
    assert "position is unknown" in caplog.text and "clear of the plate" in caplog.text


def test_known_low_position_is_lifted_first_without_a_warning(caplog):
    m = Motion((0.0, 0.0, 2.0))
    with caplog.at_level(logging.WARNING):
        cycle(m).touch(100.0, 50.0, 2.0)
    assert m.sent[0] == (0.0, 0.0, 15.0) and "unknown" not in caplog.text


def test_unknown_position_sends_nothing_outside_the_workspace():
    m = Motion()
    inside = lambda x, y, z: abs(x) <= 50 and abs(y) <= 50 and 0 <= z <= 20  # noqa: E731
    with pytest.raises(UnsafeTarget, match="nothing was sent"):
        cycle(m, inside).touch(100.0, 50.0, 2.0)
    assert m.sent == []


def test_a_touch_past_the_strokes_top_is_not_sent_again():
    """A second outside safety audit (2026-11-29): a plate 6 mm higher than its cell file said
    had the first target touched three times, each 1.5 mm past the stroke's end, before the run
    stopped on rejected touches. The same approach, or a lower one, is now refused unsent."""
    from adaptive_cal.hardware.base import TouchRejected

    class High(Probe):
        def read(self):
            return Sample(9.9, 0.0)  # past the usable top 9.5: the tip pushed in further

    m = Motion((0.0, 0.0, 15.0))
    c = ProbeCycle(m, High(), lambda x, y, z: True, safe_height_mm=15.0, usable_mm=(0.5, 9.5))
    with pytest.raises(TouchRejected, match="outside the usable stroke"):
        c.touch(40.0, 2.0, 0.0)
    sent = len(m.sent)
    for z in (0.0, -1.0):
        with pytest.raises(UnsafeTarget, match="would run the probe past its stroke's end again"):
            c.touch(40.0, 2.0, z)
    assert len(m.sent) == sent  # nothing sent
    with pytest.raises(TouchRejected):  # elsewhere, or higher up, the cycle touches as before
        c.touch(40.0, 2.0, 1.0)
    assert len(m.sent) > sent
