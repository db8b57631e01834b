"""A run on a cell: the loop (``run.loop``) with the recording, the progress bar, the truth
and Ctrl-C as hooks, then results and figures. Resumable.

Every reading that was taken is written (and flushed) before it is fused; a reading the probe
cycle rejected is written too, flagged, and never fused. Ctrl-C stops after the current
touch (a second Ctrl-C stops at once; the probe cycle still retracts); the recording then holds
every touch and ``--resume`` continues it: no touch repeated, none lost.
"""
from __future__ import annotations

import signal
import sys
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from adaptive_cal.cell.build import survey_plan, touch_floor
from adaptive_cal.cell.consistency import no_admissible_point
from adaptive_cal.cell.schema import Cell
from adaptive_cal.formats.jsonfile import read_json
from adaptive_cal.formats.recording import read_recording, say
from adaptive_cal.formats.times import last_time_s
from adaptive_cal.formats.writing import RecordingWriter, provenance, repair_cut_row_said
from adaptive_cal.hardware.base import AdapterError, Interrupted, OperatorStop, StrokeOverrun
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.disagree import READINGS_DISAGREE
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.stopping import Status
from adaptive_cal.run.bar import _close_bar, _progress, _update
from adaptive_cal.run.devices import open_cell
from adaptive_cal.run.folder import run_lock, write_json
from adaptive_cal.run.loop import (CLOSING, DRIFT, NO_ADMISSIBLE_POINT, TOUCHES_REJECTED, Row,
                                   Step, SurveyLoop)
from adaptive_cal.run.recheck import (PRIOR_DISAGREES, PRIOR_HOLD, PRIOR_RECORD, PRIOR_SURPRISES,
                                      disagreement, load_prior, matching_frame, recheck_guard,
                                      saved_prior)
from adaptive_cal.run.resumable import resumable
from adaptive_cal.run.results import write_results
from adaptive_cal.run.truth import TrueError

RESULTS_SEED = 0  # the posterior samples behind result.json's intervals


class NoAdmissiblePoint(AdapterError):
    """No allowed point can be promised to land inside the probe stroke."""


class ReadingsDisagree(AdapterError):
    """Retakes rejected in a row at one place (``planning.disagree``)."""


@dataclass(frozen=True)
class RunPaths:
    """The files of a run's output folder (and its lock, ``run.folder.LOCK_NAME``)."""

    out: Path

    @property
    def recording(self) -> Path:
        return self.out / "recording.csv"


def replay(plan: SurveyPlan, state: sv.SurveyState, rec
           ) -> tuple[sv.SurveyState, float, int, np.ndarray, int | None]:
    """The state after a recording's touches ``rec`` (from a fresh ``state``), the last time
    (s), the seq the next row takes (the last seq + 1: a recording may start above 0 or have gaps), the
    time (s, NaN where blank) of each fused reading, in order (the loop's closure touch), and
    the touch at which its last closure began (None: none made). The state carries that
    closure's verdict, judged again (``report.replay.closure_of``): a resume neither touches
    the first place again nor loses what the closure found."""
    from adaptive_cal.report.replay import closure_of, last_closure

    next_seq = int(rec.seq[-1]) + 1 if len(rec) else 0
    state = sv.replay(plan, state, rec)
    at = last_closure(rec.flags)
    if at:
        state = replace(state, closure=closure_of(plan, rec))
    return (state, last_time_s(rec) or 0.0, next_seq, rec.t_s[rec.fused],
            at[0] if at else None)


@contextmanager
def _deferred_interrupt():
    """First Ctrl-C (or SIGTERM) sets a flag (stop after this touch) and says so; a second one
    interrupts at once, unless ``state["shield"]`` is set (results being written)."""
    state = {"stop": False, "shield": False}
    if signal.getsignal(signal.SIGINT) is None or not _main_thread():
        yield state
        return

    def handler(signum, frame):
        by = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"
        if state["stop"] and not state["shield"]:
            raise Interrupted(by)
        if not state["stop"]:  # said at once: a manual prompt may wait for its reading first
            print(f"\n{by}: stopping after this touch (again: at once)", file=sys.stderr)
        state["stop"] = True

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield state
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def run(cell: Cell, out: str | Path, *, resume: bool = False, prior_from: str | Path | None = None,
        correction_applied: str | tuple[float, float] = "proposed", progress: bool = True,
        max_new_touches: int | None = None,
        before_start: Callable[[], None] | None = None) -> dict:
    """Run the loop on the cell until a stopping rule fires; write recording, results, figures.

    The folder is locked for the whole run (``run.folder.run_lock``): a second run or resume on
    it fails at once with ``RunFolderBusy``. Resuming a finished run (its stopping rule already
    holds) changes nothing and returns its result.json with ``already_finished`` (the reason).
    ``prior_from``: start from that run's belief in the frame ``correction_applied`` gives
    (``load_prior``); result.json then records it as "prior_from". ``max_new_touches``: stop
    (as ``interrupted``) after that many touches (tests). ``before_start()`` runs once the lock
    is held (the CLI copies the cell file there). ``cell``: a Cell, or a cell file's path or
    dict (``cell.schema.as_cell``), read before the folder is touched."""
    from adaptive_cal.cell.schema import as_cell

    cell = as_cell(cell)
    with run_lock(out):
        if before_start is not None:
            before_start()
        return _run(cell, RunPaths(Path(out)), resume, prior_from, correction_applied, progress,
                    max_new_touches)


def _run(cell: Cell, paths: RunPaths, resume: bool, prior_from, correction_applied,
         progress: bool, max_new_touches: int | None) -> dict:
    if paths.recording.exists() and paths.recording.stat().st_size and not resume:
        raise FileExistsError(f"{paths.recording} exists: continue it with --resume, or choose "
                              "another --out")
    if resume and not paths.recording.exists():
        raise FileNotFoundError(f"{paths.recording}: nothing to resume")
    prior_from, correction_applied = saved_prior(paths.out, resume, prior_from, correction_applied)
    prior, hyper, carried, others = (load_prior(Path(prior_from), cell, correction_applied)
                                     if prior_from else (None, None, None, []))
    if carried is not None and not resume:  # so --resume continues the re-check without both flags
        write_json(paths.out / PRIOR_RECORD, {"run": str(Path(prior_from).resolve()),
                                              "correction_applied": correction_applied})
    plan = survey_plan(cell, informed_prior=prior is not None)
    state = sv.start(plan, prior=prior, hyper=hyper)
    start_t, next_seq = 0.0, 0
    if resume:
        said = repair_cut_row_said(paths.recording)  # a message line, not a Python warning
        if said is not None:
            say([said])
        rec = resumable(paths.out, read_recording(paths.recording), plan, cell.probe.zero_mm)
        state, start_t, next_seq, fused_t_s, closed_at = replay(plan, state, rec)
        done = plan.stop(sv.status(plan, state))
        saved = _saved_result(paths.out)
        if done and saved is not None and saved.get("touches") == state.touches:
            return {**saved, "already_finished": done}  # finished: nothing to do or rewrite
        print(f"resuming {paths.out}: {state.touches} touch{'es' * (state.touches != 1)} in "
              f"{paths.recording.name} ({state.fused} fused), going on from seq {next_seq}",
              file=sys.stderr, flush=True)  # before the bar, else its only sign
    else:
        fused_t_s, closed_at = None, None
    if state.touches == 0:  # refused before a device is opened (a controller connected to)
        from adaptive_cal.planning.ask import ask

        if not ask(plan, state):
            raise NoAdmissiblePoint(no_admissible_point(cell, plan))
    start_touch = state.touches
    seq_offset = next_seq - start_touch  # new rows continue from the last seq + 1
    made = provenance()  # written only where the recording starts (a resume appends rows)
    writer = RecordingWriter(paths.recording, {"cell": cell.name, "adapter": cell.robot.adapter,
                                               "probe_zero_mm": str(cell.probe.zero_mm),
                                               "flags": FLAGS_META,
                                               "software": made["software"],
                                               "started_utc": made["written_utc"]}, ("round",))
    arrival = (float(rec.x_mm[-1]), float(rec.direction[-1])) if resume and len(rec) else None
    opened = open_cell(cell, start_t_s=start_t, start_touch=start_touch, start_arrival=arrival)
    if resume:  # a readout frozen before the stop is still frozen: its repeats count on
        opened.cycle.seed_repeats(rec.reading_mm)
        opened.cycle.seed_overrun(rec)  # and an approach that overran is not sent again
    if others:  # a re-check: clear of the plate in the frames not assumed too, until refuted
        opened.cycle.guard = recheck_guard(plan, others, prior, rec if resume else None)
    truth = opened.simulated.surface_mm if opened.simulated is not None else None
    history = History(sv.status(plan, state), state.fitted_at)
    hooks = [history]
    true_rms = TrueError(plan, state, truth) if truth is not None else None
    if true_rms is not None:
        hooks.append(true_rms)
    bar = _progress(progress, cell, start_touch)
    if bar is not None:
        floor = touch_floor(cell, plan.model.form_surface.size, informed_prior=prior is not None)
        hooks.append(lambda step: _update(bar, cell, step.status, floor))

    seen = list(zip(rec.seq, rec.flags)) if resume else []  # a resumed re-check's verdicts stand
    surprises = [int(s) for s, f in seen if "surprise" in f]  # confirmed far from the belief
    off_stroke = [int(s) for s, f in seen if "stroke_end" in f]  # left the usable stroke

    def record(row: Row) -> None:
        writer.append(seq=row.seq + seq_offset, t_s=row.t_s, x_mm=row.x_mm, y_mm=row.y_mm, z_mm=row.z_mm,
                      reading_mm=row.reading_mm, flags=row.flags, round=0)
        if "surprise" in row.flags:
            surprises.append(row.seq + seq_offset)
        if "stroke_end" in row.flags:
            off_stroke.append(row.seq + seq_offset)

    stopped, error = None, None
    with _deferred_interrupt() as flag:
        held = {"n": 0, "at": 0}  # surprises seen, touches at the last

        def stop(state, status):
            if carried is not None and (len(surprises) >= PRIOR_SURPRISES or off_stroke):
                return PRIOR_DISAGREES  # one reading off the stroke: the next may overrun it
            if len(surprises) > held["n"]:
                held.update(n=len(surprises), at=state.touches)
            why = plan.stop(status)
            if why in CLOSING and carried is not None and held["n"] \
                    and state.touches - held["at"] < PRIOR_HOLD:
                why = None  # a reading far from the earlier belief: look again first
            if why:
                return why
            new = state.touches - start_touch
            if flag["stop"] or (max_new_touches is not None and new >= max_new_touches):
                return "interrupted"
            return None

        loop = SurveyLoop(plan, state, opened.cycle, stop=stop, record=record, hooks=tuple(hooks),
                          interrupt=lambda: flag["stop"], fused_t_s=fused_t_s)
        loop.closed_at = closed_at
        c = state.closure  # resumed after a closure that found a drift: the run ended there
        drifted = closed_at is not None and c is not None and c.made and not c.passed
        try:
            stopped = DRIFT if drifted else loop.run()
            if stopped == NO_ADMISSIBLE_POINT:
                stopped, error = "interrupted", NoAdmissiblePoint(no_admissible_point(cell, plan))
            elif stopped == READINGS_DISAGREE:
                error = ReadingsDisagree(loop.disagreement)
        except (KeyboardInterrupt, OperatorStop):  # Ctrl-C, the manual adapter's q
            stopped = "interrupted"
        except AdapterError as e:  # a device stopped the run: report what was measured, then raise
            stopped = TOUCHES_REJECTED if isinstance(e, StrokeOverrun) else "interrupted"
            error = e
        finally:
            flag["shield"] = True  # no touch is left to stop: the results are written whole
            writer.close()
            opened.close()
            if bar is not None:
                _close_bar(bar, stopped, error)
        state = loop.state
        # a second Ctrl-C between a touch's row and its fusion: recorded, not in this map
        unfused = writer.rows_written - (state.touches - start_touch)
        result = None
        if error is None or state.touches:
            if carried is not None and stopped == PRIOR_DISAGREES:
                carried = {**carried, "disagreement": disagreement(carried, surprises, off_stroke,
                           matching_frame(plan, read_recording(paths.recording), prior, others,
                                          carried))}
            try:
                result = write_results(
                    cell, plan, state, paths.out, stopped or "interrupted",
                    rng=np.random.default_rng(RESULTS_SEED), history=history.statuses,
                    refits=history.refits, truth=truth,
                    true_rms_mm=true_rms.rms_mm if true_rms else None,
                    extra={**({} if carried is None else {"prior_from": carried}),
                           **({"recorded_not_fused": unfused} if unfused > 0 else {}),
                           **({} if error is None else {"error": str(error),
                                                        "error_is": type(error).__name__})})
            except OSError as e:  # a full disk: the recording is whole, the results are not
                stop = f"; the run had stopped on: {error}" if error is not None else ""
                raise OSError(e.errno, f"the results could not be written ({e.strerror or e}); "
                              f"{paths.recording.name} holds every touch ({state.touches}): make "
                              f"room, then adaptive-cal run --resume writes them{stop}",
                              str(paths.out)) from e
    if error is not None:
        error.result = result  # what was measured before the device stopped: the CLI shows it
        raise error
    return result


def _saved_result(out: Path) -> dict | None:
    """result.json when it and belief.npz exist (result.json, written last, marks them whole)."""
    if not (out / "result.json").exists() or not (out / "belief.npz").exists():
        return None
    return read_json(out / "result.json")


#: what a reader that knows only DESIGN.md (which gives the flags column no meaning) must know
FLAGS_META = ("a row flagged gated, rejected or invalid is not a reading of the plate -- leave it "
              "out; outlier=P: the reading's gross-error probability (weight 1 - P); "
              "docs/recording.md of adaptive-cal")


class History:
    """A hook keeping the status before the first touch and after each touch, and the touch
    counts at which the hyper-parameters were refitted (the std may jump there)."""

    def __init__(self, first: Status, fitted_at: int = 0):
        self.statuses: list[Status] = [first]
        self.refits: list[int] = []
        self._fitted_at = fitted_at

    def __call__(self, step: Step) -> None:
        self.statuses.append(step.status)
        if step.state.fitted_at != self._fitted_at:
            self._fitted_at = step.state.fitted_at
            self.refits.append(step.status.touches)
