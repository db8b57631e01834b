"""The study summary's 95 % intervals over plates (``study.summary.ci95``): checked against what
they claim. Over repeated studies of 40 plates drawn from a known distribution, the interval of
a mean holds the true mean about 95 % of the time, and the paired interval of a ratio of means
(adaptive / grid on the same plates) holds the true ratio about as often (Monte Carlo, with a
binomial bound); fewer than two plates, or a missing value in a pair, give no interval."""
import numpy as np
from scipy import stats

from adaptive_cal.study.summary import ci95


def test_the_interval_of_a_mean_and_of_a_paired_ratio_cover_as_claimed():
    rng = np.random.default_rng(11)
    trials, mean_hits, ratio_hits = 300, 0, 0
    for t in range(trials):
        plate = rng.gamma(4.0, 20.0, 40)  # a plate's difficulty, shared by both strategies
        a = plate * 1.1 + rng.normal(0.0, 8.0, 40)  # true mean 88
        g = plate + rng.normal(0.0, 8.0, 40)  # true mean 80: the true ratio is 1.1
        lo, hi = ci95(a, draws=500, seed=t)
        mean_hits += lo <= 88.0 <= hi
        lo, hi = ci95(a, g, stat=lambda x, y: x.mean() / y.mean(), draws=500, seed=t)
        ratio_hits += lo <= 1.1 <= hi
    # a percentile bootstrap at 40 plates runs at 93-95 %: the count must lie inside the
    # binomial's two-sided 99.9 % range for a rate of 0.92 at the low end, 0.97 at the high
    low, high = stats.binom.ppf(0.0005, trials, 0.92), stats.binom.ppf(0.9995, trials, 0.97)
    assert low <= mean_hits <= high, (mean_hits, low, high)
    assert low <= ratio_hits <= high, (ratio_hits, low, high)


def test_pairing_no_plates_and_missing_values():
    x = np.array([60.0, 80.0, 75.0, 90.0])
    assert ci95(x, x, stat=lambda a, b: a.mean() / b.mean()) == [1.0, 1.0]  # same plates
    assert ci95([70.0]) is None and ci95([]) is None
    assert ci95([70.0, np.nan, 80.0]) == ci95([70.0, 80.0])  # left out, as the mean leaves it
    assert ci95([70.0, np.nan, 80.0], [1.0, 2.0, 3.0], stat=lambda a, b: a.mean()) is None
    lo, hi = ci95(x)
    assert x.min() <= lo <= x.mean() <= hi <= x.max()
    assert ci95(x) == ci95(x)  # a fixed seed: the summary is reproducible
