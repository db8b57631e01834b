"""adaptive-cal: plans and runs probe measurements on robot cells.

A Bayesian bicubic spline of the workplane height (Brunn & Hanebeck), Kalman fusion of each probe
reading, the next touch chosen by the largest drop of integrated posterior variance, and a loop
that drives a robot cell until a variance bound is met. All lengths are mm, times s, angles deg.

The ask / tell loop on the built-in simulated cell (run from the repository root):

>>> import adaptive_cal as ac
>>> ac.use_float64()                                  # once per notebook or script
>>> cell = ac.load_cell("configs/sim-cell.yaml")      # validated; errors name the key
>>> survey = ac.start_survey(cell)                    # the cell file is read once, here
>>> sim = ac.open_cell(cell)                          # the simulated robot and probe
>>> while not survey.stop_reason():
...     target = survey.ask()[0]                      # where to touch, at which approach height
...     touch = sim.cycle.touch(target.x_mm, target.y_mm, target.z_mm)
...     told = survey.tell(touch.x_mm, touch.y_mm, touch.z_mm, touch.reading_mm)
>>> survey.stop_reason(), survey.status().mean_std_mm <= 0.004
('mean_std_bound', True)
>>> sim.close()

``stop_reason()`` also ends the loop with ``no_admissible_point`` where ``ask()`` has no touch
to offer (e.g. heights told in place of readings), and with ``readout_frozen``. The same loop with
the recording written before each fusion, progress and truth hooks is ``run_loop`` (the CLI's
``adaptive-cal run`` is ``run_session``); it also makes the closure touch (the first place
again at a bound's stop: did the cell drift?) and ends after 3 invalid readings in a row, which
this loop leaves to its writer. Names are imported on first use, so ``import adaptive_cal``
stays light:

=====================  ==========================================================================
``load_cell``          read and validate a cell file (``parse_cell`` for a dict)
``survey_plan``        the engine's settings made once from a cell (prior, candidates, stop rule)
``start_survey``       a ``Survey`` (ask, tell, skip, status, stop_reason, grid, history)
``open_cell``          the cell's robot and probe (the simulator for ``robot.adapter: sim``)
``run_loop``           ask -> touch -> judge -> record -> fuse until a stop predicate fires
``InvalidReading``     what ``tell`` raises for a NaN reading or a touch off the plate or in a keep-out
``run_session``        a whole run into a folder: recording, result.json, figures, belief
``read_recording``     a v1 recording (``RecordingWriter`` writes one)
``flatness``           the paper's flatness figures of a recording with 95 % intervals
``explain``            where a recording and the cell's simulation differ, and which physics
=====================  ==========================================================================
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it, ":name" where it is called otherwise there
# (imported on first use)
_LAZY = {
    "load_cell": "adaptive_cal.cell.schema",
    "parse_cell": "adaptive_cal.cell.schema",
    "ConfigError": "adaptive_cal.cell.files",
    "survey_plan": "adaptive_cal.cell.build",
    "Survey": "adaptive_cal.planning.shell",
    "open_cell": "adaptive_cal.run.devices",
    "run_loop": "adaptive_cal.run.loop",
    "InvalidReading": "adaptive_cal.planning.robust",
    "run_session": "adaptive_cal.run.session:run",
    "read_recording": "adaptive_cal.formats.recording",
    "RecordingWriter": "adaptive_cal.formats.writing",
    "explain": "adaptive_cal.analysis.explain",
}

__all__ = ["use_float64", "start_survey", "flatness", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        module, _, attr = _LAZY[name].partition(":")
        value = getattr(importlib.import_module(module), attr or name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'adaptive_cal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


def use_float64() -> None:
    """Turn on JAX float64 (x64). The library never does this by itself; call it once at the
    start of a notebook or script (the CLI and the tests do)."""
    import jax

    jax.config.update("jax_enable_x64", True)


def start_survey(cell, *, prior=None, hyper=None, correction="proposed"):
    """A ``Survey`` of the cell's workplane: ``survey_plan(cell)`` read once, the prior belief
    (or ``prior``, e.g. an earlier run's widened belief, with its ``hyper``-parameters).
    ``cell``: a Cell, a cell file's path or a dict. ``prior``: a ``Belief`` (with ``hyper``, a
    ``Hyper``), or an earlier run's folder: its belief.npz and hyper-parameters, moved into the
    frame ``correction`` says was applied since ("proposed", "none" or (rx, ry) deg) and
    widened by plan.drift_std_mm, as ``adaptive-cal run --prior-from`` reads it (that command
    also keeps the probe clear of the frames not assumed). A setting that looks like a unit slip
    (a bound of 4 mm meant as 4 um) is warned about, as ``adaptive-cal run`` does."""
    import os
    import warnings
    from pathlib import Path

    from adaptive_cal.cell.build import cell_doubts, survey_plan
    from adaptive_cal.cell.schema import as_cell
    from adaptive_cal.gaussian.belief import Belief
    from adaptive_cal.gaussian.prior import Hyper
    from adaptive_cal.planning.shell import Survey

    cell = as_cell(cell)
    if isinstance(prior, (str, os.PathLike)):
        recheck = importlib.import_module("adaptive_cal.run.recheck")  # on first use
        if hyper is not None:
            raise TypeError("hyper: leave it out with prior = a run folder, whose own "
                            "hyper-parameters come with its belief")
        run_dir = Path(prior)
        if not (run_dir / "belief.npz").is_file():
            raise FileNotFoundError(f"prior = {str(prior)!r}: no belief.npz there (give the folder "
                                    "of a finished 'adaptive-cal run --out DIR')")
        prior, hyper = recheck.load_prior(run_dir, cell, correction)[:2]
        note = recheck.provisional_note(run_dir)
        if note:
            warnings.warn(f"prior = {note}", UserWarning, stacklevel=2)
    elif correction != "proposed":
        raise TypeError(f"correction = {correction!r}: it moves an earlier run's map; give that "
                        "run's folder as prior")
    elif prior is not None and not isinstance(prior, Belief):
        raise TypeError(f"prior = {prior!r:.60}: give a Belief or an earlier run's folder")
    if isinstance(hyper, dict):  # result.json's "hyper" block, by its field names
        try:
            hyper = Hyper(**{k: hyper[k] for k in Hyper._fields if k in hyper})
        except TypeError:
            raise TypeError(f"hyper = {hyper!r:.80}: needs form_std_mm, length_scale_mm and "
                            "noise_std_mm (mm), and may give kernel") from None
    if hyper is not None and not isinstance(hyper, Hyper):
        raise TypeError(f"hyper = {hyper!r:.60}: give a Hyper (adaptive_cal.gaussian.prior."
                        "Hyper(form_std_mm, length_scale_mm, noise_std_mm, kernel)), or None")
    for line in cell_doubts(cell, informed_prior=prior is not None):
        warnings.warn(line, UserWarning, stacklevel=2)
    return Survey(survey_plan(cell, informed_prior=prior is not None), prior=prior, hyper=hyper)


def flatness(recording, *, samples: int = 400, seed: int = 0) -> dict:
    """Tilt, least-squares flatness (Cheng et al. eqs. 1-6), range and ISO 1101 minimum zone of a
    recording (a path, or a Recording), each with a 95 % interval from ``samples`` predicted
    repeat measurements drawn with ``numpy.random.default_rng(seed)`` (mm, deg). ``samples`` at
    least 2 (an interval needs two draws), ``seed`` at least 0: else a ValueError naming them.
    The intervals learn the noise: call ``use_float64()`` first (else a RuntimeError says so).
    ``flatness_mm`` is of the touched points (``flatness_mm_is``); the whole plate's needs a map
    (``adaptive-cal flatness REC --robot CELL.yaml``)."""
    import numbers

    import numpy as np

    from adaptive_cal.analysis.flatness_intervals import recording_flatness

    for name, value, least in (("samples", samples, 2), ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
            raise ValueError(f"{name} = {value!r}: a whole number of at least {least}")

    return recording_flatness(recording, np.random.default_rng(seed), samples)[0]
