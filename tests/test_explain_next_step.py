"""An ``unexplained`` verdict is followed by one line saying what to check or touch next, for
the axis the structure tests found (the report's ``unexplained.test`` / ``axis``): time ->
warm-up or drift, direction -> backlash, position -> plate shape finer than the library, reach
-> the arm, indication -> the gauge, noise -> the repeatability. No new statistics."""
import pytest

from adaptive_cal.report.explain_text import NEXT_STEP, verdict_lines


def _none(p):
    return {"verdict": "none", "verdict_probability": p, "ambiguous_with": [],
            "threshold": {"log_bayes_factor": 1.0},
            "candidates": [{"effect": "form", "log_bayes_factor": -0.2}]}


def _unexplained(axis, test):
    return {"verdict": "unexplained", "verdict_probability": 0.98, "ambiguous_with": [],
            "unexplained": {"axis": axis, "test": test, "p_value": 1e-3,
                            "structure_rms_mm": 0.004, "library_share": 0.0,
                            "nearest_library_effect": None,
                            "where": [{"x_mm": 55.0, "y_mm": 15.0, "residual_mm": 0.0054}],
                            "detail": "d"}}


@pytest.mark.parametrize("axis, test, words", [
    ("time", "time", "warm-up or drift"),
    ("time", "serial correlation", "disturbance that lasts"),
    ("direction", "direction", "backlash: touch a few points twice, arriving once moving +x"),
    ("direction", "direction along y", "backlash along y"),
    ("position", "position along x", "finer than the library's form"),
    ("position", "position", "finer than the library's form"),
    ("reach", "reach", "check the arm"),
    ("indication", "indication", "check the gauge"),
    ("noise", "noise", "stated noise"),
])
def test_unexplained_is_followed_by_the_next_step_for_its_axis(axis, test, words):
    out = verdict_lines(_unexplained(axis, test))
    assert out[-1].startswith("  next: ") and words in out[-1]
    assert out[-2].startswith("    near x 55")  # after the structure and where it is
    assert sum(line.startswith("  next:") for line in out) == 1


def test_every_axis_the_structure_tests_report_has_a_next_step():
    from adaptive_cal.analysis.explain import structure

    axes = set(structure.AXIS_OF.values()) | {"time", "direction", "position", "reach",
                                              "indication", "noise"}
    assert axes <= set(NEXT_STEP)


def test_no_next_step_without_an_unexplained_verdict():
    assert not any("next:" in line for line in verdict_lines(_none(0.6)))
