"""The product's quantiles and tail probabilities come from scipy.special, not scipy.stats
(loading scipy.stats is 1-3 s of a command's start-up): the same numbers as scipy.stats's own
distributions, bit for bit (scipy.stats computes them with these special functions)."""
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from adaptive_cal.analysis import flatness_answer
from adaptive_cal.gaussian import checks
from adaptive_cal.planning import closure, scoring


@pytest.mark.parametrize("n", [1, 2, 5, 30, 400, 5000])
@pytest.mark.parametrize("alpha", [0.05, 0.01, 1e-3])
def test_chi2_bounds_are_scipy_stats(n, alpha):
    assert checks.mean_square_interval(n, alpha) == (stats.chi2.ppf(alpha / 2, n) / n,
                                                     stats.chi2.isf(alpha / 2, n) / n)
    assert checks.mean_square_upper(n, alpha) == stats.chi2.isf(alpha, n) / n


@pytest.mark.parametrize("nu", [0.5, 1.0, 2.5, 4.0, 10.0, 1e3, 1e8])
def test_student_t_quantiles_are_scipy_stats(nu):
    assert flatness_answer.t_std_factor(nu) == stats.t.ppf(stats.norm.cdf(2.0), nu) / 2.0
    c = closure.Closure(True, difference_mm=0.001, sd_mm=0.002, dof=nu, p=0.5, passed=True,
                        first_readings=3)
    if nu >= 1.0:
        assert c.detectable_mm == stats.t.isf(closure.ALPHA / 2, nu) * 0.002


def test_closure_p_value_is_scipy_stats():
    rows = np.eye(3)
    got = closure.judge(rows, np.array([0.010, 0.011, 0.009]), rows[:1], np.array([0.0135]),
                        np.zeros(3), np.zeros((3, 3)), 1e-6, 7.0)
    d = 0.0135 - 0.010  # the belief's mean is flat: no change of the surface between the places
    sd = np.sqrt(1e-6 * (1.0 + 1.0 / 3.0))
    assert got.difference_mm == pytest.approx(d, abs=1e-15)
    assert got.p == 2.0 * stats.t.sf(abs(got.difference_mm) / got.sd_mm, 7.0)
    assert got.sd_mm == pytest.approx(sd, rel=1e-14)


def test_normal_quantiles_are_scipy_stats():
    assert scoring.STROKE_Z == stats.norm.isf(0.5e-6)
    assert flatness_answer.TWO_SD == stats.norm.cdf(2.0)


def test_commands_that_do_not_fuse_one_by_one_do_not_load_scipy_stats():
    """flatness of a recording (and report, compensate) condition and sample a belief: they
    load neither filterpy nor scipy.stats."""
    code = ("import sys; import adaptive_cal.analysis.flatness_intervals, "
            "adaptive_cal.run.results, adaptive_cal.report.sections; "
            "print('scipy.stats' in sys.modules, 'filterpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
