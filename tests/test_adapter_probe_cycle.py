"""The probe cycle's first move when the adapter cannot say where the probe is (NaN position:
Modbus and manual adapters before their first move, HSES without check_position after a stop)."""
import logging
import math

import pytest

from adaptive_cal.hardware.base import ProbeCycle, Sample, UnsafeTarget


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
    with caplog.at_level(logging.WARNING, logger="adaptive_cal.hardware.base"):
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
