"""Test setup: float64 in JAX (the library never sets it itself), headless matplotlib."""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see adaptive_cal/cli.py


def _shared_jax_cache() -> None:
    """One JAX compilation cache for this run's workers and the commands the tests start in
    subprocesses (``adaptive_cal/cli/jax_cache.py``), in a folder of this user's under the
    temporary directory: each compiles the same programs otherwise. Set before JAX loads."""
    import tempfile

    from adaptive_cal.cli import jax_cache

    uid = os.getuid() if hasattr(os, "getuid") else "user"
    # a JAX_COMPILATION_CACHE_DIR or ADAPTIVE_CAL_JAX_CACHE (off included) of the caller wins
    os.environ.setdefault("ADAPTIVE_CAL_JAX_CACHE", os.path.join(
        tempfile.gettempdir(), f"adaptive-cal-tests-jax-{uid}"))
    jax_cache.enable()


_shared_jax_cache()

from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402
import pytest  # noqa: E402

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

ROOT = Path(__file__).resolve().parents[1]
CHENG = ROOT / "adaptive_cal" / "data" / "cheng2025"


@pytest.fixture
def cheng_round0():
    return CHENG / "round0_initial.csv"


@pytest.fixture
def cheng_round1():
    return CHENG / "round1_first_correction.csv"


@pytest.fixture(scope="session")
def cheng_cell():
    """The reference cell's file (configs/cheng2025-cell.yaml), loaded once."""
    from adaptive_cal.cell.schema import load_cell

    return load_cell(ROOT / "configs" / "cheng2025-cell.yaml")


def pytest_collection_modifyitems(config, items):
    """Tests marked slow run first (the order is otherwise kept): with pytest-xdist's
    work stealing (below) they start at once, the other worker and the thieves take the short
    ones, and the run ends on short tests instead of one worker idle while the other finishes a
    two-minute test."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.hookimpl(optionalhook=True)  # only where pytest-xdist is installed
def pytest_xdist_make_scheduler(config, log):
    """``-n N`` with the default ``--dist load``: work stealing instead (a worker that runs out
    of tests takes half of another's queue; under load scheduling a worker's first chunk of
    about 233 tests stays its own to the end). Any other --dist is left as asked."""
    if config.getoption("dist") != "load":
        return None
    from xdist.scheduler import WorkStealingScheduling

    return WorkStealingScheduling(config, log)
