"""explain on readings it cannot misread, from an outside audit (2026-11-24):

- a gross error of any size is a suspect: a 1 mm misread on 10 um noise stood as "unexplained
  structure" (112 um RMS) while a 0.1 mm one was set aside -- the gross-error density was a
  normal of 20 noise sds, thinner-tailed far out than the good readings' Student-t;
- a noise-free simulation written to 6 decimals is rounding, not physics: a reversal of
  0.0004 um was named at probability 1.00 (log BF 38), far below the probe's readout step.

Recordings from tests/spike_generator.py (DESIGN.md's physics only) on the Cheng cell's S-path.
"""
import numpy as np
import pytest

import spike_generator as gen
from adaptive_cal.analysis.explain import explain


def _findings(tmp_path, cell, case, name):
    rec = gen.write(tmp_path / f"{name}.csv", case)
    return explain([rec], cell, identifiability=False).findings


@pytest.mark.parametrize("sigmas", [100.0, 500.0])  # 1 mm and 5 mm on 10 um noise
def test_a_misread_of_any_size_is_a_suspect_not_structure(tmp_path, cheng_cell, sigmas):
    rng = np.random.default_rng([77, int(sigmas)])
    case = gen.readings(rng, spike_sigma=sigmas)
    f = _findings(tmp_path, cheng_cell, case, "spike")
    assert f["verdict"] == "none"
    assert [s["seq"] for s in f["suspect_readings"]] == [case["spike_seq"]]
    s = f["suspect_readings"][0]
    assert s["probability"] > 0.99
    assert abs(abs(s["residual_mm"]) - sigmas * gen.NOISE_MM) < 5 * gen.NOISE_MM


def test_a_noise_free_recording_names_no_effect_below_the_readout_step(tmp_path, cheng_cell):
    x, y = gen.s_path()
    direction = np.sign(np.gradient(x))  # rows alternate +x / -x
    h = 0.01 * x - 0.004 * y + 0.2 + 2e-7 * direction  # a "reversal" of 0.0004 um
    f = _findings(tmp_path, cheng_cell, {"x": x, "y": y, "reading": h}, "exact")
    assert f["verdict"] == "none" and not f["suspect_readings"]
    assert f["readout_limited"]["rms_mm"] < f["readout_limited"]["readout_mm"] == 1e-4
    assert all(c["log_bayes_factor"] <= 0.0 for c in f["candidates"])


def test_a_real_reversal_is_still_named_and_not_readout_limited(tmp_path, cheng_cell):
    rng = np.random.default_rng(5)
    x, y = gen.s_path()
    direction = np.sign(np.gradient(x))
    h = 0.01 * x - 0.004 * y + 0.2 + 0.03 * direction + gen.NOISE_MM * rng.standard_normal(x.size)
    f = _findings(tmp_path, cheng_cell, {"x": x, "y": y, "reading": h}, "reversal")
    assert f["verdict"] == "reversal" and "readout_limited" not in f


def test_the_report_says_the_mismatch_is_below_the_readout_step():
    from adaptive_cal.report.explain_text import none_line
    line = none_line({"candidates": [{"effect": "reversal", "log_bayes_factor": 0.0}],
                      "readout_limited": {"rms_mm": 2.4e-7, "readout_mm": 1e-4}})
    assert "RMS 0.0002 um" in line and "readout step (0.1 um)" in line and "rounding" in line
