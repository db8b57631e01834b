"""What a study shows its user: figures with titles, axis labels and legends, a table that says
how it counts, the JSON's true-error target as applied, and progress on stderr."""
import matplotlib

matplotlib.use("Agg")

import pytest  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402

from adaptive_cal.study.config import load_study, parse_study  # noqa: E402
from adaptive_cal.study.figures import (coverage_figure, example_plate_figure,  # noqa: E402
                                        touches_vs_bound_figure)
from adaptive_cal.study.summary import summarise, table  # noqa: E402

from conftest import ROOT  # noqa: E402

SMOKE = ROOT / "configs" / "study-smoke.yaml"


def _study(**bound):
    study, base = load_study(SMOKE)
    data = study.model_dump(mode="json")
    data.update(plates=2, strategies=["adaptive", "grid"], lower_bound={"plates": 1})
    data["bound"].update(mean_std_mm=0.01, max_touches=45, **bound)
    return parse_study(data), base


def _rec(strategy, plate, touches, touches_true, closure=True, **extra):
    xy = [[-200.0 + 10 * i, -150.0 + 7 * i] for i in range(touches)]
    return {"strategy": strategy, "plate": plate, "seed": 1234 + plate, "touches": touches,
            "touches_true": touches_true, "closure": closure, "robot_time_s": 10.0 * touches,
            "robot_time_true_s": None if touches_true is None else 10.0 * touches_true,
            "travel_mm": 100.0, "mean_std_mm": 0.009, "true_rms_mm": 0.011, "true_max_mm": 0.03,
            "coverage95": 0.9, "xy": xy,
            "trajectory": [[5, 0.03, 0.04], [12, 0.012, 0.02], [touches, 0.009, 0.011]], **extra}


def _records():
    lb = {"relaxed_touches": 18.0, "relaxed_whole_touches": 19.0, "best_integer_touches": None}
    return [_rec("adaptive", 0, 21, 25, **lb), _rec("adaptive", 1, 30, None),
            _rec("grid", 0, 20, 20), _rec("grid", 1, 30, 30)]


def _texts(fig):
    FigureCanvasAgg(fig).draw()
    return fig


def test_example_plate_figure_names_plate_seed_axes_and_touch_order():
    study, base = _study()
    records = _records()
    fig = _texts(example_plate_figure(study, summarise(study, records), records, base))
    title = fig._suptitle.get_text()
    assert "plate 0" in title and "seed 1234" in title and "own stop" in title
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == 2
    assert all(ax.get_xlabel() == "x (mm)" for ax in panels)
    assert panels[0].get_ylabel() == "y (mm)"
    assert "adaptive: 20 touches (+1 closure)" in panels[0].get_title()
    bars = [ax for ax in fig.axes if ax not in panels]
    assert [b.get_ylabel() for b in bars] == ["touch order"]
    assert [t.get_text() for t in bars[0].get_yticklabels()] == ["first", "last"]


def test_coverage_figure_has_title_x_label_and_explains_the_dashed_line():
    study, _ = _study()
    records = _records()
    fig = _texts(coverage_figure(summarise(study, records), records))
    ax = fig.axes[0]
    assert "coverage" in ax.get_title() and "2 plates" in ax.get_title()
    assert ax.get_xlabel().startswith("strategy")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["nominal 95 %"]


def test_touches_vs_bound_has_titles_and_plain_tick_numbers():
    study, _ = _study()
    records = _records()
    fig = _texts(touches_vs_bound_figure(study, summarise(study, records), records))
    assert "touches against the bound" in fig._suptitle.get_text()
    for ax in fig.axes:
        assert ax.get_title()
        ticks = [t.get_text() for t in ax.get_xticklabels() + ax.get_xticklabels(minor=True)]
        shown = [t for t in ticks if t]
        assert "10" in shown and "20" in shown, shown
        assert not any("times" in t or "^" in t for t in shown), shown


def test_touches_vs_bound_counts_a_plate_that_never_reached_it_at_the_budget():
    """Averaged over the plates that reached a bound, a strategy that reached it only on the
    easy plate looked cheaper than one that reached it on both (an outside audit)."""
    study, _ = _study()
    easy = {"trajectory": [[5, 0.03, 0.03], [10, 0.009, 0.009]]}
    hard = {"trajectory": [[5, 0.05, 0.05], [45, 0.02, 0.02]]}  # never at 10 um: the budget
    records = [{**_rec("adaptive", 0, 10, 10), **easy}, {**_rec("adaptive", 1, 45, None), **hard}]
    fig = touches_vs_bound_figure(study, summarise(study, records), records)
    ax = fig.axes[1]
    x, y = ax.lines[0].get_data()  # the line of the means
    assert x[0] == pytest.approx(10.0) and y[0] == pytest.approx((10 + 45) / 2)
    hollow = [line for line in ax.lines if line.get_markerfacecolor() == "white"]
    assert hollow and hollow[0].get_xdata()[0] == pytest.approx(10.0)
    assert "counted at the budget of 45" in ax.get_ylabel()


def test_summary_json_carries_the_true_error_target_in_force():
    study, _ = _study()
    b = summarise(study, _records())["bound"]
    assert b["true_rms_mm"] == pytest.approx(0.01)
    assert b["true_rms_from"] == "bound.mean_std_mm (default)"
    study, _ = _study(true_rms_mm=0.02)
    b = summarise(study, _records())["bound"]
    assert b["true_rms_mm"] == pytest.approx(0.02) and b["true_rms_from"] == "bound.true_rms_mm"


def test_table_says_how_it_counts_plates_that_missed_and_the_closure_touch():
    study, _ = _study()
    text = table(summarise(study, _records()))
    assert "true RMS error 10.0 um; 2 plates" in text
    assert ("a plate that never reached it counts at the touch budget (max_touches = 45); "
            "reached: adaptive 50%") in text
    line = next(t for t in text.splitlines() if t.startswith("lower bound"))
    assert "first 1 plate)" in line and "closure touch excluded" in line
    # every plate reached it: said so; an old summary (true_rms_mm null) still reads
    records = [r for r in _records() if r["strategy"] == "grid"]
    summary = summarise(study, records)
    summary["bound"]["true_rms_mm"] = None
    text = table(summary)
    assert "reached: every plate, every strategy" in text and "true RMS error 10.0 um" in text


def test_progress_reports_runs_time_taken_and_time_left():
    import io

    from adaptive_cal.cli.study import Progress

    now = [100.0]
    stream = io.StringIO()
    p = Progress("smoke", 10, "DIR/plates.jsonl", stream=stream, clock=lambda: now[0])
    now[0] = 103.0  # a cluster's start: in the time taken, not in the time per run
    p(0, 6)
    now[0] = 133.0
    p(2, 6)
    now[0] = 163.0
    p(6, 6)
    p.close()
    assert stream.getvalue().splitlines() == [
        "study smoke: 4 of 10 runs already in DIR/plates.jsonl, 6 to run",
        "study smoke: 2/6 runs done, 33 s, about 60 s left",
        "study smoke: 6/6 runs done, 63 s"]


def test_study_help_names_the_per_plate_file_without_out(capsys):
    from adaptive_cal.cli import main

    with pytest.raises(SystemExit):
        main(["study", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "OUT.json.plates.jsonl" in text and "DIR/plates.jsonl" in text


def test_progress_gives_no_time_left_before_a_plates_strategies_are_done():
    import io

    from adaptive_cal.cli.study import Progress

    now = [0.0]
    stream = io.StringIO()
    p = Progress("s", 9, "DIR/plates.jsonl", stream=stream, clock=lambda: now[0], per_plate=3)
    p(0, 9)
    for done, t in ((1, 2.0), (3, 60.0)):  # a quick grid first, then the plate's slow ones
        now[0] = t
        p(done, 9)
    assert stream.getvalue().splitlines() == [
        "study s: 1/9 runs done, 2 s, time left once a plate's strategies are done",
        "study s: 3/9 runs done, 60 s, about 2 min left"]
