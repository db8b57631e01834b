"""Readings at one place in the learned noise's fit (``gaussian.places``, ``prior.learned_belief``):
pooled into their mean with the summed weight (oracle: the posterior of every reading one by
one), their scatter a floor under the nugget (oracle: the profiled chi-square likelihood, its
derivative by central differences), and what that does to the learned noise by Monte Carlo on
plates drawn from the model: structure finer than the spline is no longer pulled out of the
nugget by repeats, and a noisy probe's repeats still keep the nugget from falling below them."""
import numpy as np
import pytest

import adaptive_cal
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.places import floor_penalty, pooled

adaptive_cal.use_float64()


def _plan(span=(0.003, 0.008)):
    from adaptive_cal.cell.build import survey_plan
    from helpers import sim_cell

    return survey_plan(sim_cell(probe={"noise_range_mm": list(span)}), grow=False)


def test_pooled_readings_give_the_same_posterior_and_their_scatter():
    plan = _plan()
    prior = plan.model.belief(plan.model.hyper0)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-150, 150, (20, 2))
    xy = np.vstack([xy, xy[[3, 3, 7, 12]] + 1e-10, xy[:1]])  # repeats 1e-10 mm off, as sent
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    y = rng.normal(0, 0.01, len(xy))
    w = rng.uniform(0.6, 1.0, len(xy))
    w[21] = 1e-6  # a gross error weighted out: in the mean at no weight, not in the scatter
    r = 0.005**2
    prow, py, pw, floor = pooled(plan.model.surface, rows, y, w)
    assert len(py) == 20 and np.array_equal(prow, rows[:20])  # places in the order first read
    assert pw[3] == pytest.approx(w[3] + w[20] + w[21])
    assert py[3] == pytest.approx(np.average(y[[3, 20, 21]], weights=w[[3, 20, 21]]))
    ss = 0.0
    for idx in ([3, 20], [7, 22], [12, 23], [0, 24]):
        m = np.average(y[idx], weights=w[idx])
        ss += float(np.sum(w[idx] * (y[idx] - m) ** 2))
    assert floor[1] == 4 and floor[0] == pytest.approx(ss, rel=1e-12)
    want = prior
    for i in range(len(y)):
        want = bl.fuse(want, rows[i], y[i], r / w[i])[0]
    got = bl.condition(prior, prow, py, r / pw)
    sd = np.sqrt(np.diag(want.cov))
    np.testing.assert_allclose(got.mean / sd, want.mean / sd, atol=1e-7)
    np.testing.assert_allclose(got.cov / np.outer(sd, sd), want.cov / np.outer(sd, sd), atol=1e-7)
    assert pooled(plan.model.surface, rows[:20], y[:20], w[:20])[3] is None


def test_the_floor_is_the_profiled_scatter_likelihood():
    """-log L(p) = dof log p + ss / (2 p^2) maximised over p <= sigma: flat from sigma^2 = ss /
    dof up, rising below; its derivative in log sigma by central differences (step 1e-5: the
    truncation error 1e-10 relative, round-off 1e-11)."""
    ss, dof = 0.0004 * 7, 7
    nll = lambda p: dof * np.log(p) + ss / (2 * p**2)
    best = nll(np.sqrt(ss / dof))
    for sigma in (0.002, 0.005, 0.0075, 0.01, 0.03):
        p = min(sigma, np.sqrt(ss / dof))
        v, d = floor_penalty(np.log(sigma), ss, dof)
        assert v == pytest.approx(nll(p) - best, abs=1e-12)
        h = 1e-5
        fd = (floor_penalty(np.log(sigma) + h, ss, dof)[0]
              - floor_penalty(np.log(sigma) - h, ss, dof)[0]) / (2 * h)
        assert d == pytest.approx(fd, rel=1e-6, abs=1e-9)
    assert floor_penalty(np.log(0.0075), 0.0, 3) == (0.0, 0.0)


@pytest.mark.parametrize("structure_mm, probe_mm, extra, lo, hi", [
    (0.006, 0.005, (4, 3), 0.75, 1.25),   # structure: the nugget sqrt(s^2 + p^2) = 7.8 um
    (0.0, 0.015, (15, 2), 0.8, 1.2)])     # a noisy probe, the planner reading places again
def test_the_learned_noise_keeps_structure_and_its_probe_floor(structure_mm, probe_mm, extra,
                                                               lo, hi):
    """40 places on plates drawn from the model, some read again (``extra``: places, times);
    each place carries white structure of ``structure_mm`` (the same at every reading there).
    Learned noise (MAP, 6 plates): fitted to every reading as one (the old fit), to the places
    alone, and to the places with the repeats' floor (``learned_belief``). With structure the
    repeats pull the every-reading fit below the nugget, and the fit with the floor stays
    above it on every plate and near the nugget on average; on a noisy probe without structure
    the places alone read the noise low (the form takes part of it) and the floor lifts it to
    at least what the places alone say, on every plate, near the probe's on average."""
    from adaptive_cal.gaussian.prior import hyper_posterior, learned_belief

    plan = _plan((0.003, 0.02))
    prior = plan.model.belief(plan.model.hyper0)
    rng = np.random.default_rng(8)
    (x0, x1), (y0, y1) = plan.bounds_mm
    nugget = float(np.hypot(structure_mm, probe_mm))
    every, alone, floored = [], [], []
    for _ in range(6):
        a = bl.sample(prior, rng, 1)[0]
        xy = np.stack([rng.uniform(x0, x1, 40), rng.uniform(y0, y1, 40)], 1)
        which = np.concatenate([np.arange(40), np.repeat(np.arange(extra[0]), extra[1])])
        rows = plan.model.surface.basis(xy[which, 0], xy[which, 1])
        y = rows @ a + structure_mm * rng.standard_normal(40)[which] \
            + probe_mm * rng.standard_normal(len(which))
        learned = learned_belief(plan.model, rows, y)[1][0][0]  # the heaviest kernel's MAP
        fit = lambda r, v, w=None: hyper_posterior(plan.model, r, v, points=False, weights=w,
                                                   kernel=learned.kernel)[0][0].noise_std_mm
        every.append(fit(rows, y))
        prow, py, pw, _ = pooled(plan.model.surface, rows, y)
        alone.append(fit(prow, py, pw))
        floored.append(learned.noise_std_mm)
    every, alone, floored = map(np.array, (every, alone, floored))
    assert np.all(floored >= alone - 1e-6), (floored, alone)
    assert lo * nugget < floored.mean() < hi * nugget, (floored, nugget)
    if structure_mm:
        assert np.all(floored > every), (floored, every)


def test_the_survey_pools_its_own_repeats_live_and_replayed_alike():
    """Repeats go to a position rebuilt from the first reading's basis row (``repeats.place``),
    about 1e-10 mm off it, and a recording keeps 4 decimals: either way they are one place
    (``places.places``), as ``checks.repeats`` counts them (an outside audit: with bit-equal
    rows a live run's repeats were not pooled, and its replay learned another noise)."""
    from adaptive_cal.gaussian.checks import repeats
    from adaptive_cal.gaussian.places import places, positions_mm
    from adaptive_cal.planning import repeats as rp
    from adaptive_cal.planning import survey
    from adaptive_cal.planning.ask import target

    plan = _plan()
    state = survey.start(plan)
    rng = np.random.default_rng(1)
    for x, y in rng.uniform(-150, 150, (8, 2)):
        t = target(plan, state, float(x), float(y))
        state, _ = survey.tell(plan, state, t.x_mm, t.y_mm, t.z_mm,
                               t.expected_reading_mm + 0.005 * rng.standard_normal())
        for _ in range(2):
            t = target(plan, state, *rp.place(plan, state))
            assert (t.x_mm, t.y_mm) != (float(x), float(y))  # not bit-equal
            state, _ = survey.tell(plan, state, t.x_mm, t.y_mm, t.z_mm,
                                   t.expected_reading_mm + 0.005 * rng.standard_normal())
    pos = positions_mm(plan.model.surface, state.rows)
    assert len(places(pos)[1]) == 8
    assert repeats(pos, state.heights_mm)[0] == len(state.heights_mm) - 8
    replayed = plan.model.surface.basis(np.round(pos[:, 0], 4), np.round(pos[:, 1], 4))
    assert np.array_equal(places(positions_mm(plan.model.surface, replayed))[0],
                          places(pos)[0])
    s = plan.model.surface
    assert pooled(s, state.rows, state.heights_mm)[3][1] == 16
    assert pooled(s, replayed, state.heights_mm)[3][1] == 16


def test_one_definition_of_a_place_for_the_repeats_check_and_the_fit():
    """``places`` labels in the order first read, with the readings per place; the repeats check
    (``checks.repeats``) and the fit's pooling (``pooled``) count the same places and the same
    degrees of freedom, whether the readings come from live rows or 4-decimal positions."""
    from adaptive_cal.gaussian.checks import repeats
    from adaptive_cal.gaussian.places import places, positions_mm

    label, counts = places([[5.0, 1.0], [-3.0, 2.0], [5.0 + 4e-5, 1.0], [-3.0, 2.0 - 1e-10],
                            [100.0, 0.0], [5.0, 1.0]])
    assert label.tolist() == [0, 1, 0, 1, 2, 0] and counts.tolist() == [3, 2, 1]
    assert places(np.zeros((0, 2)))[1].size == 0 and places([[1.0, 2.0]])[1].tolist() == [1]
    # a rounding grid's boundary (0.005 mm) between a live position and its 4-decimal copy
    assert places([[12.345, 0.0], [12.345 + 3e-5, 0.0], [12.3449, 0.0]])[1].tolist() == [3]
    assert places([[0.0, 0.0], [0.02, 0.0], [0.0, 0.02]])[1].tolist() == [1, 1, 1]
    s = _plan().model.surface
    rng = np.random.default_rng(7)
    xy = rng.uniform(-200, 180, (30, 2))
    xy = np.vstack([xy, xy[[2, 2, 9, 17, 17, 17]] + rng.uniform(-3e-5, 3e-5, (6, 2))])
    y = rng.normal(0, 0.005, len(xy))
    for rows in (s.basis(xy[:, 0], xy[:, 1]), s.basis(*np.round(xy, 4).T)):
        assert np.allclose(positions_mm(s, rows), xy, atol=1e-4)
        _, _, _, (ss, dof) = pooled(s, rows, y)
        d, var = repeats(positions_mm(s, rows), y)
        assert dof == d == 6 and ss == pytest.approx(var * d, rel=1e-12)
