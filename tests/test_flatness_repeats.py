"""The touched points' flatness interval predicts a repeat measurement at the same touches: its
noise is as uncertain as the learned sd, which rests on nu = n - (what the map spent) degrees of
freedom. Checked where the answer is known exactly: a plane seen by n touches, where a
repeat's least-squares flatness over the learned sd is a pivot, so a calibrated interval holds
a fresh repeat 95 % of the time; Monte Carlo over fixed seeds."""
import numpy as np
import pytest

from adaptive_cal.analysis.flatness_answer import noise_dof, repeat_noise_mm
from adaptive_cal.gaussian import belief as bl


def _ls_flatness(X, z):
    """Least-squares flatness (range of residuals) of each row of z (S, n): numpy lstsq."""
    coef = np.linalg.lstsq(X, np.atleast_2d(z).T, rcond=None)[0]
    return np.ptp(np.atleast_2d(z) - (X @ coef).T, axis=1)


def _coverage(fixed: bool, runs: int = 400, n: int = 12, sigma: float = 0.005):
    rng = np.random.default_rng(11)
    xy = rng.uniform(-200, 200, (n, 2))
    X = np.c_[np.ones(n), xy / 200.0]  # a plane: the map spends 3 of the n readings
    inside = 0
    for _ in range(runs):
        z = sigma * rng.standard_normal(n)
        coef = np.linalg.lstsq(X, z, rcond=None)[0]
        s = np.sqrt(np.sum((z - X @ coef) ** 2) / (n - 3))  # the learned sd, on n - 3 dof
        belief = bl.Belief(coef, s**2 * np.linalg.inv(X.T @ X))
        e = (s * rng.standard_normal((400, n)) if fixed
             else repeat_noise_mm(X, belief, s, rng, 400))
        lo, hi = np.percentile(_ls_flatness(X, e), [2.5, 97.5])
        repeat = _ls_flatness(X, sigma * rng.standard_normal(n))[0]
        inside += lo <= repeat <= hi
    return inside / runs


def test_the_noise_rests_on_the_readings_the_plane_left():
    n = 12
    X = np.c_[np.ones(n), np.linspace(-1, 1, n), np.cos(np.arange(n))]
    cov = 0.004**2 * np.linalg.inv(X.T @ X)
    hat = X @ cov @ X.T / 0.004**2  # the dense hat matrix: its trace is what the fit spent
    assert noise_dof(X, bl.Belief(np.zeros(3), cov), 0.004) == pytest.approx(n - np.trace(hat))
    assert noise_dof(X, bl.Belief(np.zeros(3), cov), 0.004) == pytest.approx(n - 3)


def test_a_repeat_lies_in_the_interval_95_percent_of_the_time():
    """400 planes seen by 12 touches (9 degrees of freedom), 400 draws each: the interval with
    the noise's own uncertainty holds the fresh repeat 0.95 +- 0.011 (1 sd of 400 Bernoulli
    draws; allowed 3 sd); with the learned sd taken as exact it holds fewer."""
    calibrated, plug_in = _coverage(fixed=False), _coverage(fixed=True)
    print(f"coverage {calibrated:.3f} with the sd's uncertainty, {plug_in:.3f} without")
    assert 0.917 <= calibrated <= 0.983
    assert plug_in < calibrated - 0.02


def _t3_coverage(heavy_aware: bool, runs: int = 300, n: int = 60, sigma: float = 0.005):
    """As ``_coverage``, the readings' noise Student-t of 3 dof with sd ``sigma``."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(-200, 200, (n, 2))
    X = np.c_[np.ones(n), xy / 200.0]
    t3 = lambda size: sigma * rng.standard_t(3, size) / np.sqrt(3.0)  # noqa: E731
    inside = 0
    for _ in range(runs):
        z = t3(n)
        coef = np.linalg.lstsq(X, z, rcond=None)[0]
        s = np.sqrt(np.sum((z - X @ coef) ** 2) / (n - 3))
        belief = bl.Belief(coef, s**2 * np.linalg.inv(X.T @ X))
        e = repeat_noise_mm(X, belief, s, rng, 400, heights=z if heavy_aware else None)
        lo, hi = np.percentile(_ls_flatness(X, e), [2.5, 97.5])
        inside += lo <= _ls_flatness(X, t3(n))[0] <= hi
    return inside / runs


def test_heavy_tailed_readings_get_heavy_tailed_repeats_and_gaussian_ones_the_same_draws():
    """Student-t (3 dof) readings: a Gaussian repeat under-states a max - min figure (an outside
    audit: 0.71 of fresh repeats inside, every miss above). Where the readings' residuals are
    judged heavy-tailed (analysis.tails) the repeats draw Student-t noise: on 300 planes of 60
    touches the interval holds more fresh repeats (measured 0.48 -> 0.78; 0.95 where the tails
    were found); Gaussian readings keep the very same draws. The tail test itself: on 300
    Gaussian samples of 48 it fires about 1.5 % of the time (allowed 4 %: 3 sd of 300 draws),
    on t3 samples of 72 about 80 % (at least 65 %)."""
    from adaptive_cal.analysis.tails import tail_dof

    before, after = _t3_coverage(False), _t3_coverage(True)
    print(f"t3 readings: {before:.3f} of fresh repeats inside without, {after:.3f} with")
    assert after >= before + 0.15 and after >= 0.7
    rng = np.random.default_rng(3)
    assert np.mean([np.isfinite(tail_dof(rng.standard_normal(48))) for _ in range(300)]) <= 0.04
    assert np.mean([np.isfinite(tail_dof(rng.standard_t(3, 72))) for _ in range(300)]) >= 0.65
    n = 40
    X = np.c_[np.ones(n), np.linspace(-1, 1, n)]
    z = 0.005 * np.random.default_rng(8).standard_normal(n)
    coef = np.linalg.lstsq(X, z, rcond=None)[0]
    belief = bl.Belief(coef, 0.005**2 * np.linalg.inv(X.T @ X))
    plain = repeat_noise_mm(X, belief, 0.005, np.random.default_rng(1), 50)
    judged = repeat_noise_mm(X, belief, 0.005, np.random.default_rng(1), 50, heights=z)
    np.testing.assert_array_equal(plain, judged)


def test_a_bare_recordings_intervals_do_not_move_with_a_constant_added_to_every_height():
    """Every figure is blind to a constant; the fit behind the intervals was not (an outside
    audit: heights 990 mm up learned 4.65 um of noise for 3.66 um, the interval ends moved
    1 um). The heights are now taken about their mean."""
    from adaptive_cal.analysis.flatness_intervals import repeat_samples

    rng = np.random.default_rng(3)
    x, y = (g.ravel() for g in np.meshgrid(np.linspace(-200, 200, 8), np.linspace(-160, 160, 5)))
    z = 0.012 * x - 0.004 * y + 0.15 * (y / 160) ** 2 + rng.normal(0, 0.004, x.size)
    a = repeat_samples(x, y, z, np.random.default_rng(0), 60)
    b = repeat_samples(x, y, z + 990.0, np.random.default_rng(0), 60)
    # the fit stops at its own tolerance: 1 nm is far below the 1 um the offset used to move
    assert abs(a[1]["noise_std_mm"] - b[1]["noise_std_mm"]) < 1e-7
    for k in a[0]:
        assert np.allclose(a[0][k], b[0][k], atol=1e-6, rtol=0), k


def test_the_touched_points_tilt_sd_is_the_spread_of_repeats_monte_carlo():
    """tilt_with_std's 1 sd (a, b, rx, ry) against the spread of the least-squares plane over
    4,000 noise draws at the same touches: the sd of an sd estimate from n draws is about
    1 / sqrt(2 n) = 1.1 %, so within 5 %."""
    from adaptive_cal.analysis import flatness as fl
    from adaptive_cal.analysis.flatness_intervals import tilt_with_std

    x, y = (g.ravel() for g in np.meshgrid(np.linspace(-200, 200, 10), np.linspace(-165, 165, 4)))
    z = 0.012 * x - 0.004 * y + 0.15 * (y / 165) ** 2
    t = tilt_with_std(x, y, z, 0.005)
    rng = np.random.default_rng(1)
    draws = [fl.plane_tilt(x, y, z + rng.normal(0, 0.005, x.size)) for _ in range(4000)]
    for key in ("a", "b", "rx_deg", "ry_deg"):
        spread = np.std([d[key] for d in draws])
        sd = t[key.replace("_deg", "") + ("_std_deg" if key.endswith("_deg") else "_std")]
        assert abs(sd / spread - 1) < 0.05, (key, sd, spread)


def test_a_bare_recordings_json_tilt_says_what_its_plane_is(capsys):
    """flatness --json on a recording: the touched points' tilt says what a, b, c and the angles
    are, with units (result.json's tilt does; an outside audit found this one without)."""
    import json

    from adaptive_cal.cli import main

    from pathlib import Path

    rec = (Path(__file__).resolve().parents[1] / "adaptive_cal" / "data" / "cheng2025"
           / "round0_initial.csv")
    assert main(["flatness", str(rec), "--json", "--samples", "8"]) == 0
    tilt = json.loads(capsys.readouterr().out)["tilt"]
    assert "touched points" in tilt["plane_is"] and "(mm/mm)" in tilt["plane_is"]
    assert {"a", "b", "c", "rx_deg", "ry_deg", "a_std", "rx_std_deg"} <= set(tilt)
