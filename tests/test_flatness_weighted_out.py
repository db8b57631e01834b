"""flatness with a map says which readings the map weighted out as gross errors: a 100 um misread
left the touched points' figure outside its interval, marked only with the footnote's "biased by
noise and by smoothing" (an audit, 2026-11-24). Now a line and the JSON's ``weighted_out`` name
it, and a clean recording names none."""
import contextlib
import io
import json

import numpy as np

from adaptive_cal.cli import main
from adaptive_cal.formats.writing import RecordingWriter

from helpers import SIM_CELL


def _recording(path, spike_at=None):
    rng = np.random.default_rng(4)
    k = 0
    with RecordingWriter(path) as w:
        for j, y in enumerate(np.linspace(-160, 160, 7)):
            for x in np.linspace(-200, 200, 9)[:: 1 if j % 2 == 0 else -1]:
                r = 5.0 + 0.014 * x + 0.0019 * y + 0.2 + 0.002 * rng.standard_normal()
                w.append(seq=k, t_s=3.0 * k, x_mm=x, y_mm=y, z_mm=0.0,
                         reading_mm=r + (0.1 if k == spike_at else 0.0))
                k += 1
    return path


def _flatness(path, *extra):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(["flatness", "--robot", str(SIM_CELL), str(path), *extra]) == 0
    return out.getvalue()


def test_a_misread_the_map_weighted_out_is_named(tmp_path):
    path = _recording(tmp_path / "spike.csv", spike_at=33)
    text = _flatness(path)
    assert "1 reading weighted out of the map as gross error" in text and "seq 33 (p 1.00)" in text
    data = json.loads(_flatness(path, "--json"))
    assert [w["seq"] for w in data["weighted_out"]] == [33]


def test_a_clean_recording_names_none(tmp_path):
    path = _recording(tmp_path / "clean.csv")
    assert "weighted out" not in _flatness(path)
    assert json.loads(_flatness(path, "--json"))["weighted_out"] == []


def test_a_row_flagged_outlier_1_00_replays_at_the_least_weight(tmp_path):
    """A run writes ``outlier=1.00`` for p >= 0.995 (two decimals); a replay read it as weight 0,
    an infinite noise variance: "rows, readings and noise_var must be finite" (a docs audit,
    2026-11-29). Its weight is now 1e-6, as in the run that wrote it."""
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.planning.gate import W_MIN, flagged_weight

    path = _recording(tmp_path / "spike.csv", spike_at=33)
    text = path.read_text().splitlines()
    head = text.index(next(t for t in text if t.startswith("seq,")))
    cols = text[head].split(",")
    row = text[head + 1 + 33].split(",")
    row[cols.index("flags")] = "outlier=1.00"
    text[head + 1 + 33] = ",".join(row)
    path.write_text("\n".join(text) + "\n")
    assert flagged_weight(read_recording(path).flags[33]) == W_MIN
    out = _flatness(path)
    assert "seq 33 (p 1.00)" in out
    assert main(["report", str(path), "--robot", str(SIM_CELL), "--out",
                 str(tmp_path / "r.html")]) == 0
