"""The manual adapter: the operator's typed readings, with injected streams."""
import io

import pytest

from adaptive_cal.hardware.base import AdapterError, BadSample
from adaptive_cal.hardware.cycle import ProbeCycle
from adaptive_cal.hardware.manual.adapter import ManualCell


def manual(text, **kw):
    out = io.StringIO()
    return ManualCell(out=out, inp=io.StringIO(text), range_mm=(0.0, 10.0), **kw), out


def test_point_shown_and_typed_reading_returned_through_the_cycle():
    cell, out = manual("abc\n5,0123\n", prompt="(UF1)")
    cyc = ProbeCycle(cell, cell, lambda x, y, z: True, 15.0, (0.5, 9.5), samples=1,
                     sleep=lambda s: None)
    t = cyc.touch(12.5, -3.0, 1.0)
    assert t.reading_mm == pytest.approx(5.0123) and t.samples[0].raw == b"5,0123"
    text = out.getvalue()
    assert "x=12.500 y=-3.000" in text and "(UF1)" in text and "'abc' is not a number" in text


def test_out_of_range_and_nan_asked_again_then_bad_sample():
    cell, out = manual("nan\n12\n-1\n")
    with pytest.raises(BadSample, match="no valid reading in 3") as refused:
        cell.read()
    assert "outside the probe range" in out.getvalue()
    # what was typed is named, in the message and the raw bytes the log shows
    assert "'nan', '12', '-1'" in str(refused.value) and refused.value.raw == b"nan | 12 | -1"


@pytest.mark.parametrize("text, match", [("q\n", "stopped by the operator"), ("", "input ended")])
def test_quit_or_end_of_input_stops_cleanly(text, match):
    cell, _ = manual(text)
    with pytest.raises(AdapterError, match=match):
        cell.read()


def test_ask_callable_replaces_streams():
    answers = iter(["4.5"])
    cell = ManualCell(out=io.StringIO(), ask=lambda prompt: next(answers))
    assert cell.read().reading_mm == 4.5
