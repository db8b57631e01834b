"""``adaptive-cal study STUDY.yaml --json OUT.json [--out DIR] [--scheduler ADDRESS]``: the same
synthetic plates under every strategy, a lower bound on touches, tables and plots.

Plates finished are appended to DIR/plates.jsonl (or OUT.json's name + .plates.jsonl) as they
finish; an interrupted study keeps them and a rerun skips them. The work is the library's
(``adaptive_cal.study``); this module parses arguments and prepares Dask workers.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from adaptive_cal.cli.common import at_least


def add_arguments(p) -> None:
    p.add_argument("study", help="study file (YAML), e.g. configs/study-tilts.yaml")
    p.add_argument("--json", required=True, metavar="OUT.json", help="summary (JSON)")
    p.add_argument("--out", metavar="DIR", help="per-plate records, table (markdown) and plots")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:port); workers need OPENBLAS_NUM_THREADS=1")
    p.add_argument("--workers", type=at_least(0), default=0,
                   help="run on a Dask LocalCluster of N worker processes (0: in-process)")
    p.add_argument("--plates", type=at_least(1),
                   help="override the study's number of plates (at least 1)")
    p.add_argument("--strategies", help="override the study's strategies (comma separated)")
    p.add_argument("--doc", metavar="PAGE.md", help="write the study page (docs/study.md)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one study key, e.g. --set bound.true_rms_mm=0.01 (YAML value)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def worker_setup() -> None:
    """A Dask worker's start, like this command's own: float64 in JAX, one BLAS thread (numpy
    may already be loaded with threads in a worker we did not start)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from adaptive_cal import use_float64

    use_float64()
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:
        pass


def command(args) -> int:
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.doc import write_doc
    from adaptive_cal.study.overrides import apply_overrides
    from adaptive_cal.study.runner import connect, run_study
    from adaptive_cal.study.summary import summarise, table

    study, base = load_study(args.study)
    study = apply_overrides(study, base, plates=args.plates, strategies=args.strategies,
                            settings=args.set)
    out_json = Path(args.json)
    out_dir = Path(args.out) if args.out else None
    checkpoint = (out_dir / "plates.jsonl" if out_dir
                  else out_json.with_name(out_json.name + ".plates.jsonl"))
    client = None
    if args.scheduler or args.workers:
        from adaptive_cal.cli.common import UserError
        from adaptive_cal.study.runner import SchedulerError

        try:
            client = connect(args.scheduler, max(args.workers, 1))
        except SchedulerError as e:  # the address given is wrong or down: the user's to fix
            raise UserError(f"--scheduler {args.scheduler}: {e}") from None
    t0 = time.monotonic()

    def progress(done: int, total: int) -> None:
        if not args.quiet:
            print(f"\rstudy {study.name}: {done}/{total} tasks, {time.monotonic() - t0:.0f} s",
                  end="", file=sys.stderr, flush=True)

    try:
        records = run_study(study, base, checkpoint, client=client, worker_setup=worker_setup,
                            progress=progress)
    finally:
        if client is not None:
            client.close()
    if not args.quiet:
        print(file=sys.stderr)
    summary = summarise(study, records)
    summary["wall_s"] = round(time.monotonic() - t0, 1)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if out_dir:
        from adaptive_cal.study.figures import write_summary

        write_summary(study, summary, records, base, out_dir)
    if args.doc:
        write_doc(Path(args.doc), study, summary, study_file=args.study, json_file=args.json,
                  out_dir=args.out or str(out_json.parent), base=base,
                  plates_arg=f"--plates {args.plates}" if args.plates else "")
    print(table(summary))
    return 0
