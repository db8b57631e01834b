"""The package root is the notebook user's API: its docstring's ask/tell loop runs, every name
it lists resolves and is documented, and importing the package loads nothing heavy."""
import doctest
import subprocess
import sys
from pathlib import Path

import pytest

import adaptive_cal

ROOT = Path(__file__).resolve().parents[1]


def test_package_docstring_loop_runs(monkeypatch):
    monkeypatch.chdir(ROOT)  # the example reads configs/sim-cell.yaml
    result = doctest.testmod(adaptive_cal, optionflags=doctest.ELLIPSIS, verbose=False)
    assert result.attempted >= 8 and result.failed == 0


@pytest.mark.parametrize("name", sorted(adaptive_cal.__all__))
def test_public_name_resolves_with_a_docstring(name):
    obj = getattr(adaptive_cal, name)
    assert (obj.__doc__ or "").strip(), f"adaptive_cal.{name} has no docstring"


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        adaptive_cal.no_such_name  # noqa: B018


def test_import_loads_nothing_heavy():
    code = ("import sys, adaptive_cal; heavy = [m for m in ('jax', 'numpy', 'scipy', 'matplotlib', "
            "'pydantic', 'filterpy') if m in sys.modules]; print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_start_survey_and_flatness_agree_with_the_layers_below():
    from adaptive_cal.analysis.flatness_intervals import recording_flatness
    import numpy as np

    cell = adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml")
    survey = adaptive_cal.start_survey(cell)
    plan = adaptive_cal.survey_plan(cell)
    assert survey.plan.stop == plan.stop and survey.touches == 0
    path = ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"
    expected = recording_flatness(path, np.random.default_rng(3), 50)[0]
    assert adaptive_cal.flatness(path, samples=50, seed=3) == expected


def test_survey_ask_and_skip_refuse_what_cannot_be_meant():
    """ask(0) used to mean the plan's batch and ask(-1) gave an empty list; skip() counted a
    touch at x = 1e6 mm. Now a ValueError naming n, and InvalidReading naming the position
    with nothing counted."""
    import numpy as np

    adaptive_cal.use_float64()
    survey = adaptive_cal.start_survey(adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml"))
    for n in (0, -1, 2.5, "3", True):
        with pytest.raises(ValueError, match=f"n = {n!r}: ask for at least 1 touch"):
            survey.ask(n)
    assert len(survey.ask(np.int64(2))) == 2
    for xy, words in (((1e6, 0.0), r"x_mm = 1e\+06"), ((float("nan"), 0.0), "x_mm = nan"),
                      ((-15.0, 85.0), "keep-out")):
        with pytest.raises(adaptive_cal.InvalidReading, match=words):
            survey.skip(*xy)
    assert survey.touches == 0 and len(survey.history) == 1
    survey.skip(0.0, 0.0)
    assert survey.touches == 1


def test_flatness_refuses_samples_and_seed_it_cannot_use():
    """samples = 0 was an IndexError, -5 numpy's 'negative dimensions are not allowed'."""
    path = ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"
    for kw, words in (({"samples": 0}, "samples = 0"), ({"samples": 1}, "samples = 1"),
                      ({"samples": 2.5}, "samples = 2.5"), ({"seed": -1}, "seed = -1")):
        with pytest.raises(ValueError, match=words):
            adaptive_cal.flatness(path, **kw)
    # a Recording read already gives the same figures as its path
    rec = adaptive_cal.read_recording(path)
    assert adaptive_cal.flatness(rec, samples=20, seed=1) == \
        adaptive_cal.flatness(path, samples=20, seed=1)


def test_explain_takes_paths_as_well_as_recordings_and_cells(tmp_path):
    """A notebook's explain("round0.csv", "cell.yaml") was "'str' object has no attribute
    'path'"; explain([], cell) numpy's "need at least one array to concatenate"."""
    adaptive_cal.use_float64()
    path = ROOT / "adaptive_cal" / "data" / "cheng2025" / "round0_initial.csv"
    cell_file = ROOT / "configs" / "cheng2025-cell.yaml"
    cell = adaptive_cal.load_cell(cell_file)
    want = adaptive_cal.explain([adaptive_cal.read_recording(path)], cell).findings
    for recs, c in ((str(path), cell), (path, str(cell_file)), ([path], cell_file)):
        got = adaptive_cal.explain(recs, c).findings
        assert (got["verdict"], got["verdict_probability"]) == \
            (want["verdict"], want["verdict_probability"])
    with pytest.raises(ValueError, match="at least one recording"):
        adaptive_cal.explain([], cell)
    with pytest.raises(ValueError, match="nope.csv: no such file"):
        adaptive_cal.explain(tmp_path / "nope.csv", cell)
    # a seed that is not one was accepted on one round and numpy's SeedSequence error on two;
    # a keyword explain does not take named an internal function
    with pytest.raises(ValueError, match=r"rng = 'x': a numpy Generator or a seed"):
        adaptive_cal.explain(path, cell, rng="x")
    with pytest.raises(TypeError, match=r"explain\(\) got an unexpected keyword argument 'seed'"):
        adaptive_cal.explain(path, cell, seed=3)


def test_survey_grid_ask_from_and_tell_refuse_what_cannot_be_meant_and_grid_bands_match_status():
    """grid(-5) / grid(2.5) / ask(from_xy='ab') gave numpy's errors, tell(..., True) was a 1 mm
    reading; grid's std left out the unresolved structure status() counts. Now clear errors
    naming the value, and the grid's RMS std is status()'s on a fine grid."""
    import numpy as np

    adaptive_cal.use_float64()
    survey = adaptive_cal.start_survey(adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml"))
    for n in (-5, 2.5, 1, True):
        with pytest.raises(ValueError, match=f"n = {n!r}: a grid needs"):
            survey.grid(n)
    for bad in ("ab", (1.0,), (float("nan"), 0.0), (1e6, 1e6)):  # 1 km away: an audit
        with pytest.raises(ValueError, match="from_xy = "):
            survey.ask(1, from_xy=bad)
    t = survey.ask(1, from_xy=(0, 0))[0]
    with pytest.raises(TypeError, match="reading_mm = True is not a number"):
        survey.tell(t.x_mm, t.y_mm, t.z_mm, True)
    assert survey.touches == 0
    # unresolved structure in the state: the grid's bands carry it, as status() does
    from dataclasses import replace

    from adaptive_cal.planning import survey as sv

    class Found:  # 10 um RMS of structure finer than the spline, everywhere
        def unresolved_var_mm2(self, x, y):
            return np.full(np.shape(x), 1e-4)

    survey.state = replace(survey.state, adequacy=Found())
    _, _, _, std = survey.grid(11)
    _, _, _, bare = sv.grid(survey.plan, survey.state.belief, 11)
    assert np.allclose(std ** 2 - bare ** 2, 1e-4, rtol=1e-9, atol=1e-12)


def test_a_survey_in_float32_is_refused_before_the_first_touch():
    """The first refit (some touches in) needed float64: a notebook that forgot use_float64()
    was stopped after 8 robot touches, the 8th reading not fused. Now before any ask."""
    import jax

    cell = adaptive_cal.load_cell(ROOT / "configs" / "sim-cell.yaml")
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(RuntimeError, match=r"needs float64: call adaptive_cal.use_float64"):
            adaptive_cal.start_survey(cell)
    finally:
        jax.config.update("jax_enable_x64", True)


def test_a_path_or_dict_where_a_cell_is_meant_is_read_and_anything_else_named(tmp_path):
    import yaml

    path = ROOT / "configs" / "sim-cell.yaml"
    for given in (path, str(path), yaml.safe_load(path.read_text())):
        assert adaptive_cal.start_survey(given).plan.coefficients > 0
        adaptive_cal.open_cell(given).close()
    for call in (adaptive_cal.start_survey, adaptive_cal.open_cell):
        with pytest.raises(TypeError, match=r"cell = 42: give a Cell"):
            call(42)
    out = tmp_path / "run"
    with pytest.raises(TypeError, match=r"cell = None: give a Cell"):
        adaptive_cal.run_session(None, out)
    assert not out.exists()  # refused before the folder (and its lock) was made
    with pytest.raises(TypeError, match=r"plan = .*give a SurveyPlan"):
        adaptive_cal.Survey(adaptive_cal.load_cell(path))


def test_a_bound_typed_in_mm_meant_as_um_is_warned_about_by_the_api_too():
    import yaml

    data = yaml.safe_load((ROOT / "configs" / "sim-cell.yaml").read_text())
    data["plan"]["stop"]["mean_std_mm"] = 4
    with pytest.warns(UserWarning, match=r"plan.stop.mean_std_mm: 4 mm .* um given as mm"):
        adaptive_cal.start_survey(data)


def test_flatness_functions_name_what_they_cannot_use():
    """Notebook 02's functions gave scipy's 'A_ub must not contain nan', numpy's 'zero-size
    array', or a silent level plane from no points."""
    import numpy as np

    from adaptive_cal.analysis import flatness as fl

    x, y = [0.0, 100.0, 0.0, 100.0], [0.0, 0.0, 100.0, 100.0]
    cases = [((x, y, [0, np.nan, 0, 0]), r"z_mm\[1\] = nan: every value must be a finite"),
             (([], [], []), r"0 point\(s\): a plane, and so a flatness, needs at least 3"),
             ((np.ones((2, 2)), y, x), r"x_mm: one value per point .* shape \(2, 2\)"),
             ((x, y, "abc"), r"z_mm: 'abc' is not an array of numbers"),
             ((x, y[:3], x), r"same number of points")]
    for args, match in cases:
        for f in (fl.figures, fl.plane_tilt, fl.minimum_zone_mm, fl.least_squares_plane):
            with pytest.raises(ValueError, match=match):
                f(*args)
    for a, b in ((np.nan, 0.0), ("0.01", 0.0), (0.0, np.inf)):
        with pytest.raises(ValueError, match=r"a slope must be a finite number"):
            fl.tilt_correction_deg(a, b)


def test_the_belief_refuses_to_fuse_what_would_turn_it_to_nan():
    import numpy as np

    from adaptive_cal.gaussian import belief as bl

    b = bl.Belief(np.zeros(3), np.eye(3))
    row = np.array([1.0, 0.5, 0.25])
    for args, match in (((row, np.nan, 1e-6), r"reading = nan"),
                        ((row, 0.0, -1.0), r"noise_var = -1.0: a variance must be positive"),
                        ((np.ones(99), 0.0, 1e-6), r"row: 3 finite numbers .* shape \(99,\)")):
        with pytest.raises(ValueError, match=match):
            bl.fuse(b, *args)
    with pytest.raises(ValueError, match=r"must be finite"):
        bl.condition(b, row[None, :], np.array([np.nan]), 1e-6)
    with pytest.raises(ValueError, match=r"rows \(1, 99\) and readings"):
        bl.condition(b, np.ones((1, 99)), np.zeros(1), 1e-6)
    fused, _ = bl.fuse(b, row, 0.1, 1e-6)  # and a good reading still fuses
    assert np.all(np.isfinite(fused.mean))


def test_stop_reason_says_no_admissible_point_where_ask_has_nothing_and_ask_is_not_redone(
        monkeypatch):
    """Heights told in place of readings put the plate millimetres off the stroke: ask() then
    offers nothing. The documented loop ``while not survey.stop_reason(): survey.ask()[0]`` had
    raised IndexError there (an outside audit, 2026-11-29); stop_reason now ends it as the run's
    loop does. The ask() after stop_reason() reuses its answer (same state, same question).
    A height past the stroke is told as the probe would read it, at the stroke's end (tell
    refuses the height itself; under one JAX release the planner's path reached one)."""
    import numpy as np

    from adaptive_cal.planning import shell

    adaptive_cal.use_float64()
    survey = adaptive_cal.start_survey(ROOT / "configs" / "sim-cell.yaml")
    calls = []
    real = shell.ask
    monkeypatch.setattr(shell, "ask", lambda *a, **k: calls.append(1) or real(*a, **k))
    assert survey.stop_reason() is None and len(calls) == 1
    first = survey.ask()
    assert len(calls) == 1 and first and survey.ask() == first and len(calls) == 1
    survey.ask(1)  # another question: asked
    assert len(calls) == 2
    rng = np.random.default_rng(1)
    reasons = []
    for _ in range(60):
        reasons.append(survey.stop_reason())
        if reasons[-1] is not None:
            break
        t = survey.ask()[0]  # the documented loop: never an IndexError
        height = 0.012 * t.x_mm - 0.006 * t.y_mm + 1.0 + rng.normal(0, 0.005)
        end = abs(rng.normal(0, 0.002))  # past the stroke: read at its end, noisily
        survey.tell(t.x_mm, t.y_mm, t.z_mm, min(max(height, 0.5 + end), 9.5 - end))
    assert reasons[-1] == shell.NO_ADMISSIBLE_POINT and survey.ask() == []


def test_start_survey_takes_an_earlier_runs_folder_as_its_prior_and_refuses_odd_types(tmp_path):
    """An outside audit (2026-12-01): start_survey(prior='runs/x') and hyper=dict raised
    AttributeError deep inside, and no public call read an earlier run's belief."""
    import numpy as np

    import adaptive_cal
    from adaptive_cal.cli import main
    from adaptive_cal.run.recheck import load_prior

    adaptive_cal.use_float64()
    SIM = ROOT / "configs" / "sim-cell.yaml"
    out = tmp_path / "run"
    assert main(["run", "--robot", str(SIM), "--out", str(out), "--no-progress"]) == 0
    survey = adaptive_cal.start_survey(SIM, prior=out, correction="none")
    belief, hyper = load_prior(out, adaptive_cal.load_cell(SIM), "none")[:2]
    np.testing.assert_array_equal(survey.state.belief.mean, belief.mean)
    fresh = adaptive_cal.start_survey(SIM)
    assert survey.status().mean_std_mm < 0.1 * fresh.status().mean_std_mm
    with pytest.raises(TypeError, match="leave it out with prior = a run folder"):
        adaptive_cal.start_survey(SIM, prior=str(out), hyper=hyper)
    with pytest.raises(FileNotFoundError, match="no belief.npz there"):
        adaptive_cal.start_survey(SIM, prior=tmp_path)
    with pytest.raises(TypeError, match="give a Belief or an earlier run's folder"):
        adaptive_cal.start_survey(SIM, prior=3)
    with pytest.raises(TypeError, match="needs form_std_mm, length_scale_mm and noise_std_mm"):
        adaptive_cal.start_survey(SIM, hyper={"form_std_mm": 0.05})
    with pytest.raises(TypeError, match="give a Hyper"):
        adaptive_cal.start_survey(SIM, hyper=[0.05, 185, 0.004])
    s = adaptive_cal.start_survey(SIM, prior=belief, hyper=hyper._asdict())
    np.testing.assert_array_equal(s.state.belief.mean, belief.mean)


def test_grid_is_indexed_x_first_as_its_docstring_says():
    import numpy as np

    adaptive_cal.use_float64()
    survey = adaptive_cal.start_survey(ROOT / "configs" / "sim-cell.yaml")
    for t in survey.ask(3):  # a plate rising along x only
        survey.tell(t.x_mm, t.y_mm, t.z_mm, 0.01 * t.x_mm - t.z_mm + 5.0)
    gx, gy, mean, _ = survey.grid(7)
    h = survey.plan.model.surface.basis(np.array([gx[5]]), np.array([gy[1]]))[0]
    assert mean[5, 1] == pytest.approx(float(h @ survey.state.belief.mean), abs=1e-12)
    assert "mean[i, j] and std[i, j] at (gx[i], gy[j])" in adaptive_cal.planning.shell.Survey.grid.__doc__


def test_a_prior_from_a_run_that_was_not_a_result_is_warned_about(tmp_path, capsys):
    """A second audit: start_survey(prior=...) and run --prior-from took the map of a run that
    stopped with readings_disagree after 4 fused readings (1.3 mm off) without a word; and a
    correction given without a run folder was ignored."""
    import warnings

    import yaml

    from adaptive_cal.cli import main

    adaptive_cal.use_float64()
    sim = ROOT / "configs" / "sim-cell.yaml"
    data = yaml.safe_load(sim.read_text())
    data["plan"]["stop"]["max_touches"] = 6  # spent before the bound: not a result
    data["plan"]["stop"]["min_touches"] = 0
    short = tmp_path / "short.yaml"
    short.write_text(yaml.safe_dump(data))
    out = tmp_path / "short"
    assert main(["run", "--robot", str(short), "--out", str(out), "--no-progress"]) == 1
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        adaptive_cal.start_survey(sim, prior=out, correction="none")
    said = [str(w.message) for w in seen]
    assert any("was not a result (touch budget spent after 6 touches" in m
               and "its map is provisional" in m for m in said), said
    capsys.readouterr()
    assert main(["run", "--robot", str(sim), "--prior-from", str(out), "--correction-applied",
                 "none", "--dry-run"]) == 2  # a dry run plans from scratch: refused as before
    from adaptive_cal.cli.run_guards import check_prior_from
    check_prior_from(out, "none")
    assert "warning: --prior-from" in capsys.readouterr().err
    with pytest.raises(TypeError, match="give that run's folder as prior"):
        adaptive_cal.start_survey(sim, correction=(0.5, 0.5))
