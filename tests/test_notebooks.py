"""The notebooks run top to bottom (nbclient, a fresh kernel each) and are committed stripped."""
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="nbformat not installed (pip install -e '.[notebooks]')")
nbclient = pytest.importorskip("nbclient", reason="nbclient not installed (pip install -e '.[notebooks]')")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
NAMES = ["01_quickstart", "02_paper_cell", "03_synthetic_tilts", "04_explain"]
BUDGET_S = 180  # each is about 10-45 s on the 2-core CI machine; the budget catches a runaway


def test_all_notebooks_listed():
    assert sorted(p.stem for p in NOTEBOOKS.glob("*.ipynb")) == NAMES


def test_committed_stripped():
    import sys

    sys.path.insert(0, str(NOTEBOOKS))
    try:
        from strip import strip
    finally:
        sys.path.pop(0)
    dirty = [n for n in NAMES if strip(nbformat.read(NOTEBOOKS / f"{n}.ipynb", as_version=4))]
    assert not dirty, f"run 'python notebooks/strip.py' before committing: {dirty} hold outputs"


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_notebook_runs(name, monkeypatch, tmp_path):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    t0 = time.monotonic()
    nbclient.NotebookClient(nb, timeout=BUDGET_S, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    took = time.monotonic() - t0
    assert took < BUDGET_S
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors
    images = sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code"
                 for o in c.outputs)
    assert images >= 1, f"{name} showed no figure"
