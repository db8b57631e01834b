"""A re-check's guard (``planning.clearance.Guard``): where the correction assumed and the one
really applied differ, the plate may stand millimetres from where the belief puts it. An outside
safety audit (2026-11-29) drove a re-check 13 mm past the probe's stroke end on its first touch:
2 deg assumed applied but not, about an origin 525 mm away. Now the probe travels clear of the
plate in every frame not yet refuted, and approaches in steps from above the highest. Checked
here by brute force over plate heights and against the simulated plate's TRUE surface."""
import contextlib
import io
import math
import re

import numpy as np
import pytest
import yaml
from scipy.stats import norm

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.cell.schema import load_cell, load_yaml
from adaptive_cal.cli import main
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.hardware.base import Sample, TouchRejected
from adaptive_cal.hardware.cycle import ProbeCycle
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.clearance import Guard

from helpers import SIM_CELL, record_moves
from test_adapter_probe_cycle import Motion

LO, HI, ZERO = 0.5, 9.5, 5.0  # the sim cell's usable stroke and zero (mm)


@pytest.fixture(scope="module")
def plan():
    return survey_plan(load_cell(SIM_CELL))


def _frame(plan, offset_mm):
    """The sim cell's prior moved up by ``offset_mm`` (its offset is a constant coefficient
    shift: a not-a-knot spline reproduces constants)."""
    b = sv.start(plan).belief
    ones = np.linalg.lstsq(plan.model.surface.basis(*plan.eval_xy.T),
                           np.ones(len(plan.eval_xy)), rcond=None)[0]
    return bl.Belief(b.mean + offset_mm * ones, 1e-6 * np.eye(len(b.mean)))


@pytest.mark.parametrize("offset", [3.0, 4.6, 7.0, 13.0, 26.0])
def test_no_plate_height_between_the_frames_overruns_the_stroke(plan, offset):
    """Every plate height from below the belief's window to the other frame's (and 4 mm above
    it where the first step puts it mid-stroke): the first step that reads inside the stroke
    reads at most its top, by brute force."""
    guard = Guard(plan, [_frame(plan, offset)])
    z_mm = 0.0  # the belief's own approach: its plate at ZERO - mid = 0 mm reads mid-stroke
    zs = guard.approaches(0.0, 0.0, z_mm)
    assert zs[-1] == z_mm and all(a > b for a, b in zip(zs, zs[1:]))
    assert all(a - b <= Guard.STEP * (HI - LO) + 1e-12 for a, b in zip(zs, zs[1:]))
    if offset <= HI - 0.5 * (LO + HI) - 0.01:  # the other frame reads inside from z_mm
        assert zs == [z_mm]
    else:
        assert zs[0] == pytest.approx(z_mm + offset, abs=1e-6)  # its plate mid-stroke
    for h in np.linspace(-10.0, offset + (4.0 if len(zs) > 1 else 0.0), 2001):
        readings = [min(max(h - z + ZERO, 0.0), 10.0) for z in zs]
        first = next((r for r in readings if r >= LO), None)
        assert first is None or first <= HI, (h, zs, readings)


def test_a_refuted_frame_costs_nothing_more(plan):
    guard = Guard(plan, [_frame(plan, 13.0)])
    assert len(guard.approaches(0.0, 0.0, 0.0)) == 3 and guard.top_mm((0, 0), (50, 50)) > 12.0
    for k in range(5):  # no contact, or the stroke's end: not a reading of the plate's height
        guard.seen(10.0 * k, 0.0, 0.0, (0.0, 10.0)[k % 2])
    assert guard.refuted == [0]
    for k in range(Guard.REFUTE):  # readings where the belief put the plate: 13 mm below it
        assert guard.live()
        guard.seen(10.0 * k, 0.0, 0.0, 5.0)
    assert not guard.live()
    assert guard.approaches(0.0, 0.0, 0.0) == [0.0] and guard.top_mm((0, 0), (50, 50)) == -math.inf
    near = Guard(plan, [_frame(plan, 13.0)])
    for k in range(5):  # readings that agree with the other frame refute nothing
        near.seen(10.0 * k, 0.0, 13.0, 5.0)
    assert near.live()


def test_readings_where_no_frame_puts_the_plate_refute_none(plan):
    """An outside audit: the truth a third frame, its readings 9 mm from both the frame assumed
    and the other: they had refuted the other and ended the guard, and the next touch overran.
    Only readings where the assumed frame puts the plate count."""
    guard = Guard(plan, [_frame(plan, 13.0)], assumed=_frame(plan, 0.0))
    for k in range(5):  # 6.5 mm from either (a reading of 6.5 from z = 5: height 6.5)
        guard.seen(10.0 * k, 0.0, 6.5, 5.0)
    assert guard.refuted == [0] and guard.live()
    for k in range(Guard.REFUTE):  # where the assumed frame puts it: 13 mm below the other
        guard.seen(10.0 * k, 0.0, 0.0, 5.0)
    assert not guard.live()


def test_the_cells_own_prior_is_cleared_until_readings_bound_the_plate(plan):
    """A third frame the guard was not told of (an outside audit: a sign flipped, 13 mm past the
    stroke's end): the cell's own prior, told every reading, bounds where the plate may stand.
    At a corner, before any reading, it lets the plate stand far above the belief's approach:
    the touch is approached in steps from its top, which reads mid-stroke at the first. Three
    readings spread over a level plate bound it: one plain approach there after them."""
    safety = sv.start(plan).belief
    guard = Guard(plan, [], safety=safety)
    h = plan.model.surface.basis(np.array([215.0]), np.array([175.0]))
    mean, var = (float(v[0]) for v in bl.predict(safety, h))
    top = mean + norm.isf(0.5e-6) * var ** 0.5  # the two-sided 1-in-10^6 top, written out
    zs = guard.approaches(215.0, 175.0, 0.0)
    assert len(zs) > 2 and zs[0] == pytest.approx(top + ZERO - 0.5 * (LO + HI), abs=1e-6)
    assert guard.soft_top_mm((0.0, 0.0), (215.0, 175.0)) == pytest.approx(top, abs=1e-6)
    for x, y in ((-200.0, -160.0), (200.0, -160.0), (0.0, 160.0)):
        guard.seen(x, y, 0.0, ZERO)  # the plate at height 0 there
    assert guard.approaches(215.0, 175.0, 0.0) == [0.0]
    assert guard.soft_top_mm((0.0, 0.0), (215.0, 175.0)) < 0.5  # the form prior alone: 4.9 x 0.05 mm


def test_the_cells_own_prior_is_cleared_as_far_as_the_workspace_box_reaches(plan):
    """The box is where the user lets the probe work: the prior's plate above it is not a reason
    to refuse a re-check (the Cheng cell's box ends 19 mm up, its prior's plate 18 mm at a
    corner), as a frame's is; its steps and travels stop at the box's top."""
    from dataclasses import replace

    boxed = replace(plan, z_range_mm=(-20.0, 18.0))
    guard = Guard(boxed, [], safety=sv.start(plan).belief)
    assert guard.approaches(215.0, 175.0, 0.0)[0] == pytest.approx(18.0)
    m = Motion((0.0, 0.0, 15.0))
    cycle = ProbeCycle(m, Plate(m, 0.0), lambda x, y, z: z <= 18.0, 15.0, (LO, HI),
                       reach_mm=5.0, guard=guard)
    touch = cycle.touch(215.0, 175.0, 0.0, lambda xy: 0.2)
    assert max(p[2] for p in m.sent) == pytest.approx(18.0) and LO <= touch.reading_mm <= HI


def test_a_stop_during_a_guarded_approach_names_the_height_sent(plan):
    """An outside audit: 'THE PROBE MAY BE DOWN' named the belief's approach height, 13 mm below
    the step the probe had been sent to."""
    from adaptive_cal.hardware.base import ProbeLeftDown

    class Stuck(Motion):
        def move_to(self, *p):
            if self.sent and self.sent[-1][2] == pytest.approx(13.0):
                raise KeyboardInterrupt  # the retract after the first step
            super().move_to(*p)

    m = Stuck((0.0, 0.0, 15.0))

    class NoContact(Plate):
        def read(self):
            raise TouchRejected("samples spread", 5.0, ("rejected", "spread"))

    cycle = ProbeCycle(m, NoContact(m, 13.0), lambda x, y, z: True, 15.0, (LO, HI),
                       reach_mm=5.0, guard=Guard(plan, [_frame(plan, 13.0)]))
    with pytest.raises(ProbeLeftDown, match=r"approach z=13\.000 mm"):
        cycle.touch(0.0, 0.0, 0.0, lambda xy: 15.0)


class Plate:
    """A probe over a flat plate at ``height`` (mm): reads what the tip would, clipped to its
    10 mm stroke."""

    def __init__(self, motion, height):
        self.motion, self.height = motion, height

    def read(self):
        z = self.motion.pose[2]
        return Sample(min(max(self.height - z + ZERO, 0.0), 10.0), 0.0)

    def close(self):
        pass


@pytest.mark.parametrize("height, reads_at", [(13.0, 13.0), (6.25, 6.25), (0.0, 0.0)])
def test_the_cycle_steps_down_until_the_probe_reads(plan, height, reads_at):
    """The other frame 13 mm above the belief's: approaches at 13, 6.25 and 0 mm. A plate there
    is read at the first; between, at the second; where the belief says, at the last, the steps
    above it unrecorded (no contact) and the travel clear of the higher frame."""
    m = Motion((0.0, 0.0, 15.0))
    guard = Guard(plan, [_frame(plan, 13.0)])
    cycle = ProbeCycle(m, Plate(m, height), lambda x, y, z: True, 15.0, (LO, HI), reach_mm=5.0,
                       guard=guard)
    touch = cycle.touch(0.0, 0.0, 0.0, lambda xy: 0.2)
    assert touch.z_mm == pytest.approx(reads_at) and LO <= touch.reading_mm <= HI
    down = [p[2] for p in m.sent if p[:2] == (0.0, 0.0)]
    assert down[0] >= 13.0 + 5.0 + 0.5  # the travel clears the other frame's plate
    assert min(down) == pytest.approx(reads_at)


def test_a_plate_below_every_frame_is_a_stroke_end_at_the_last_step(plan):
    m = Motion((0.0, 0.0, 15.0))
    cycle = ProbeCycle(m, Plate(m, -6.0), lambda x, y, z: True, 15.0, (LO, HI), reach_mm=5.0,
                       guard=Guard(plan, [_frame(plan, 13.0)]))
    with pytest.raises(TouchRejected) as e:
        cycle.touch(0.0, 0.0, 0.0)
    assert e.value.z_mm == 0.0 and "stroke_end" in e.value.flags and e.value.reading_mm < LO


def _far_cell(tmp_path, seed):
    """The audit's cell: the plate 300..750 mm from the frame's origin, tilted 2 deg about x,
    level at its middle (x = 525 mm)."""
    data = load_yaml(SIM_CELL)
    data["workplane"].update(x_mm=[300.0, 750.0], keep_outs=[])
    data["workspace"].update(x_mm=[295.0, 755.0], z_mm=[-40.0, 80.0])
    data["model"]["tilt_std_deg"], data["robot"]["safe_height_mm"] = 3.0, 30.0
    data["simulation"].update(seed=seed)
    data["simulation"]["effects"]["tilt"] = {"a": 0.035, "b": 0.0019, "c": -0.035 * 525}
    path = tmp_path / f"far-{seed}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_correction_assumed_but_not_applied_never_overruns_far_from_the_origin(tmp_path,
                                                                               monkeypatch):
    """The audit's case through the command line: mapped, the proposed 2 deg correction not
    applied, the re-check run assuming it. The second line says the frames lie over 18 mm apart;
    the re-check stops as prior_disagrees_with_readings (exit 1) and no approach ever pushed
    the probe past its usable stroke on the TRUE plate, nor dragged it over the plate."""
    assert main(["run", "--robot", str(_far_cell(tmp_path, 1)), "--out", str(tmp_path / "first"),
                 "--no-progress"]) == 0
    from adaptive_cal.run.recheck import frame_shift_mm

    far = load_cell(_far_cell(tmp_path, 2))  # the other frame lies as far whatever is assumed
    shifts = [frame_shift_mm(tmp_path / "first", far, c) for c in ("proposed", "none", (0.0, 0.1))]
    assert min(shifts) > 18.0, shifts  # (an outside audit: a measured one said nothing)
    sent, sims = record_moves(monkeypatch)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        rc = main(["run", "--robot", str(_far_cell(tmp_path, 2)), "--out", str(tmp_path / "re"),
                   "--prior-from", str(tmp_path / "first"), "--no-progress"])
    lines = out.getvalue().splitlines()
    assert rc == 1 and "stopped: prior disagrees with readings" in out.getvalue(), out.getvalue()
    said = re.match(r"the correction moves the earlier plate by up to ([0-9.]+) mm", lines[1])
    assert said and float(said.group(1)) > 18.0, lines[:3]  # 2 deg at 525 mm and more
    surface = sims[0].surface_mm
    x, y, z = (np.array(v) for v in zip(*sent))
    pushed = surface(x, y) - z + ZERO  # the indication each target would give, true plate
    assert pushed.max() <= HI + 0.05, f"an approach pushed the probe {pushed.max():.2f} mm in"
    assert pushed.max() >= LO  # the plate was touched: the test tests something
    # its --resume makes no touch: the verdict stands (an outside audit: a resume after such a
    # stop overran the stroke again, 1.9 mm from the first)
    rows = (tmp_path / "re" / "recording.csv").read_text()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", "--resume", str(tmp_path / "re"), "--no-progress"]) == 1
    assert (tmp_path / "re" / "recording.csv").read_text() == rows
    travels = [(a, b) for a, b in zip(sent, sent[1:]) if a[:2] != b[:2]]
    for a, b in travels:  # every travel: the free tip (5 mm below) clears the true plate
        t = np.linspace(0.0, 1.0, 200)
        h = surface(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        assert np.max(h - (min(a[2], b[2]) - ZERO)) < 0.0, (a, b)
