"""Running a study: plates in-process or on Dask distributed, results appended as JSON lines.

Each finished plate is appended (and flushed) to ``plates.jsonl`` at once (``checkpoint.py``),
so an interrupted study keeps the plates already finished and a rerun skips them. The library
sets no global flags: Dask workers get the caller's ``worker_setup`` (the CLI turns on float64
and one BLAS thread there); a LocalCluster's processes inherit this process's environment.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

from adaptive_cal.cell.schema import parse_cell
from adaptive_cal.study.checkpoint import Checkpoint, legacy_key, refuse_other_code, study_key
from adaptive_cal.study.config import Study
from adaptive_cal.study.tasks import fixed_batch_task, in_worker, plate_task

PER_PLATE = ("paper", "adaptive", "greedy_fixed")  # paper first: adaptive runs on to its accuracy
FIXED_DESIGNS = ("paper", "grid", "random")


class SchedulerError(ConnectionError):
    """The Dask scheduler cannot be reached; the message names the address."""


def _jobs(study: Study, done: set) -> tuple[dict, dict]:
    per_plate, fixed = {}, {}
    learned = study.estimator == "learned"
    for i in range(study.plates):
        todo = tuple(s for s in study.strategies if (i, s) not in done
                     and (learned or s not in FIXED_DESIGNS))
        todo = tuple(sorted(todo, key=lambda s: PER_PLATE.index(s) if s in PER_PLATE else 9))
        if todo:
            per_plate[i] = todo
        if not learned:
            for s in study.strategies:
                if s in FIXED_DESIGNS and (i, s) not in done:
                    fixed.setdefault(s, []).append(i)
    return per_plate, fixed


def _parts(todo: tuple[str, ...]) -> list[tuple[str, ...]]:
    """A plate's strategies as Dask tasks: the paper with the planner (which runs on to the
    paper's accuracy), each other alone -- a Ctrl-C loses only the tasks in flight, not a
    plate's finished strategies, and the workers share a plate's work."""
    paired = tuple(s for s in todo if s in ("paper", "adaptive"))
    return ([paired] if paired else []) + [(s,) for s in todo if s not in paired]


def connect(scheduler: str | None, workers: int, timeout_s: float = 5.0):
    """A Dask client: the scheduler at ``scheduler`` (tcp://host:port) or a LocalCluster of
    ``workers`` processes, one thread each. The processes inherit this process's environment:
    set OPENBLAS_NUM_THREADS=1 before numpy loads (the CLI does), so BLAS runs one thread.
    SchedulerError where Dask is not installed (it is an extra: ``adaptive-cal[dask]``)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:  # an audit: the README's install has no Dask; "internal error" before
        raise SchedulerError("--workers and --scheduler run plates on Dask, which this install "
                             "lacks: pip install 'adaptive-cal[dask]' (from a clone: pip "
                             "install -e '.[dask]'), or leave them out to run the plates in "
                             "this process") from None

    if scheduler:
        try:
            return Client(scheduler, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError) as e:
            raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler} within "
                                 f"{timeout_s:.0f} s ({type(e).__name__}); is it running "
                                 "and is the address right?") from None
    # silence_logs: a plate that fails is the CLI's to report (its error, once); a worker's
    # "Compute Failed ... Traceback" log before it only buries the message
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.CRITICAL)
    return Client(cluster)


def run_study(study: Study, base: dict, checkpoint: Path, *, client=None,
              worker_setup: Callable[[], None] | None = None,
              progress: Callable[[int, int], None] | None = None,
              limit: int | None = None,
              warn: Callable[[str], None] | None = None,
              reuse: bool = False) -> list[dict]:
    """Run every plate not yet in ``checkpoint``; returns all records. ``client``: a Dask client
    (None: in-process, float64 already on). ``worker_setup``: called in the worker before each
    task (e.g. ``adaptive_cal.use_float64``: a fresh worker process has JAX in float32, and a
    task refuses to run so). ``progress(done, total)``: runs (one strategy on one plate) finished
    of those still to do, called with 0 before the first and after each one in-process (a Dask
    task reports its strategies -- the paper with the planner, or one other -- or one fixed
    design's plates, at once).
    ``limit`` stops after that many new tasks (tests of interruption). ``warn(text)``: told of
    damaged lines of the checkpoint, skipped (their runs go again, the records after them kept).
    ``reuse``: keep the checkpoint's records made by other code (``checkpoint.other_code``);
    without it they are refused (ValueError naming the checkpoint), before any plate runs."""
    parse_cell(base)  # fails early on a bad cell
    key = study_key(study, base)
    ck = Checkpoint(checkpoint, key, also=(legacy_key(study, base),))
    try:
        used = [r for r in ck.records if r["plate"] < study.plates]  # a study cut short
        if not reuse:
            refuse_other_code(checkpoint, used)
        if ck.skipped and warn is not None:
            lines = ", ".join(map(str, ck.skipped))
            warn(f"{checkpoint}: line{'s' * (len(ck.skipped) > 1)} {lines} not a plate's record "
                 "(damaged?): skipped, and a run it held goes again; the records after it are kept")
        per_plate, fixed = _jobs(study, ck.done())
        data = study.model_dump(mode="json")
        total = sum(map(len, per_plate.values())) + sum(map(len, fixed.values()))
        finished = 0

        def tick(n: int) -> None:
            nonlocal finished
            finished += n
            if progress:
                progress(finished, total)

        if progress:
            progress(0, total)
        tasks = [(plate_task, (data, base, i, part)) for i, todo in per_plate.items()
                 for part in (_parts(todo) if client is not None else (todo,))]
        tasks += [(fixed_batch_task, (data, base, idx, s)) for s, idx in fixed.items()]
        if limit is not None:
            tasks = tasks[:limit]
        if client is None:
            for fn, args in tasks:
                if fn is plate_task:  # each strategy kept as it finishes (a Ctrl-C mid-plate)
                    fn(*args, report=lambda rec: (ck.add([rec]), tick(1)))
                else:
                    recs = fn(*args)
                    ck.add(recs)
                    tick(len(recs))
        else:
            from dask.distributed import as_completed

            futures = [client.submit(in_worker, worker_setup, fn, *args, pure=False)
                       for fn, args in tasks]
            try:
                for fut in as_completed(futures):
                    recs = fut.result()
                    ck.add(recs)
                    tick(len(recs))
            finally:
                for f in futures:
                    f.cancel()
        return sorted((r for r in ck.records if r["plate"] < study.plates),
                      key=lambda r: (r["plate"], r["strategy"]))
    finally:
        ck.close()
