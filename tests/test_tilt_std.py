"""The tilt correction's std counts the learned noise's own uncertainty: the tilt's conditional
posterior scales with the noise sd, which rests on nu degrees of freedom, so its posterior is a
Student-t. Checked where the answer is known exactly -- a plane seen by n touches, where the
slope's error over its learned standard error is a pivot, t on n - 3 dof -- by Monte Carlo over
fixed seeds, and in ``flatness_answer`` against the same draws without the factor."""
import numpy as np
import pytest
from scipy.stats import norm, t as student_t

from adaptive_cal.analysis.flatness_answer import flatness_answer, noise_dof, t_std_factor
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.gaussian import belief as bl

from helpers import sim_cell


def test_the_factor_gives_a_t_its_two_sd_share():
    for nu in (3.0, 5.0, 9.0, 30.0):
        f = t_std_factor(nu)
        assert student_t.cdf(2.0 * f, nu) - student_t.cdf(-2.0 * f, nu) == pytest.approx(
            2.0 * norm.cdf(2.0) - 1.0, abs=1e-9)
        if nu >= 4:  # close to the t's own std
            assert f == pytest.approx(np.sqrt(nu / (nu - 2.0)), rel=0.03)
    assert t_std_factor(1e6) == pytest.approx(1.0, abs=1e-5)
    assert t_std_factor(0.0) == 1.0  # no degrees of freedom: nothing to count


def test_a_slope_lies_within_two_sd_as_often_as_it_says():
    """2,000 planes seen by 8 touches (5 dof): slope +- 2 sd with the factor holds the truth
    0.9545 +- 0.0047 (1 sd of 2,000 Bernoulli draws; allowed 3 sd); with the learned sd taken
    as exact, P(|t_5| < 2) = 0.898."""
    rng = np.random.default_rng(3)
    n, runs, sigma = 8, 2000, 0.005
    xy = rng.uniform(-200, 200, (n, 2))
    X = np.c_[np.ones(n), xy]
    held = plug = 0
    for _ in range(runs):
        z = sigma * rng.standard_normal(n)
        coef = np.linalg.lstsq(X, z, rcond=None)[0]
        s = np.sqrt(np.sum((z - X @ coef) ** 2) / (n - 3))
        cov = s**2 * np.linalg.inv(X.T @ X)
        sd = np.sqrt(cov[2, 2]) * t_std_factor(noise_dof(X, bl.Belief(coef, cov), s))
        held += abs(coef[2]) <= 2.0 * sd
        plug += abs(coef[2]) <= 2.0 * np.sqrt(cov[2, 2])
    assert abs(held / runs - 0.9545) <= 3 * 0.0047
    assert abs(plug / runs - 0.898) <= 3 * 0.0068


def test_the_run_answer_scales_the_same_draws():
    """With the touches given, the tilt's stds are those of the same draws times the factor of
    the dof the touches leave; without them (no learned noise to count) they stay as drawn."""
    plan = survey_plan(sim_cell())
    rng = np.random.default_rng(4)
    xy = np.c_[rng.uniform(-215, 215, 14), rng.uniform(-175, 175, 14)]
    z = 0.01 * xy[:, 0] / 225.0 + 0.004 * rng.standard_normal(14)
    rows = plan.model.surface.basis(*xy.T)
    belief = bl.condition(plan.model.belief(plan.model.hyper0), rows, z, 0.004**2)
    bare = flatness_answer(plan, belief, 0.004)["tilt"]
    told = flatness_answer(plan, belief, 0.004, (xy[:, 0], xy[:, 1], z))["tilt"]
    nu = noise_dof(rows, belief, 0.004)
    assert told["noise_dof"] == pytest.approx(nu) and 2.0 < nu < 14.0
    for k in ("rx_std_deg", "ry_std_deg"):
        assert told[k] == pytest.approx(bare[k] * t_std_factor(nu), rel=1e-12)
    assert told["rx_deg"] == bare["rx_deg"] and "noise_dof" not in bare
    stated = flatness_answer(plan, belief, 0.004, (xy[:, 0], xy[:, 1], z), noise_learned=False)
    # a noise the cell states and does not learn is taken as exact: the stds as drawn
    assert "noise_dof" not in stated["tilt"]
    assert stated["tilt"]["rx_std_deg"] == bare["rx_std_deg"]


def test_the_report_and_the_summary_say_what_the_std_is():
    from adaptive_cal.report.sections import tilt_angles, tilt_section

    tilt = {"rx_deg": 0.1, "ry_deg": -0.8, "a": 0.014, "b": 0.0019, "c": 0.2,
            "rx_std_deg": 0.0006, "ry_std_deg": 0.0005, "noise_dof": 17.84}
    assert tilt_angles(tilt) == "rx +0.1000 +- 0.0006 deg, ry -0.8000 +- 0.0005 deg (1 sd)"
    assert "a Student-t on 17.8 degrees of freedom" in tilt_section(tilt)
    bare = {k: v for k, v in tilt.items() if k not in ("rx_std_deg", "ry_std_deg", "noise_dof")}
    assert tilt_angles(bare) == "rx +0.1000 deg, ry -0.8000 deg"
    assert "Student-t" not in tilt_section(bare)
