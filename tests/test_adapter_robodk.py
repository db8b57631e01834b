"""The robodk adapter: without a RoboDK server it fails fast with a clear message, never tries
to launch the app. (No fake RoboDK server yet: moves are untested, see docs/adapters/robodk.md.)"""
import time

import pytest

from adaptive_cal.adapters.base import AdapterError
from adaptive_cal.adapters.robodk import RobodkMotion
from adaptive_cal.adapters.schema import RobodkConfig


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost"])
def test_no_robodk_is_a_clean_error(host):
    t = time.monotonic()
    with pytest.raises(AdapterError, match="RoboDK is not answering|cannot connect"):
        RobodkMotion(RobodkConfig(host=host, port=9))
    assert time.monotonic() - t < 5.0
