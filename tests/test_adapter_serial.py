"""The serial probe adapter over a pty pair with a responder thread (a real port to pyserial)."""
import pytest

from adaptive_cal.hardware.base import AdapterError, BadSample
from adaptive_cal.hardware.serial.config import SerialConfig
from adaptive_cal.hardware.serial.adapter import SerialProbe, parse
from adaptive_cal.simulation.emulator.gauge import answer_line
from tests.devices import gauge  # noqa: F401 (fixture)




@pytest.mark.parametrize("preset", ["mitutoyo", "sylvac", "keyence"])
def test_presets_read_the_value_and_keep_raw_bytes(gauge, preset):
    g, probe = gauge(value=4.2371, preset=preset)
    s = probe.read()
    assert s.reading_mm == pytest.approx(4.2371, abs=1e-9)
    assert s.raw == answer_line(preset, 4.2371) and s.t_s > 0


def test_custom_pattern_and_scale(gauge):
    g, probe = gauge(value=1.25, preset="custom", request="R\\r",
                     pattern=r"^([-+]?\d+\.\d+)$", scale=0.001)  # gauge sends um
    assert probe.read().reading_mm == pytest.approx(1.25)


@pytest.mark.parametrize("fault, match", [("silent", "did not answer within 0.2 s"),
                                          ("garbage", "does not match the expected format"),
                                          ("error", "reported an error 'ERR3'")])
def test_faults_are_bad_samples_then_recovery(gauge, fault, match):
    g, probe = gauge(preset="sylvac")
    setattr(g.faults, fault, 1)
    with pytest.raises(BadSample, match=match):
        probe.read()
    assert probe.read().reading_mm == pytest.approx(4.2)  # the late/garbage answer is not reused


def test_out_of_range_value_rejected(gauge):
    g, probe = gauge(value=12.0, preset="sylvac", range_mm=(0.0, 10.0))
    with pytest.raises(BadSample, match="outside probe.serial.range_mm"):
        probe.read()


def test_missing_port_is_a_clear_error():
    with pytest.raises(AdapterError, match="probe.serial.port='/dev/no-such-gauge'"):
        SerialProbe(SerialConfig(port="/dev/no-such-gauge", timeout_s=0.1))


@pytest.mark.parametrize("line", [b"01A+0000.12x\r", b"\r", b"01A+inf\r"])
def test_parse_rejects_non_numbers(line):
    with pytest.raises(BadSample):
        parse(line, r"^\d{2}A([-+]\s*\S+)\s*$", 1.0)


def test_emulated_mitutoyo_line_has_the_manuals_width():
    """99MAF600B / HARDWARE.md: ``01A+0000.123\\r``: 01, A, the sign, then 8 characters (D5-D12,
    the decimal point included), CR."""
    import re

    from adaptive_cal.simulation.emulator.gauge import answer_line

    published = b"01A+0000.123\r"
    for mm in (0.123, 4.2, -12.5, 999.9999):
        line = answer_line("mitutoyo", mm)
        assert len(line) == len(published) and re.fullmatch(rb"01A[-+][0-9.]{8}\r", line)
        assert float(line[3:-1]) == pytest.approx(mm, abs=1e-4)


def test_a_streaming_gauge_read_mid_line_gives_whole_values_only():
    """A gauge that sends continuously (preset custom, no request) is mid-line when the buffer
    is cleared: the tail of a line ("1.2345" of "-1.2345") must not be read as a value -- it
    would flip the sign. The adapter drops everything up to the first line end first. Written a
    byte at a time on a pty, read at 40 moments: every sample is the whole value."""
    import os
    import random
    import threading
    import time
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    stop = threading.Event()

    def stream():
        line = b"-1.2345\r"
        while not stop.is_set():
            for b in line:
                try:
                    os.write(master, bytes([b]))
                except OSError:
                    return
                time.sleep(0.0005)

    t = threading.Thread(target=stream, daemon=True)
    t.start()
    cfg = SerialConfig(port=os.ttyname(slave), timeout_s=0.5, preset="custom", request="",
                       pattern=r"^([-+]?\d+\.\d+)$")
    probe = SerialProbe(cfg)
    rng = random.Random(0)
    try:
        got = []
        for _ in range(40):
            time.sleep(rng.uniform(0.0, 0.004))
            got.append(probe.read().reading_mm)
    finally:
        stop.set()
        probe.close()
        t.join(1.0)
        os.close(master)
        os.close(slave)
    assert got == [-1.2345] * 40


def test_a_late_answer_to_a_timed_out_request_is_not_the_next_sample():
    """An outside audit (2026-11-29): request 1 timed out, its answer came 50 ms later, just
    after the next read cleared the buffer, and request 2 returned request 1's value with its
    own time. A timed-out read now drops what comes until the line has been quiet."""
    from adaptive_cal.simulation.emulator.gauge import PtyGauge
    values = iter([0.111, 0.222, 0.333, 0.444])
    cfg = SerialConfig(port="/dev/null", timeout_s=0.2, preset="sylvac")
    g = PtyGauge(cfg, lambda: next(values)).start()
    probe = SerialProbe(cfg.model_copy(update={"port": g.path}))
    try:
        g.faults.late, g.faults.late_s = 1, 0.25  # 50 ms after the read gave up
        with pytest.raises(BadSample, match="did not answer"):
            probe.read()
        assert probe.read().reading_mm == pytest.approx(0.222)
        assert probe.read().reading_mm == pytest.approx(0.333)
    finally:
        probe.close()
        g.close()


@pytest.mark.parametrize("line, decimals, ok", [
    (b"01A+0000.123\r", 3, True), (b"01A+0000.1\r", 3, False),   # digits lost
    (b"01A+00.04850\r", 3, False),                                # a gauge switched to inches
    (b"01A+00.04850\r", None, True)])
def test_decimals_catch_an_inch_gauge_and_lost_digits(line, decimals, ok):
    from adaptive_cal.hardware.serial.adapter import PRESETS
    if ok:
        assert parse(line, PRESETS["mitutoyo"].pattern, 1.0, decimals) == float(line[3:-1])
    else:
        with pytest.raises(BadSample, match="digits after the point"):
            parse(line, PRESETS["mitutoyo"].pattern, 1.0, decimals)


def test_a_mitutoyo_line_without_its_decimal_point_is_no_reading():
    from adaptive_cal.hardware.serial.adapter import PRESETS
    with pytest.raises(BadSample, match="does not match"):
        parse(b"01A+00000123\r", PRESETS["mitutoyo"].pattern, 1.0)


@pytest.mark.parametrize("line", [b"M0,+EE.EEE\r\n", b"M0,+99.999\r\n", b"M0,-99.999,+001.000\r\n",
                                  b"M0,+FFFFFFF\r\n", b"M0,-FFFFFFF\r\n"])
def test_keyence_out_of_range_readouts_say_so(line):
    """DL-RS1A manual, readout data: +EE.EEE an amplifier error, +-99.999 at or beyond the
    display range -- no reading, and not 'check the baud rate'."""
    from adaptive_cal.hardware.serial.adapter import PRESETS
    with pytest.raises(BadSample, match="out-of-range or error readout"):
        parse(line, PRESETS["keyence"].pattern, 1.0)
    assert parse(b"M0,+012.3456\r\n", PRESETS["keyence"].pattern, 1.0) == 12.3456


def _pty_gauge(answer):
    """A pty pair whose responder calls ``answer(i, request)`` -> bytes for the i-th request
    line (CR-terminated) and writes them back; (probe port path, closer)."""
    import os
    import threading
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    stop = threading.Event()

    def serve():
        buf, i = b"", 0
        while not stop.is_set():
            try:
                buf += os.read(master, 64)
            except OSError:
                return
            while b"\r" in buf:
                req, buf = buf.split(b"\r", 1)
                out = answer(i, req)
                i += 1
                if out:
                    os.write(master, out)

    t = threading.Thread(target=serve, daemon=True)
    t.start()

    def close():
        stop.set()
        os.close(master)
        os.close(slave)
    return os.ttyname(slave), close


def test_an_answer_later_than_the_drain_is_caught_not_taken_for_the_next_requests():
    """An outside audit (2026-11-29): a request answered only after the drain had ended (more
    than 2 x timeout_s late) gave its value to the next request, stamped with that request's
    time, and the next request's own answer was lost. After an unanswered request the next
    read waits for a second line; when one comes, neither is used; the read after is clean."""
    def answer(i, req):
        return {0: b"", 1: b"01A+0001.111\r01A+0002.222\r"}.get(i, b"01A+0003.333\r")

    path, close = _pty_gauge(answer)
    probe = SerialProbe(SerialConfig(port=path, timeout_s=0.2, preset="mitutoyo"))
    try:
        with pytest.raises(BadSample, match="did not answer"):
            probe.read()
        with pytest.raises(BadSample, match=r"two answers to one request \(b'01A\+0001\.111"
                           r"\\r', then b'01A\+0002\.222\\r'\)"):
            probe.read()
        assert probe.read().reading_mm == pytest.approx(3.333)
        assert probe.read().reading_mm == pytest.approx(3.333)  # no longer suspect
    finally:
        probe.close()
        close()


def test_a_gauge_may_end_its_lines_with_lf_or_cr_lf_whatever_the_request_ends_with():
    """A custom gauge asked with CR that answers with LF waited timeout_s for every sample (the
    line end was guessed from the request) and was read only because the timed-out bytes
    ended in LF (an outside audit, 2026-11-29). Either line end ends a line now, a CR LF pair
    kept whole in the raw bytes."""
    import time

    path, close = _pty_gauge(lambda i, req: b"+1.2345\n" if i % 2 == 0 else b"+1.2346\r\n")
    probe = SerialProbe(SerialConfig(port=path, timeout_s=1.0, preset="custom", request="R\\r",
                                     pattern=r"^([-+]?\d+\.\d+)$"))
    try:
        t0 = time.monotonic()
        got = [probe.read() for _ in range(4)]
        took = time.monotonic() - t0
    finally:
        probe.close()
        close()
    assert [s.reading_mm for s in got] == pytest.approx([1.2345, 1.2346] * 2)
    assert [s.raw for s in got] == [b"+1.2345\n", b"+1.2346\r\n"] * 2
    assert took < 2.0  # four timeouts would be 4 s
