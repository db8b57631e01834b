"""Emulated devices the adapter tests and the peer tests share: an HSES controller on 127.0.0.1
with its user frame, and serial gauges on pty pairs. Import the fixtures into a test module."""
import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.hardware.hses.adapter import HsesMotion
from adaptive_cal.hardware.hses.config import HsesConfig
from adaptive_cal.hardware.serial.adapter import SerialProbe
from adaptive_cal.hardware.serial.config import SerialConfig
from adaptive_cal.simulation.emulator.gauge import PtyGauge
from adaptive_cal.simulation.emulator.hses_server import HsesServer
from adaptive_cal.simulation.emulator.robot import EmulatedRobot
from tests.conftest import ROOT

UFRAME = ((650.0, -20.0, 300.0), (0.0, 0.0, 90.0))  # user frame 1 in the base frame (mm, deg)


@pytest.fixture
def controller():
    """The emulated HSES controller of configs/cell-hses-emulated.yaml, user frame UFRAME."""
    cell = load_cell(ROOT / "configs" / "cell-hses-emulated.yaml")
    server = HsesServer(EmulatedRobot.from_cell(cell, move_s=0.01), offset_mm=(100, 0, 300),
                        user_frame=UFRAME).start()
    yield server
    server.close()


def connect(server, **kw):
    """The hses adapter on ``server`` with short timeouts and the same user frame; two resends
    by default (one 0.1 s try timed out once on a loaded 2-core machine: a CI failure with no
    fault injected). Tests of the resend logic give ``retries`` themselves."""
    kw = {"timeout_s": 0.1, "retries": 2, "poll_s": 0.002, "move_timeout_s": 2.0,
          "offset_mm": (100, 0, 300),
          "user_frame_in_base": {"origin_mm": UFRAME[0], "rotation_deg": UFRAME[1]}, **kw}
    return HsesMotion(HsesConfig(host="127.0.0.1", port=server.port, **kw))


@pytest.fixture
def gauge():
    """make(value=..., **serial config) -> (emulated gauge on a pty, the serial probe on it)."""
    made = []

    def make(value=4.2, **cfg):
        cfg = SerialConfig(port="/dev/null", timeout_s=0.2, **cfg)
        g = PtyGauge(cfg, lambda: value).start()
        probe = SerialProbe(cfg.model_copy(update={"port": g.path}))
        made.append((g, probe))
        return g, probe

    yield make
    for g, probe in made:
        probe.close()
        g.close()
