"""What ``adaptive-cal run`` and ``adaptive-cal report`` say, in words a reader cannot misread:
the report's touches figure whole, an adequate model's widened bands said for what they are,
an unfinished run's figures marked, "RMS std" for the RMS, a bar that ends full when the bound
is met, the dry run's approach heights, which clock each time is on, the re-check's edge
caveat, what --resume resumed, no "-0.0"."""
import base64
import contextlib
import io
from types import SimpleNamespace

import numpy as np
import pytest

from adaptive_cal.cli import main
from adaptive_cal.cli.run import _summary
from adaptive_cal.planning.adequacy import Adequacy
from adaptive_cal.planning.closure import Closure
from adaptive_cal.report import figures as plots
from adaptive_cal.report.sections import percent, reason_text, run_section, signed
from adaptive_cal.run import session

from helpers import SIM_CELL, sim_cell


def test_the_reports_touches_figure_holds_its_legend_and_axis_labels():
    """The legend right of the axes and the y label were cut off the saved PNG: ink ran into
    its left and right edges. Now a white margin surrounds everything drawn."""
    import matplotlib.image as mimage

    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.report.html import _png, touches_figure

    cell = load_cell(SIM_CELL)
    x, y = np.array([-200.0, 0.0, 200.0, 43.0]), np.array([-170.0, 0.0, 170.0, 2.0])
    rec = type("Rec", (), {"x_mm": x, "y_mm": y, "seq": np.arange(4),
                           "fused": np.ones(4, bool), "__len__": lambda self: 4})()
    png = mimage.imread(io.BytesIO(base64.b64decode(_png(touches_figure(cell, rec)))))[..., :3]
    for name, edge in (("left", png[:, :3]), ("right", png[:, -3:]), ("top", png[:3]),
                       ("bottom", png[-3:])):
        assert edge.min() > 0.99, f"something drawn is cut at the {name} edge"


def _adequacy(adequate, region_um, form_um, checks=None, uneven=None):
    regions = np.full((3, 3), (region_um * 1e-3) ** 2)
    regions[1, 1] = 0.0
    return Adequacy(adequate, checks or {"loo": {"passed": adequate}}, regions,
                    np.linspace(-225, 225, 4), np.linspace(-185, 185, 4), 46.25,
                    np.ones((3, 3), int), form_var_mm2=(form_um * 1e-3) ** 2,
                    grew=region_um > 0 and uneven is None, uneven=uneven)


def test_a_half_that_scatters_more_is_said_as_such_not_as_a_grown_model():
    text = _adequacy(True, 7.3, 0.0, uneven={"half": "x > 0 mm", "rms_mm": 0.0073}).summary()
    assert text.startswith("model checks pass; bands widened by about ")
    assert ("the readings on x > 0 mm scatter beyond the other half's by about 7.3 um RMS more "
            "than chance allows") in text
    assert "grew" not in text


def test_widened_bands_of_a_model_whose_checks_pass_are_said_for_what_they_are():
    text = _adequacy(True, 47.6, 0.15).summary()  # a grown model (the 10-touch run's numbers)
    assert text.startswith("model checks pass; bands widened by about 44.9 um RMS: the coarse "
                           "knots failed their checks, so the model grew 46 mm knots")
    assert "adequate" not in text and "unresolved" not in text
    assert text.count(" um; x ") == 2 and text.endswith("47.6 um (and 5 more regions)")
    form = _adequacy(True, 0.0, 1.2).summary()  # the learned form's finer part alone
    assert form.startswith("model checks pass; bands widened by about 1.2 um RMS: the learned "
                           "form's part finer than the 46 mm knots, about 1.2 um RMS")
    # the form's finer part is alike in every region: said once, not as three regions of nine
    # (an outside audit: the three named were the left third of a plate rough on its right)
    assert "grew" not in form and "over the whole plate alike" in form
    assert "more region" not in form and " um; x " not in form
    # the caveat of an adequate model is said where the bands were widened too (it was left
    # out exactly on the runs an outside audit found 2-2.6 x off)
    caveat = "structure finer than the touches' spacing cannot be told from that noise"
    assert caveat in text and caveat in form and caveat in _adequacy(True, 0.0, 0.0).summary()
    assert caveat not in _adequacy(False, 20.0, 0.0).summary()
    # a grown model's form lives on coarser knots than the map's: both are named (an outside
    # audit read "finer than the 92 mm knots" beside result.json's 45 mm knots)
    import dataclasses

    grown = dataclasses.replace(_adequacy(True, 0.0, 1.2), knot_spacing_mm=92.5,
                                map_knot_spacing_mm=45.0)
    assert ("the learned form's part finer than the 92 mm knots (the form's knots; the map's are "
            "45 mm), about 1.2 um RMS") in grown.summary()
    bad = _adequacy(False, 20.0, 0.0).summary()
    assert bad.startswith("model inadequate (loo): structure finer than 46 mm, about ")
    assert bad.endswith("(and 5 more regions)")
    assert "more region" not in _adequacy(True, 0.0, 0.0).summary()


def test_an_unfinished_runs_figures_say_so_in_their_titles():
    gap = "interrupted after 20 touches; posterior RMS std 26.6 um against the 4 um bound"
    g = np.linspace(-1, 1, 3)
    fig = plots.surface_figure(g, g, np.zeros((3, 3)), np.ones((3, 3)), np.zeros((0, 2)),
                               (-1, 1), (-1, 1), title="cell", incomplete=gap)
    assert "INCOMPLETE: interrupted after 20 touches" in fig._suptitle.get_text()
    conv = plots.convergence_figure([0, 1], [1.0, 0.5], [2.0, 1.0], incomplete=gap)
    title = conv.axes[0].get_title()
    assert title.startswith("convergence\nINCOMPLETE: interrupted after 20 touches")
    done = plots.convergence_figure([0, 1], [1.0, 0.5], [2.0, 1.0])
    assert done.axes[0].get_title() == "convergence"
    assert "INCOMPLETE" not in plots.surface_figure(
        g, g, np.zeros((3, 3)), np.ones((3, 3)), np.zeros((0, 2)), (-1, 1), (-1, 1),
        title="cell")._suptitle.get_text()


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """A run stopped after 5 touches (its figures' marks seen), then resumed to its bound with
    the progress bar on: (folder, first result, resumed result, resume's stderr)."""
    out = tmp_path_factory.mktemp("ux") / "run"
    cell = sim_cell(plan={"candidates": 2000, "stop": {"mean_std_mm": 0.006,
                                                       "max_touches": 60}})
    seen = {}
    real = plots.surface_figure

    def spy(*a, **k):
        seen["incomplete"] = k.get("incomplete")
        return real(*a, **k)

    plots.surface_figure = spy
    try:
        first = session.run(cell, out, progress=False, max_new_touches=5)
    finally:
        plots.surface_figure = real
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        again = session.run(cell, out, resume=True, progress=True)
    return out, first, again, err.getvalue(), seen


def test_the_written_figures_of_an_interrupted_run_are_marked(quick):
    _, first, _, _, seen = quick
    assert first["stopped_because"] == "interrupted"
    assert seen["incomplete"].startswith("interrupted after 5 touches; posterior RMS std ")


def test_resume_says_what_it_resumes_before_the_bar(quick):
    out, _, _, err, _ = quick
    line = f"resuming {out}: 5 touches in recording.csv (5 fused), going on from seq 5"
    assert err.startswith(line + "\n"), err[:300]


def test_a_bar_that_stops_on_its_bound_ends_full_and_says_bound_met(quick):
    _, _, again, err, _ = quick
    assert again["stopped_because"] == "mean_std_bound"
    n = again["touches"]
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert "100%" in last and f"{n}/{n} " in last and last.rstrip().endswith("bound met]"), last
    assert "RMS std " in last and "mean std" not in last


def test_the_bar_is_closed_full_only_on_a_bound():
    for why, total in (("mean_std_bound", 31), ("max_std_bound", 31), ("interrupted", 120),
                       ("drift", 120), (None, 120)):
        bar = SimpleNamespace(n=31, total=120, close=lambda: None)
        session._close_bar(bar, why)
        assert bar.total == total, why


def test_the_html_and_the_dry_run_say_rms_std_bound():
    assert reason_text("mean_std_bound") == "RMS std bound"
    assert reason_text("touch_budget") == "touch budget"
    page = run_section({"touches": 31, "fused": 31, "stopped_because": "mean_std_bound",
                        "posterior": {"mean_std_mm": 0.0036, "max_std_mm": 0.0094},
                        "truth": {"rms_error_mm": 0.0035, "max_error_mm": 0.0094,
                                  "coverage95": 0.98}})
    assert "RMS std bound" in page and "mean std" not in page
    assert "covers 98 % of the plate" in page


def test_a_recheck_page_says_it_is_one_and_that_its_noise_was_carried_not_learned():
    """A --prior-from re-check learns nothing (its belief and noise are the earlier run's); its
    page called them "(learned)" and did not say it was a re-check (an audit, 2026-11-24)."""
    base = {"touches": 10, "fused": 10, "stopped_because": "mean_std_bound",
            "posterior": {"mean_std_mm": 0.0036, "max_std_mm": 0.0094},
            "hyper": {"noise_std_mm": 0.0054, "form_std_mm": 0.49, "length_scale_mm": 418.0}}
    page = run_section({**base, "prior_from": {"run": "runs/demo", "assumed": "proposed",
                                               "correction_deg": {"rx": 0.1088, "ry": -0.8021}}})
    assert "a re-check of" in page and "runs/demo" in page and "rx +0.1088, ry -0.8021 deg" in page
    assert "reading noise (carried from the earlier run)" in page and "(learned)" not in page
    assert "reading noise (learned)" in run_section(base) and "re-check" not in run_section(base)


def test_dry_run_gives_the_first_approach_height_and_says_the_rest_are_set_at_run_time(capsys):
    assert main(["run", "--robot", str(SIM_CELL), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = [line for line in lines if line[:3].strip().isdigit()]
    assert len(rows) == 20
    assert rows[0].split()[3] == "+0.000"  # the prior's mean: 0 on a fresh run
    assert all(r.endswith("set at run time") for r in rows[1:])
    assert not any(r.endswith(" 0.000") for r in rows[1:])
    assert "(RMS std bound; at most 120)" in next(x for x in lines if x.startswith("expected"))


def test_dry_run_says_how_high_the_travels_go(tmp_path, capsys):
    """The prior's 1 deg tilt lets the sim plate's corners stand 25 mm high: the first travels
    rise above the 15 mm safe height (``planning.clearance``), and the dry run says so, with the
    height an independent product of the prior gives; a tight tilt prior travels at 15 mm."""
    import numpy as np
    import yaml

    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.cell.schema import load_cell, load_yaml
    from adaptive_cal.planning import survey as sv

    assert main(["run", "--robot", str(SIM_CELL), "--dry-run"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("travel:"))
    plan = survey_plan(load_cell(SIM_CELL))
    b = sv.start(plan).belief
    h = plan.model.surface.basis(*plan.eval_xy.T)
    sd = np.sqrt(np.einsum("nk,kl,nl->n", h, b.cov, h))  # the prior's sd, written out
    top = float(np.max(h @ b.mean + 4.8916 * sd))  # z* for a two-sided 1e-6
    assert f"stand up to {top:.2f} mm" in line and f"rise to {top + 5.5:.2f} mm" in line, line
    tight = load_yaml(SIM_CELL)
    tight["model"]["tilt_std_deg"] = 0.01
    path = tmp_path / "tight.yaml"
    path.write_text(yaml.safe_dump(tight))
    assert main(["run", "--robot", str(path), "--dry-run"]) == 0
    assert "travel: at robot.safe_height_mm = 15 mm, clear of the plate" in capsys.readouterr().out


def _result(**more):
    r = {"stopped_because": "mean_std_bound", "touches": 31, "fused": 31,
         "bound": {"mean_std_mm": 0.004, "max_std_mm": None, "max_touches": 120},
         "posterior": {"mean_std_mm": 0.0036, "max_std_mm": 0.0094},
         "tilt": {"rx_deg": 0.1, "ry_deg": -0.00001, "a": -1e-8, "b": 0.0019, "c": -0.00001},
         "flatness_mm": {k: {"value": 0.27, "ci95": [0.26, 0.28]}
                         for k in ("least_squares", "minimum_zone")},
         "truth": {"rms_error_mm": 0.0035, "max_error_mm": 0.0094, "coverage95": 0.98},
         "robot_time_s": 117.5, "travel_mm": 3700.0}
    return {**r, **more}


def test_the_summary_labels_the_robot_time_an_estimate_and_prints_no_negative_zero(capsys):
    from adaptive_cal.cell.schema import load_cell

    _summary(_result(), "runs/x", load_cell(SIM_CELL))
    text = capsys.readouterr().out
    assert ("estimated robot time: about 2.0 min for 31 touches (3.7 m of travel at 150 mm/s, "
            "plus 3 s per touch)") in text
    assert "ry +0.0000 deg; a +0.000000, b +0.001900 mm/mm, c +0.0000 mm" in text
    assert "-0.0" not in text
    assert "95 % band covers 98 % of the plate" in text
    assert signed(-1e-9, 1) == "+0.0" and signed(-0.06, 1) == "-0.1" and percent(0.98) == "98 %"


def test_the_closure_says_which_clock_its_time_is_on():
    c = Closure(True, x_mm=43.0, y_mm=2.0, first_readings=3, elapsed_s=120.2,
                difference_mm=-0.00001, sd_mm=0.0063, p=0.69)
    assert c.text() == ("closure: the first place (x 43.0, y 2.0 mm), touched again 120 s after "
                        "its first reading on the recording's clock (t_s), read +0.0 um against "
                        "the run's first 3 readings there (sd 6.3 um, p 0.69): no drift seen")


def test_result_json_says_what_robot_time_and_the_tilt_plane_are(quick):
    _, first, _, _, _ = quick
    assert first["robot_time_is"].startswith("estimate: straight travel from the plate centre")
    assert "150 mm/s" in first["robot_time_is"]
    assert "(mm/mm)" in first["tilt"]["plane_is"] and "(mm" in first["tilt"]["plane_is"]
    assert {"a", "b", "c", "rx_deg", "ry_deg"} <= set(first["tilt"])  # the keys stay
    assert 0 < first["tilt"]["noise_dof"] < 5  # 5 touches less what the map spent


def test_a_model_not_checked_still_says_where_the_map_is_extrapolated():
    """The re-check (hyper-parameters carried, never checked) dropped the edge caveat."""
    from adaptive_cal.cell.build import survey_plan
    from adaptive_cal.planning import survey as sv
    from adaptive_cal.planning.stopping import Status
    from adaptive_cal.run.results import model_block

    plan = survey_plan(sim_cell(), informed_prior=True)
    block = model_block(sv.start(plan), Status(0, 1.0, 1.0, adequate=True), plan)
    assert block["summary"].startswith("model not checked (the hyper-parameters are not learned")
    assert block["summary"].endswith("of the workplane's edge (10 % of the plate) is "
                                     "extrapolated: no touch can reach it and no check tests it")
    assert block["extrapolated"]["margin_mm"] == [10.0, 10.0, 10.0, 10.0]


def test_a_stop_that_may_leave_the_probe_down_erases_the_bar_so_the_warning_comes_first():
    """With the progress bar on, its last redraw came after the stop and before "THE PROBE MAY
    BE DOWN" (an outside audit, 2026-11-29): such a stop now erases the bar; any other stop
    leaves it where the run stopped."""
    import io

    from tqdm import tqdm

    from adaptive_cal.hardware.base import AdapterError, ProbeLeftDown
    from adaptive_cal.run.session import _close_bar

    def last_line(error):
        out = io.StringIO()
        bar = tqdm(total=120, file=out, desc="touches")
        bar.update(3)
        _close_bar(bar, "interrupted", error)
        return out.getvalue().split("\r")[-1]

    assert "3/120" in last_line(AdapterError("link lost"))
    assert "3/120" in last_line(None)
    assert last_line(ProbeLeftDown("THE PROBE MAY BE DOWN")).strip() == ""


def test_a_second_sigterm_is_named_sigterm_not_ctrl_c(capsys):
    """A service manager's or a timeout's SIGTERM stopped a run with "interrupted: Ctrl-C"
    (an outside audit, 2026-11-29): the interrupt now carries the signal's name into the
    probe-down warning; the exit status stays 130 (README)."""
    import os
    import signal

    from adaptive_cal.hardware.base import Interrupted, _left_down
    from adaptive_cal.run.session import _deferred_interrupt

    with pytest.raises(Interrupted) as caught:
        with _deferred_interrupt() as state:
            os.kill(os.getpid(), signal.SIGTERM)  # the first: stop after this touch
            assert state["stop"]
            os.kill(os.getpid(), signal.SIGTERM)  # the second: at once
    assert caught.value.by == "SIGTERM"
    # the first is said at once, naming the signal (an audit: nothing was said until the touch
    # ended, and a manual adapter's prompt may wait for its reading first)
    assert "SIGTERM: stopping after this touch" in capsys.readouterr().err
    down = _left_down(1.0, 2.0, 0.0, 15.0, caught.value, "then")
    assert "failed (interrupted: SIGTERM)" in str(down) and down.interrupted
    plain = _left_down(1.0, 2.0, 0.0, 15.0, KeyboardInterrupt(), "then")
    assert "failed (interrupted: Ctrl-C)" in str(plain)
