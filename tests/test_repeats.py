"""Repeat touches tell the probe's noise from the plate (planning.repeats): the pooled variance
against a direct sum, the repeats check's false-alarm rate and power by Monte Carlo against the
F distribution it is built on, readings at one place pooled for the learned noise (the same
posterior as one by one; the noise no longer pulled toward the probe's by the repeats), and
the loop on a simulated cell that owes repeats before its bound may stop it."""
import numpy as np
import pytest
import yaml

import adaptive_cal
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian.checks import repeats
from adaptive_cal.planning.repeats import SPAN_TEST

adaptive_cal.use_float64()


def test_pooled_variance_of_repeats_is_the_direct_sum():
    """Oracle: for every place, the squared deviations from its own mean, summed and divided by
    the readings beyond the first; readings judged outliers (w < 1/2) left out."""
    rng = np.random.default_rng(0)
    places = rng.uniform(-200, 200, (9, 2))
    which = rng.integers(0, 9, 40)
    xy = places[which] + rng.uniform(-1e-4, 1e-4, (40, 2))  # the same place, to round-off
    y = rng.normal(0, 1, 40)
    w = np.where(rng.uniform(size=40) < 0.1, 0.2, 1.0)
    dof, var = repeats(xy, y, w)
    ss, n = 0.0, 0
    for k in range(9):
        sel = (which == k) & (w >= 0.5)
        if sel.sum() > 1:
            ss += float(np.sum((y[sel] - y[sel].mean()) ** 2))
            n += int(sel.sum()) - 1
    assert dof == n and var == pytest.approx(ss / n, rel=1e-12)
    assert repeats(places, y[:9])[0] == 0  # no place read twice


def _plan():
    from adaptive_cal.cell.build import survey_plan
    from helpers import sim_cell

    return survey_plan(sim_cell(probe={"noise_range_mm": [0.003, 0.008]}), grow=False)


@pytest.mark.parametrize("structure_mm, lo, hi", [(0.0, 0.0, 0.10),   # the probe alone
                                                    (0.0075, 0.70, 1.0)])  # 1.8 x the probe
def test_the_repeats_check_fires_as_its_f_test_says(structure_mm, lo, hi):
    """60 places on plates drawn from the model, 4 of them read 4 times (12 repeat readings),
    probe noise 5 um; each place also carries white structure of ``structure_mm`` (the same at
    every reading there: finer than the touches' spacing). The check is given the noise the fit
    would learn, sqrt(probe^2 + structure^2). F(60, 12) at SPAN_TEST's level says: 5 % fail on the
    probe alone, about 84 % at a learned noise 1.8 x the probe's (60 runs: the bounds hold with
    binomial probability above 99 %). Where it fails, the unresolved variance is measured beyond
    the repeats' variance: about the structure's."""
    from adaptive_cal.planning.adequacy import assess

    plan = _plan()
    probe = 0.005
    hyper = plan.model.hyper0._replace(noise_std_mm=float(np.hypot(probe, structure_mm)))
    prior = plan.model.belief(hyper)
    rng = np.random.default_rng(11)
    (x0, x1), (y0, y1) = plan.bounds_mm
    fails, unresolved = 0, []
    for _ in range(60):
        a = bl.sample(prior, rng, 1)[0]
        xy = np.stack([rng.uniform(x0, x1, 60), rng.uniform(y0, y1, 60)], 1)
        xy = np.vstack([xy, np.repeat(xy[:4], 3, axis=0)])
        extra = structure_mm * rng.standard_normal(60)
        rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
        y = rows @ a + np.concatenate([extra, np.repeat(extra[:4], 3)]) \
            + probe * rng.standard_normal(len(xy))
        v = assess(plan.model.surface, plan.plate_mm, rows, y, prior, hyper,
                   plan.noise_range_mm, plan.adequacy_regions, repeats=SPAN_TEST)
        assert v.repeat_dof == 12
        if not v.checks["repeats"]["passed"]:
            fails += 1
            unresolved.append(v.unresolved_rms_mm)
    assert lo <= fails / 60 <= hi, fails
    if structure_mm:
        assert 0.5 * structure_mm < np.median(unresolved) < 1.5 * structure_mm


def test_pooled_readings_give_the_same_posterior():
    """``prior.pooled``: readings at one place become their weighted mean with the summed
    weight; oracle: the posterior of every reading, one by one, at its own noise sigma^2 / w."""
    from adaptive_cal.gaussian.prior import pooled

    plan = _plan()
    prior = plan.model.belief(plan.model.hyper0)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-150, 150, (20, 2))
    xy = np.vstack([xy, xy[[3, 3, 7, 12]], xy[:1]])
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    y = rng.normal(0, 0.01, len(xy))
    w = rng.uniform(0.2, 1.0, len(xy))
    r = 0.005**2
    prow, py, pw = pooled(rows, y, w)
    assert len(py) == 20 and np.array_equal(prow, rows[:20])  # places in the order first read
    assert pw[3] == pytest.approx(w[3] + w[20] + w[21]) and pw[5] == w[5]
    assert py[3] == pytest.approx(np.average(y[[3, 20, 21]], weights=w[[3, 20, 21]]))
    want = prior
    for i in range(len(y)):
        want = bl.fuse(want, rows[i], y[i], r / w[i])[0]
    got = bl.condition(prior, prow, py, r / pw)
    scale = np.sqrt(np.diag(want.cov))
    np.testing.assert_allclose(got.mean / scale, want.mean / scale, atol=1e-8)
    np.testing.assert_allclose(got.cov / np.outer(scale, scale), want.cov / np.outer(scale, scale),
                               atol=1e-8)
    untouched = pooled(rows[:20], y[:20], w[:20])
    assert untouched[0] is not None and np.array_equal(untouched[1], y[:20])


def test_the_learned_noise_is_fitted_to_places_not_to_their_repeats():
    """A plate with white structure of 6 um at each of 40 places (finer than the touches'
    spacing), a 5 um probe, 4 places read 4 times. The nugget is probe and structure, about 7.8
    um; the 12 repeats scatter by the probe alone. Fitted to every reading, the noise is pulled
    toward the probe's (about 7.3 um, by the counts); fitted to the places (``learned_belief``)
    it is not: higher on each of 6 plates, and within 25 % of 7.8 um on average."""
    from adaptive_cal.gaussian.prior import hyper_posterior, learned_belief

    plan = _plan()
    prior = plan.model.belief(plan.model.hyper0)
    rng = np.random.default_rng(8)
    (x0, x1), (y0, y1) = plan.bounds_mm
    per_place, per_reading = [], []
    for _ in range(6):
        a = bl.sample(prior, rng, 1)[0]
        xy = np.stack([rng.uniform(x0, x1, 40), rng.uniform(y0, y1, 40)], 1)
        which = np.concatenate([np.arange(40), np.repeat(np.arange(4), 3)])
        rows = plan.model.surface.basis(xy[which, 0], xy[which, 1])
        y = rows @ a + 0.006 * rng.standard_normal(40)[which] + 0.005 * rng.standard_normal(52)
        per_place.append(learned_belief(plan.model, rows, y)[1][0][0].noise_std_mm)
        per_reading.append(hyper_posterior(plan.model, rows, y, points=False)[0][0].noise_std_mm)
    assert all(p > q for p, q in zip(per_place, per_reading)), (per_place, per_reading)
    assert 0.75 * 0.0078 < np.mean(per_place) < 1.25 * 0.0078, per_place


def test_the_survey_pools_its_own_repeats_live_and_replayed_alike():
    """Repeats go to a position rebuilt from the first reading's basis row (``repeats.place``),
    about 1e-10 mm off it, and a recording keeps 4 decimals: either way they are one place
    (``checks.row_places``), as ``checks.repeats`` counts them, and the residual degrees of
    freedom count the place once (an outside audit: bit-equal rows only had left a live run's
    repeats unpooled, so its learned noise differed from its replay's)."""
    from adaptive_cal.gaussian.checks import row_places
    from adaptive_cal.planning import repeats as rp
    from adaptive_cal.planning import survey
    from adaptive_cal.planning.adequacy import positions_mm
    from adaptive_cal.planning.ask import target
    from adaptive_cal.planning.closure import residual_dof

    plan = _plan()
    state = survey.start(plan)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-150, 150, (8, 2))
    for x, y in xy:
        t = target(plan, state, float(x), float(y))
        state, _ = survey.tell(plan, state, t.x_mm, t.y_mm, t.z_mm,
                               t.expected_reading_mm + 0.005 * rng.standard_normal())
        for _ in range(2):
            t = target(plan, state, *rp.place(plan, state))
            assert (t.x_mm, t.y_mm) != (float(x), float(y))  # not bit-equal
            state, _ = survey.tell(plan, state, t.x_mm, t.y_mm, t.z_mm,
                                   t.expected_reading_mm + 0.005 * rng.standard_normal())
    pos = positions_mm(plan.model.surface, state.rows)
    assert row_places(state.rows)[1] == 8
    assert repeats(pos, state.heights_mm)[0] == len(state.heights_mm) - 8
    replayed = plan.model.surface.basis(np.round(pos[:, 0], 4), np.round(pos[:, 1], 4))
    assert np.array_equal(row_places(replayed)[0], row_places(state.rows)[0])
    cov = state.belief.cov
    assert residual_dof(state.rows, state.fused_weights, cov, 0.005**2) == pytest.approx(
        residual_dof(state.rows[::3], np.full(8, 3.0), cov, 0.005**2), rel=1e-9)


def test_without_suspicion_a_place_read_twice_asks_no_question():
    """The check is judged only where the learned noise is suspect (and 6 repeats are in): a
    run's natural repeats (a corner picked twice, the closure touch) are no test of the probe."""
    from adaptive_cal.planning.adequacy import assess

    plan = _plan()
    hyper = plan.model.hyper0._replace(noise_std_mm=0.005)
    prior = plan.model.belief(hyper)
    rng = np.random.default_rng(2)
    xy = rng.uniform(-150, 150, (30, 2))
    xy = np.vstack([xy, np.repeat(xy[:3], 3, axis=0)])
    rows = plan.model.surface.basis(xy[:, 0], xy[:, 1])
    y = 0.005 * rng.standard_normal(len(xy))
    off = assess(plan.model.surface, plan.plate_mm, rows, y, prior, hyper, plan.noise_range_mm)
    on = assess(plan.model.surface, plan.plate_mm, rows, y, prior, hyper, plan.noise_range_mm,
                repeats=SPAN_TEST)
    assert "repeats" not in off.checks and off.repeat_dof == 0
    assert "repeats" in on.checks and on.repeat_dof == 9


def _sim_cell(tmp_path, **edits):
    data = yaml.safe_load(open(adaptive_cal.__path__[0] + "/../configs/sim-cell.yaml"))
    data["probe"].pop("noise_std_mm")  # the span below says it
    for section, values in edits.items():
        data[section] = {**data.get(section, {}), **values}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_probe_at_its_spans_top_is_read_again_then_the_bound_stops(tmp_path):
    """A cell states a noise span of 3-5 um and its probe reads 6 um, above the span's top: the
    learned noise sits at the top, so before its bound stops the run it reads places
    again -- 12 repeat readings, at most 4 readings a place, no travel -- the repeats find the
    probe as noisy as learned (nothing hides in the noise), and the bound stops the run; the
    summary gives both noises."""
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.formats.recording import read_recording
    from adaptive_cal.run.session import run

    # (a span of 3-6 um, the probe at its very top, left the learned noise at 4.8 or 5.6 um as
    # the jax release moved the hyper-parameters' MAP between two local optima: the fit is
    # multimodal, and this test is about the repeats, not about that)
    cell = _sim_cell(tmp_path, probe={"noise_range_mm": [0.003, 0.005]},
                     simulation={"noise_std_mm": 0.006, "repeatability_mm": 0.0},
                     plan={"stop": {"mean_std_mm": 0.006, "max_touches": 120}})
    result = run(load_cell(cell), tmp_path / "run", progress=False)
    assert result["stopped_because"] == "mean_std_bound"
    rec = read_recording(tmp_path / "run" / "recording.csv")
    xy = np.round(np.c_[rec.x_mm, rec.y_mm], 4)
    _, counts = np.unique(xy, axis=0, return_counts=True)
    assert np.sum(counts - 1) >= 12 and counts.max() <= 5  # 4 a place, the closure's besides
    model = result["model"]
    assert model["checks"]["repeats"]["passed"] and model["repeats"]["dof"] >= 12
    assert 0.004 < model["repeats"]["std_mm"] < 0.008
    assert "learned noise" in model["summary"] and "repeat readings: the probe" in model["summary"]


def test_without_a_span_a_noise_well_above_the_first_guess_is_suspect_and_judged_strictly():
    """No span: the learned noise at GUESS_FACTOR x probe.noise_std_mm or more is suspect (the
    guess is wrong or plate structure hides in the noise), and the check then waits for all DOF
    repeats and judges at 1 %; what it lets pass (F - 1) s_r^2 is the unseen structure."""
    from types import SimpleNamespace

    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.planning import repeats as rp
    from adaptive_cal.planning.adequacy import assess
    from helpers import sim_cell

    plan = survey_plan(sim_cell(probe={"noise_std_mm": 0.004}), grow=False)
    assert plan.noise_range_mm is None and plan.model.hyper0.noise_std_mm == 0.004

    def state(sigma):
        return SimpleNamespace(prior=None, hyper_points=[1], fused=30,
                               hyper=plan.model.hyper0._replace(noise_std_mm=sigma))

    assert not rp.suspected(plan, state(0.0059)) and rp.judged(plan, state(0.0059)) is None
    assert rp.suspected(plan, state(0.0061)) and rp.judged(plan, state(0.0061)) == (0.01, 12)
    hyper = plan.model.hyper0._replace(noise_std_mm=0.006)
    prior = plan.model.belief(hyper)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-150, 150, (40, 2))
    for extra, judged in ((3, False), (4, True)):  # 9 repeat readings, then 12
        pts = np.vstack([xy, np.repeat(xy[:extra], 3, axis=0)])
        rows = plan.model.surface.basis(pts[:, 0], pts[:, 1])
        y = 0.006 * rng.standard_normal(len(pts))
        v = assess(plan.model.surface, plan.plate_mm, rows, y, prior, hyper, None,
                   plan.adequacy_regions, repeats=rp.NO_SPAN_TEST)
        assert ("repeats" in v.checks) is judged
        if judged:
            from scipy.stats import f

            bound = v.checks["repeats"]["bound"]
            assert bound == pytest.approx(f.isf(0.01, len(y) - 12, 12), rel=1e-12)  # places
            assert v.unseen_rms_mm == pytest.approx(np.sqrt((bound - 1) * v.repeat_std_mm**2),
                                                    rel=1e-12)
            assert "its repeats leave room for it" in v.summary() or not v.adequate
        else:
            assert v.unseen_rms_mm is None
