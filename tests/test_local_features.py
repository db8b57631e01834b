"""A local feature a retake confirmed: found by the retake's leave-one-out residual (checked
against a batch posterior without it), kept out when the retake agrees with the map, and
included in the whole plate's flatness."""
import numpy as np
import pytest

from adaptive_cal.analysis import local_features as lf
from adaptive_cal.analysis.flatness_answer import flatness_answer
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.formats.recording import Recording
from adaptive_cal.gaussian import belief as bl

from helpers import sim_cell

SIGMA = 0.005
ZERO = 5.0  # the simulated cell's probe zero: height = reading - zero + z


def _case(first_um: float, retake_um: float, seed: int = 0):
    """40 touches on a flat plate (heights N(0, 5 um)), then a gated reading and its retake at
    (120, -60) mm, ``first_um`` and ``retake_um`` above the plate. Returns the plan, the belief
    conditioned on the fused readings (all but the gated one), the recording and the belief
    without the retake (the oracle)."""
    plan = survey_plan(sim_cell(plan={"candidates": 2000}))
    rng = np.random.default_rng(seed)
    xy = np.c_[rng.uniform(-200, 200, 40), rng.uniform(-160, 160, 40)]
    h = SIGMA * rng.standard_normal(40)
    x = np.r_[xy[:, 0], 120.0, 120.0]
    y = np.r_[xy[:, 1], -60.0, -60.0]
    heights = np.r_[h, first_um * 1e-3, retake_um * 1e-3]
    flags = tuple([frozenset()] * 40 + [frozenset({"gated"}), frozenset({"retake"})])
    n = len(x)
    rec = Recording(np.arange(n), np.arange(n, dtype=float), x, y, np.zeros(n), heights + ZERO,
                    flags)
    surface = plan.model.surface
    prior = plan.model.belief(plan.model.hyper0._replace(noise_std_mm=SIGMA))
    rows = surface.basis(x, y)
    fused = np.r_[np.arange(40), 41]
    post = bl.condition(prior, rows[fused], heights[fused], SIGMA**2)
    without = bl.condition(prior, rows[:40], heights[:40], SIGMA**2)
    return plan, post, rec, without


def test_a_confirmed_dent_is_found_with_its_leave_one_out_departure():
    plan, post, rec, without = _case(-30.0, -25.0)
    found = lf.confirmed(plan.model.surface, post, SIGMA, rec, ZERO)
    assert len(found) == 1 and found[0]["seq"] == [40, 41]
    b = plan.model.surface.basis(np.array([120.0]), np.array([-60.0]))[0]
    # oracle for the test statistic: the batch posterior without the retake (the gated
    # reading was never fused)
    z = (-25e-3 - b @ without.mean) / np.sqrt(SIGMA**2 + b @ without.cov @ b)
    assert found[0]["z"] == pytest.approx(z, rel=1e-6)
    # the departure is from the map as it ends (the retake in it), one reading's sd
    assert found[0]["departure_mm"] == pytest.approx(-25e-3 - b @ post.mean, rel=1e-9)
    assert found[0]["sd_mm"] == SIGMA
    assert "below the map" in lf.feature_line(found[0])


@pytest.mark.parametrize("first_um,retake_um", [(-30.0, 2.0), (-30.0, 25.0), (-30.0, -9.0)])
def test_a_retake_that_does_not_confirm_is_no_feature(first_um, retake_um):
    """The retake agrees with the map (a gross error first), departs the other way, or departs
    less than the bound (2.58 sd for one retake at ALPHA 0.01): nothing is named."""
    plan, post, rec, _ = _case(first_um, retake_um)
    assert lf.confirmed(plan.model.surface, post, SIGMA, rec, ZERO) == []


def test_the_whole_plate_flatness_includes_a_confirmed_feature():
    """The whole plate's figures are those of the map's grid plus the feature's point at the
    retake's height: the minimum zone of exactly that set (computed here) is the value, or it
    lies inside the interval, and it exceeds the map's alone."""
    from adaptive_cal.analysis import flatness as fl

    plan, post, rec, _ = _case(-30.0, -25.0)
    found = lf.confirmed(plan.model.surface, post, SIGMA, rec, ZERO)
    bare = flatness_answer(plan, post, SIGMA)["flatness_mm"]["minimum_zone"]
    with_it = flatness_answer(plan, post, SIGMA, features=found)["flatness_mm"]["minimum_zone"]
    grid_mean = plan.eval_rows @ post.mean
    x = np.r_[plan.eval_xy[:, 0], 120.0]
    y = np.r_[plan.eval_xy[:, 1], -60.0]
    want = fl.minimum_zone_mm(x, y, np.r_[grid_mean, -25e-3]).value_mm
    assert want > bare["value"] + 5e-3
    lo, hi = with_it["ci95"]
    assert with_it["value"] == pytest.approx(want, rel=1e-9) or lo <= want <= hi
