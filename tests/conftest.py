"""Test setup: float64 in JAX (the library never sets it itself), headless matplotlib."""
import os
from pathlib import Path

import matplotlib
import pytest

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
