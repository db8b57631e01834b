"""Simulation studies: synthetic plates, strategies on the same plates, a lower bound on touches,
in-process or on Dask. ``adaptive-cal study STUDY.yaml --json OUT.json`` (docs/study.md)."""
from adaptive_cal.study.config import STRATEGIES, Study, check_feasible, load_study, parse_study

__all__ = ["STRATEGIES", "Study", "check_feasible", "load_study", "parse_study"]
