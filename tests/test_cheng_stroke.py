"""The reference cell's gauge as its file describes it: the published Cheng readings are signed
relative indications (the gauge zeroed part-way into its stroke), and the cell's probe block
(``rest_mm``, ``usable_mm``) holds every one of them -- so ``flatness`` with and without
``--robot`` use the same touches, and explain uses the readings the run would."""
import numpy as np
import pytest

from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from conftest import CHENG, ROOT

CELL = ROOT / "configs" / "cheng2025-cell.yaml"
ROUNDS = sorted(CHENG.glob("round*.csv"))


def test_every_published_reading_lies_in_the_cells_usable_stroke(cheng_cell):
    lo, hi = cheng_cell.probe.usable_mm
    start = cheng_cell.probe.rest_mm
    assert start <= lo and hi <= start + cheng_cell.probe.stroke_mm
    readings = np.concatenate([read_recording(p).reading_mm for p in ROUNDS])
    assert readings.min() < 0  # signed relative indications: the gauge was zeroed mid-stroke
    assert lo <= readings.min() and readings.max() <= hi


@pytest.mark.parametrize("name", [p.name for p in ROUNDS])
def test_flatness_with_and_without_the_cell_use_the_same_touches(name, capsys):
    path = str(CHENG / name)
    assert main(["flatness", path]) == 0
    bare = capsys.readouterr()
    assert main(["flatness", path, "--robot", str(CELL)]) == 0
    replayed = capsys.readouterr()
    assert "usable stroke" not in replayed.err  # nothing set aside
    assert f"{path}: 40 touches" in bare.out and f"{path}: 40 touches" in replayed.out
    points = [line.split(":")[1].split(";")[0] for line in (bare.out + replayed.out).splitlines()
              if "flatness of the 40 touched points" in line]
    assert len(points) == 2 and points[0].split("(95")[0] == points[1].split("(95")[0]


def _probe(**probe):
    data = load_yaml(CELL)
    data["probe"] = {**data["probe"], **probe}
    return parse_cell(data)


def test_rest_mm_shifts_the_stroke_and_usable_or_zero_outside_it_is_refused_naming_the_key():
    assert _probe(rest_mm=-2.0, usable_mm=[-2.0, 8.0], zero_mm=-1.0).probe.usable_mm == (-2.0, 8.0)
    with pytest.raises(ConfigError, match=r"probe\.usable_mm: usable_mm=\[-1\.0, 9\.6\] must lie "
                       r"inside the stroke \[-0\.5, 9\.5\] mm \(rest_mm -0\.5"):
        _probe(usable_mm=[-1.0, 9.6])
    with pytest.raises(ConfigError, match=r"probe\.zero_mm: zero_mm=-0\.7 must lie inside the "
                       r"stroke \[-0\.5, 9\.5\]"):
        _probe(zero_mm=-0.7)
    with pytest.raises(ConfigError, match=r"probe\.rest_mm"):  # the stroke's start is never above 0
        _probe(rest_mm=0.5)
    with pytest.raises(ConfigError, match=r"probe\.usable_mm.*\[0, 10\]"):  # the default: from 0
        parse_cell({**load_yaml(CELL), "probe": {"usable_mm": [-0.5, 9.5]}})


def test_a_gauge_zeroed_mid_stroke_reads_below_zero_in_the_simulator_and_the_manual_prompt():
    # the simulated probe clipped its indication to [0, stroke] and the manual prompt refused a
    # typed reading below 0, whatever rest_mm said: the reference cell's gauge reads -0.5 .. 9.5
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.run.devices import open_cell
    from adaptive_cal.simulation.cell import SimulatedCell

    cell = load_cell(ROOT / "configs" / "cheng2025-cell.yaml")
    sim = SimulatedCell.from_cell(cell)
    sim.move_to(0.0, 0.0, 0.3)  # 0.3 mm above the level plate's nominal height, zero_mm 0
    readings = [sim.read().reading_mm for _ in range(20)]
    assert -0.45 < np.mean(readings) < -0.15  # the noise is 10 um: -0.3 within 15 sd
    sim.move_to(0.0, 0.0, 2.0)  # beyond the tip's free end: the gauge hangs at its rest
    assert sim.read().reading_mm == pytest.approx(-0.5)
    manual = cell.model_copy(update={
        "robot": cell.robot.model_copy(update={"adapter": "manual"}),
        "probe": cell.probe.model_copy(update={"adapter": "manual"})})
    assert open_cell(manual).cycle.probe.range_mm == (-0.5, 9.5)
