"""The free probe tip hangs ``zero_mm - rest_mm`` below the commanded height: a travel at the
safe height dragged it over a plate standing higher than that (an outside safety audit,
2026-11-29: a 1 m plate at 1.2 deg read up to 0.33 mm of indication while travelling, a 5.7 deg
one travelled with the probe pushed 5 mm into its stroke; every run ended on its bound, exit 0).
Now the travel to each touch goes high enough to clear the plate under it, as the belief bounds
it (``planning.clearance``), or nothing is sent. Checked against the simulated plate's TRUE
surface, by this file's own arithmetic."""
import json
import math

import numpy as np
import pytest
import yaml

from adaptive_cal.cell.schema import load_yaml
from adaptive_cal.cli import main
from adaptive_cal.hardware.base import CLEARANCE_MM, UnsafeTarget
from adaptive_cal.hardware.cycle import ProbeCycle

from helpers import SIM_CELL, record_moves
from test_adapter_probe_cycle import Motion, Probe  # recording fakes


def _cycle(motion, allowed=lambda x, y, z: True):
    return ProbeCycle(motion, Probe(), allowed, safe_height_mm=15.0, usable_mm=(0.5, 9.5),
                      reach_mm=5.0)


def test_the_travel_rises_above_a_plate_the_tip_would_reach():
    m = Motion((0.0, 0.0, 15.0))
    asked = []

    def top(from_xy):
        asked.append(from_xy)
        return 12.0  # the plate may stand 12 mm high under this travel: 12 + 5 > 15

    _cycle(m).touch(100.0, 50.0, 11.0, top)
    travel = 12.0 + 5.0 + CLEARANCE_MM
    assert asked == [(0.0, 0.0)]  # from where the probe is
    assert m.sent == [(0.0, 0.0, travel), (100.0, 50.0, travel), (100.0, 50.0, 11.0),
                      (100.0, 50.0, travel)]
    m2 = Motion((0.0, 0.0, 15.0))
    _cycle(m2).touch(100.0, 50.0, 2.0, lambda xy: 3.0)  # a low plate: the safe height as before
    assert [p[2] for p in m2.sent] == [15.0, 2.0, 15.0]


def test_a_travel_the_workspace_cannot_hold_sends_nothing_and_names_the_keys():
    m = Motion((0.0, 0.0, 15.0))
    box = lambda x, y, z: z <= 16.0  # noqa: E731
    with pytest.raises(UnsafeTarget, match=r"robot\.safe_height_mm=15 would drag it over the "
                                           r"plate.*workspace\.z_mm"):
        _cycle(m, box).touch(100.0, 50.0, 11.0, lambda xy: 12.0)
    assert m.sent == []


def _free_everywhere(sent, surface, reach_mm):
    """The worst (surface - (z - reach)) over every travel: segments between consecutive targets
    that change x or y, sampled every 1 mm, at the lower of their two heights (mm; below 0: the
    tip hangs free)."""
    worst = -math.inf
    for (x0, y0, z0), (x1, y1, z1) in zip(sent, sent[1:]):
        d = math.hypot(x1 - x0, y1 - y0)
        if d < 1e-9:
            continue  # a plunge or a lift at one place: the approach touches by design
        t = np.linspace(0.0, 1.0, int(d) + 2)
        h = surface(x0 + t * (x1 - x0), y0 + t * (y1 - y0))
        worst = max(worst, float(np.max(h - (min(z0, z1) - reach_mm))))
    return worst


def test_a_large_tilted_plate_is_never_dragged_over(tmp_path, monkeypatch):
    """The audit's plate: 1 m wide, tilted 1.2 deg (the default 1 deg tilt prior), the safe
    height 15 mm, the tip reaching 5 mm below: its far edge stands 10.5 mm high."""
    cell = load_yaml(SIM_CELL)
    cell["workplane"]["x_mm"] = [-500.0, 500.0]
    cell.setdefault("workspace", {})
    cell["workspace"] = {**(cell.get("workspace") or {}), "x_mm": [-505.0, 505.0]}
    cell["simulation"]["effects"]["tilt"] = {"a": 0.021, "b": 0.0019, "c": 0.2}
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(cell))
    sent, sims = record_moves(monkeypatch)
    assert main(["run", "--robot", str(path), "--out", str(tmp_path / "run"),
                 "--no-progress"]) == 0
    reach = cell["probe"].get("zero_mm", 5.0) - cell["probe"].get("rest_mm", 0.0)
    worst = _free_everywhere(sent, sims[0].surface_mm, reach)
    assert worst < -CLEARANCE_MM + 0.05, f"the tip reached {worst:.3f} mm into the plate"
    # the plate does stand within the tip's reach of the safe height: the test tests something
    assert float(sims[0].surface_mm(np.array([500.0]), np.array([185.0]))[0]) > \
        cell["robot"]["safe_height_mm"] - reach


@pytest.mark.parametrize("park", [(-225.0, 0.0, 15.0), (-225.0, -185.0, 15.0)])
def test_a_probe_parked_beside_the_plate_rises_where_it_stands(park):
    """A second safety audit (2026-11-29): with the travel raised, a probe parked at the safe
    height over the edge margin or beside the plate needed a lift where it stood, and the lift
    -- no new x, y -- was refused by the edge-margin rule, which is about touches: the shipped
    sim cell could not start from such a home. The lift is checked against the workspace box
    alone; the travel and the touch against everything as before."""
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.run.devices import box_check, safety_check

    cell = load_cell(SIM_CELL)
    m = Motion(park)
    cycle = ProbeCycle(m, Probe(), safety_check(cell), 15.0, (0.5, 9.5), reach_mm=5.0,
                       lift_allowed=box_check(cell))
    cycle.touch(0.0, 0.0, 0.2, lambda xy: 20.0)  # the prior's 1 in 10^6 over the plate's edge
    assert m.sent[0] == (park[0], park[1], 25.5) and m.sent[1] == (0.0, 0.0, 25.5)
    for where, top in ((park, 60.0), ((-300.0, 0.0, 15.0), 20.0)):  # the box still holds:
        m = Motion(where)  # above its top (60 mm), or outside it (x -230..230 mm)
        with pytest.raises(UnsafeTarget, match="nothing was sent"):
            ProbeCycle(m, Probe(), safety_check(cell), 15.0, (0.5, 9.5), reach_mm=5.0,
                       lift_allowed=box_check(cell)).touch(0.0, 0.0, 0.2, lambda xy: top)
        assert m.sent == []


def test_the_operator_of_a_manual_cell_is_told_a_raised_travel():
    import io

    from adaptive_cal.hardware.manual.adapter import ManualCell

    out = io.StringIO()
    cell = ManualCell(out=out, inp=io.StringIO("5.0\n"), range_mm=(0.0, 10.0))
    cell.pose = (0.0, 0.0, 15.0)
    ProbeCycle(cell, cell, lambda x, y, z: True, 15.0, (0.5, 9.5), reach_mm=5.0,
               sleep=lambda s: None).touch(100.0, 50.0, 11.0, lambda xy: 12.0)
    assert "probe reference z=11.000 mm (travel there at z=17.500 mm)" in out.getvalue()


def test_a_refused_travel_says_what_to_raise_and_a_resume_with_it_goes_on(tmp_path, capsys):
    """The audit's plate in a box too low for its travel: the run stops before that travel with
    its touches kept. --resume alone would ask the same travel and be refused again (it had
    advised exactly that); the advice names the cell keys to raise, and a resume with a copy
    that raises them (the box's height may differ on a resume) goes on from the next seq."""
    cell = load_yaml(SIM_CELL)
    cell["workplane"]["x_mm"] = [-500.0, 500.0]
    cell["workspace"] = {**cell["workspace"], "x_mm": [-505.0, 505.0], "z_mm": [-20.0, 15.5]}
    cell["simulation"]["effects"]["tilt"] = {"a": 0.021, "b": 0.0019, "c": 0.2}
    low, out = tmp_path / "low.yaml", tmp_path / "run"
    low.write_text(yaml.safe_dump(cell))
    assert main(["run", "--robot", str(low), "--out", str(out), "--no-progress"]) == 2
    said = capsys.readouterr()
    assert "would drag it over the plate" in said.err and "nothing was sent" in said.err
    assert (f"Continue with adaptive-cal run --resume {out} --robot CHANGED.yaml, a copy of the "
            "run's cell.yaml changed as the error says (robot.safe_height_mm and workspace.z_mm "
            "may differ on a resume") in said.out
    assert "Raise robot.safe_height_mm and workspace.z_mm's top" in said.err  # what to change
    touched = len((out / "recording.csv").read_text().splitlines())
    cell["workspace"]["z_mm"] = [-20.0, 30.0]
    cell["robot"]["safe_height_mm"] = 20.0
    cell["plan"]["stop"] = {**cell["plan"]["stop"], "max_touches": touched + 2}
    higher = tmp_path / "higher.yaml"
    higher.write_text(yaml.safe_dump(cell))
    assert main(["run", "--resume", str(out), "--robot", str(higher), "--no-progress"]) == 1
    said = capsys.readouterr().out  # exit 1: the small budget given here is spent
    assert "differs from" in said and "workspace.z_mm" in said
    assert json.loads((out / "result.json").read_text())["stopped_because"] == "touch_budget"
    assert len((out / "recording.csv").read_text().splitlines()) > touched
