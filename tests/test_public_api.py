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
