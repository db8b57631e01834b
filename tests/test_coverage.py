"""Honest uncertainty: over 20 random plates (tilt up to +-1 deg, form 0.02-0.3 mm of random
shape, reading noise 4-12 um) each run stops at the bound, and the share of the plate inside
the 95 % band, averaged over the plates, lies in [0.90, 0.99]. Seeds are fixed: the figure is
reproducible (measured 0.966, 69.5 touches on average on 2026-11-30 with the refit near the
bound, 0.964 and 69.4 before it -- 0.963 and 59.6 before runs whose learned noise is 1.5 x the
5 um guess took repeat touches, planning.repeats; single plates range 0.89-1.0 on 2026-11-30,
0.78-1.0 before, because map errors are spatially correlated)."""
import numpy as np
import pytest

from adaptive_cal.cell.build import survey_plan
from adaptive_cal.cell.schema import load_yaml, parse_cell
from adaptive_cal.planning import survey as sv
from adaptive_cal.run.devices import open_cell
from adaptive_cal.run.truth import state_truth_error

from helpers import SIM_CELL, drive


def random_plate(seed: int) -> dict:
    rng = np.random.default_rng(1000 + seed)
    data = load_yaml(SIM_CELL)
    rx, ry = rng.uniform(-1, 1, 2)
    w = rng.uniform(-1, 1, 4)
    data["plan"] = {"stop": {"mean_std_mm": 0.004, "max_touches": 200}}
    data["simulation"] = {
        "seed": seed,
        "effects": {"tilt": {"a": float(np.tan(np.radians(ry))), "b": float(np.tan(np.radians(rx))),
                             "c": float(rng.uniform(-0.3, 0.3))},
                    "form": {"pv_mm": float(rng.uniform(0.02, 0.3)), "bow_x": w[0], "bow_y": w[1],
                             "twist": w[2], "warp": w[3]}},
        "noise_std_mm": 0.002, "repeatability_mm": float(rng.uniform(0.004, 0.012))}
    return data


def _run_to_bound(cells):
    """Each cell driven to its variance bound: coverage95 and touches per run."""
    coverage, touches = [], []
    for i, cell in enumerate(cells):
        opened = open_cell(cell)
        plan = survey_plan(cell)
        state = drive(plan, opened)
        assert sv.stop_reason(plan, state) == "mean_std_bound", i
        coverage.append(state_truth_error(plan, state, opened.simulated.surface_mm)["coverage95"])
        touches.append(state.touches)
    return coverage, touches


@pytest.mark.slow
def test_95_percent_bands_cover_the_true_surface_over_20_plates():
    coverage, touches = _run_to_bound(parse_cell(random_plate(seed)) for seed in range(20))
    print(f"coverage95 mean {np.mean(coverage):.3f} (min {np.min(coverage):.3f}); "
          f"touches mean {np.mean(touches):.1f}")
    assert 0.90 <= np.mean(coverage) <= 0.99


@pytest.mark.slow
def test_bands_cover_with_the_datasheet_noise_range_and_no_touch_floor():
    """The study's plates (noise 5-20 um, form up to 0.3 mm) with the planner told the noise
    span (probe.noise_range_mm) and so no floor of K touches: over 16 plates stopped at 7 um RMS
    std the 95 % band covers 0.90-0.99 of the plate, and some runs stop below K touches (the
    floor is really gone). Without the range, these runs needed the floor (docs/study.md)."""
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.plates import plate_cell, sample_plate

    study, base = load_study(SIM_CELL.parent / "study-tilts.yaml")
    study = study.model_copy(update={"bound": study.bound.model_copy(update={"mean_std_mm": 0.007})})
    cells = [plate_cell(study, base, sample_plate(study, i)) for i in range(16)]
    assert all(c.probe.noise_range_mm == (0.005, 0.02) for c in cells)
    coverage, touches = _run_to_bound(cells)
    print(f"coverage95 mean {np.mean(coverage):.3f} (min {np.min(coverage):.3f}); "
          f"touches mean {np.mean(touches):.1f}, fewest {min(touches)}")
    assert 0.90 <= np.mean(coverage) <= 0.99
    assert min(touches) < survey_plan(cells[0]).model.surface.size
