"""The convergence figure explains itself (issue 17, item 5): the refits at which the std may
jump and the touch floor before which no bound stops the run are marked; the run's History hook
records the refits from the survey state."""
from types import SimpleNamespace

import numpy as np

from adaptive_cal.cell.build import survey_plan, touch_floor
from adaptive_cal.report.figures import convergence_figure
from adaptive_cal.run.session import History
from adaptive_cal.planning.stopping import Status

from helpers import sim_cell


def test_history_records_the_touches_at_which_the_survey_refitted():
    h = History(Status(0, 1.0, 1.0))
    for touches, fitted_at in [(1, 0), (8, 8), (9, 8), (12, 12), (13, 12)]:
        h(SimpleNamespace(status=Status(touches, 0.1, 0.1), state=SimpleNamespace(fitted_at=fitted_at)))
    assert h.refits == [8, 12] and len(h.statuses) == 6


def test_the_figure_marks_refits_and_the_floor():
    fig = convergence_figure(np.arange(5), np.ones(5) * 1e-2, np.ones(5) * 2e-2,
                             bound_mean_mm=4e-3, refits=[2, 4], floor_touches=3)
    ax = fig.axes[0]
    vertical = [ln.get_xdata()[0] for ln in ax.get_lines()
                if len(set(ln.get_xdata())) == 1 and len(ln.get_xdata()) == 2]
    assert sorted(vertical) == [2, 4]
    labels = ax.get_legend_handles_labels()[1]
    assert "hyper-parameters refitted (std may jump)" in labels
    assert "touch floor: no bound stops before 3 touches" in labels


def test_the_floor_drawn_is_the_stop_rules_floor():
    cell = sim_cell()
    plan = survey_plan(cell)
    k = plan.model.form_surface.size
    assert touch_floor(cell, k) == k  # learned, no noise range: as many touches as coefficients
    assert touch_floor(cell, k, informed_prior=True) == 0
    ranged = sim_cell(probe={"noise_range_mm": [0.003, 0.008]})
    assert touch_floor(ranged, k) == 0
    from adaptive_cal.planning.stopping import Status as S
    rule = plan.stop
    assert rule(S(k - 1, 1e-6, 1e-6)) is None and rule(S(k, 1e-6, 1e-6)) == "mean_std_bound"
