"""Readings that agree neither with the map nor with each other at one place end a survey as
``readings_disagree`` (``planning.disagree``). An outside audit (2026-12-01): with
probe.noise_std_mm 0.0001 (0.1 um; the simulated readings' noise about 5 um) the same point was
gated and its retake rejected 12 times over (24 touches); at 0.01 um the touch budget went with
4 readings fused and the map 1.3 mm off, and nothing said why."""
import json
import math
import warnings

import numpy as np
import pytest
import yaml

from adaptive_cal.cell.schema import load_yaml
from adaptive_cal.planning.disagree import DISAGREE_STOP, READINGS_DISAGREE, Disagreements
from adaptive_cal.planning.gate import Told
from tests.helpers import SIM_CELL, sim_cell


def told(fused, flags, x=10.0, y=20.0, height=1.0):
    return Told(fused, flags, 9.0, False, x, y, 0.0, height)


def test_two_rejected_retakes_in_a_row_at_one_place_stop_and_nothing_less_does():
    d = Disagreements()
    assert not d.see(told(False, ("gated",)))
    assert not d.see(told(False, ("retake", "rejected")))
    assert not d.see(told(False, ("gated",)))
    assert d.see(told(False, ("retake", "rejected"))) and DISAGREE_STOP == 2
    d = Disagreements()  # a fused reading between them: counted afresh
    for t in [told(False, ("gated",)), told(False, ("retake", "rejected")),
              told(True, ()), told(False, ("gated",))]:
        assert not d.see(t)
    assert d.rejected == 0 and len(d.heights_mm) == 1
    d = Disagreements()  # another place: counted afresh
    for t in [told(False, ("gated",)), told(False, ("retake", "rejected")),
              told(False, ("gated",), x=50.0), told(False, ("retake", "rejected"), x=50.0)]:
        assert not d.see(t)
    d = Disagreements()  # a millimetre away is the same place (the planner shifts a touch)
    for t in [told(False, ("gated",)), told(False, ("retake", "rejected")),
              told(False, ("gated",), x=10.9)]:
        assert not d.see(t)
    assert d.see(told(False, ("retake", "rejected"), x=10.9))
    d = Disagreements()  # a retake that confirmed the gated reading is fused: no stop
    for t in [told(False, ("gated",)), told(True, ("retake", "surprise"))] * 3:
        assert not d.see(t)


def cell_file(tmp_path, noise_std_mm):
    data = load_yaml(SIM_CELL)
    data["probe"]["noise_std_mm"] = noise_std_mm
    f = tmp_path / "cell.yaml"
    f.write_text(yaml.safe_dump(data))
    return f


def test_a_run_whose_stated_noise_is_far_too_small_stops_and_says_so(tmp_path, capsys):
    from adaptive_cal.cli import main

    code = main(["run", "--robot", str(cell_file(tmp_path, 0.0001)), "--out",
                 str(tmp_path / "run"), "--yes", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2  # error set: its message on stderr after the summary
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["stopped_because"] == READINGS_DISAGREE
    assert result["touches"] <= 14  # was 24 touches at one point, then a result at 114
    assert "noisier than the map assumes" in result["error"]
    assert "spread" in err and "probe.noise_std_mm" in err
    rows = [r.split(",") for r in (tmp_path / "run" / "recording.csv").read_text().splitlines()
            if r[:1].isdigit()]
    assert len(rows) == result["touches"]  # every touch recorded, none lost
    flags = [set(r[6].split(";")) for r in rows[-4:]]
    assert [("gated" in f, {"retake", "rejected"} <= f) for f in flags] == [(True, False),
                                                                            (False, True)] * 2
    assert len({(r[2], r[3]) for r in rows[-4:]}) == 1  # one place


def test_the_library_survey_stops_the_same_way(tmp_path):
    """ask/tell on a plane with 5 um of noise, the cell stating 0.1 um."""
    from adaptive_cal import start_survey

    rng = np.random.default_rng(4)
    survey = start_survey(cell_file(tmp_path, 0.0001))
    plate = lambda x, y: 0.014 * x + 0.0019 * y + 0.2  # noqa: E731  (the quick start's tilt)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        for _ in range(40):
            if survey.stop_reason():
                break
            t = survey.ask()[0]
            reading = plate(t.x_mm, t.y_mm) - t.z_mm + 5.0 + rng.normal(0, 0.005)
            survey.tell(t.x_mm, t.y_mm, t.z_mm, reading)
    assert survey.stop_reason() == READINGS_DISAGREE, survey.stop_reason()
    assert survey.state.touches <= 20
    assert "noisier than the map assumes" in survey.disagreement
    assert any("noisier than the map assumes" in str(w.message) for w in seen)


def test_a_stated_noise_below_the_readout_steps_own_is_warned_about():
    from adaptive_cal.cell.consistency import doubts

    said = doubts(sim_cell(probe={"noise_std_mm": 0.00001}))
    assert len(said) == 1 and said[0].startswith("probe.noise_std_mm: 0.01 um of reading noise "
                                                 "is below what the readout step alone gives")
    assert "0.029 um std" in said[0]
    assert doubts(sim_cell(probe={"noise_std_mm": 0.0001})) == []  # 0.1 um: above 0.029 um
    assert math.isclose(1e-4 / math.sqrt(12) * 1e3, 0.028868, rel_tol=1e-4)


def test_a_recheck_from_a_map_with_a_noise_far_too_small_says_the_map_is_the_cause(tmp_path):
    """A second audit: a re-check from a run whose learned noise was 0.1 um stopped with
    readings_disagree and advised setting probe.noise_std_mm, which cannot help there."""
    from adaptive_cal.gaussian.belief import Belief
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.cell.build import survey_plan

    plan = survey_plan(sim_cell(), informed_prior=True)
    fresh = sv.start(plan)
    state = sv.start(plan, prior=Belief(fresh.belief.mean, fresh.belief.cov),
                     hyper=fresh.hyper._replace(noise_std_mm=1e-4))
    d = Disagreements()
    for t in [told(False, ("gated",), height=1.0), told(False, ("retake", "rejected"), height=1.01),
              told(False, ("gated",), height=1.02), told(False, ("retake", "rejected"), height=1.0)]:
        d.see(t)
    text = d.text(plan, state)
    assert "the map this survey started from" in text and "probe.noise_std_mm" not in text
    assert "probe.noise_std_mm" in d.text(plan, fresh)
