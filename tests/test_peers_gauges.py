"""Gauge presets against their published frames (Mitutoyo 99MAF600B, Sylvac, Keyence DL-RS1A),
the Sylvac two-way cable's line states, echoing gauges and documented error replies."""
import pytest

from adaptive_cal.hardware.base import BadSample
from adaptive_cal.hardware.serial.adapter import PRESETS, SerialProbe, parse
from adaptive_cal.hardware.serial.config import SerialConfig
from tests.devices import gauge  # noqa: F401 (fixture)


@pytest.mark.parametrize("preset, line, mm", [
    ("mitutoyo", b"01A+0000.123\r", 0.123), ("mitutoyo", b"01A-0012.500\r", -12.5),
    ("sylvac", b"+0.1234\r", 0.1234), ("sylvac", b"-12.3456\r", -12.3456),
    ("sylvac", b"+0.1234=\r", 0.1234), ("sylvac", b"+0.1234<\r", 0.1234),
    ("sylvac", b"-1.0000>\r", -1.0), ("keyence", b"M0,+012.3456,+000.0000\r\n", 12.3456)])
def test_published_frames_parse(preset, line, mm):
    assert parse(line, PRESETS[preset].pattern, 1.0) == pytest.approx(mm)


@pytest.mark.parametrize("preset, line", [("sylvac", b"+0.1234=<\r"), ("sylvac", b"=\r"),
                                          ("keyence", b"M1,+012.3456\r\n")])
def test_malformed_frames_are_rejected(preset, line):
    with pytest.raises(BadSample, match="does not match"):
        parse(line, PRESETS[preset].pattern, 1.0)


def test_keyence_error_reply_names_the_code():
    with pytest.raises(BadSample, match="error code 02 to command M0"):
        parse(b"ER,M0,02\r\n", PRESETS["keyence"].pattern, 1.0)


def test_sylvac_two_way_cable_dtr_on_rts_off():
    p = SerialProbe(SerialConfig(port="loop://", preset="sylvac", timeout_s=0.05))
    try:
        assert p.port.dtr is True and p.port.rts is False
        assert (p.port.baudrate, p.port.bytesize, p.port.parity, p.port.stopbits) == (4800, 7, "E", 2)
    finally:
        p.close()


@pytest.mark.parametrize("preset", ["sylvac", "keyence"])
def test_an_echoing_gauge_has_its_echo_skipped(gauge, preset):
    g, probe = gauge(preset=preset)
    g.faults.echo = True
    assert probe.read().reading_mm == pytest.approx(4.2)
    assert probe.read().reading_mm == pytest.approx(4.2)


def test_keyence_error_over_the_line_then_recovery(gauge):
    g, probe = gauge(preset="keyence")
    g.faults.error = 1
    with pytest.raises(BadSample, match="error code 02"):
        probe.read()
    assert probe.read().reading_mm == pytest.approx(4.2)
