"""``adaptive-cal study STUDY.yaml --json OUT.json [--out DIR] [--scheduler ADDRESS]``: the same
synthetic plates under every strategy, a lower bound on touches, tables and plots.

Plates finished are appended to DIR/plates.jsonl (or OUT.json's name + .plates.jsonl) as they
finish; an interrupted study (Ctrl-C, SIGTERM, a kill) keeps them and a rerun skips them; a
second study on the same checkpoint is refused while the first runs. Progress goes to stderr
(a start line, then runs finished with the time taken and a rough time left), the table to
stdout. The work is the library's (``adaptive_cal.study``); this module parses arguments,
prepares Dask workers and reports progress.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from adaptive_cal.cli.common import at_least
from adaptive_cal.formats.numbers import count


def add_arguments(p) -> None:
    p.add_argument("study", help="study file (YAML), e.g. configs/study-tilts.yaml")
    p.add_argument("--json", required=True, metavar="OUT.json",
                   help="summary (JSON); without --out the per-plate records go beside it, to "
                   "OUT.json.plates.jsonl")
    p.add_argument("--out", metavar="DIR",
                   help="per-plate records (DIR/plates.jsonl), table (DIR/table.md) and plots")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:port); workers need OPENBLAS_NUM_THREADS=1")
    p.add_argument("--workers", type=at_least(0), default=0,
                   help="run on a Dask LocalCluster of N worker processes (0: in-process)")
    p.add_argument("--plates", type=at_least(1),
                   help="override the study's number of plates (at least 1)")
    p.add_argument("--strategies", help="override the study's strategies (comma separated)")
    p.add_argument("--doc", metavar="PAGE.md", help="write the study page (docs/study.md)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one study key, e.g. --set bound.true_rms_mm=0.01 (YAML value; "
                        "a relative plate.surface_files is, as in the file, relative to STUDY)")
    p.add_argument("--reuse-records", action="store_true",
                   help="keep finished runs the checkpoint holds from other code (refused "
                        "without it); the summary and the page say how many")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


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


def _duration(s: float) -> str:
    """Seconds as a person reads them: "45 s", "12 min", "2.5 h"."""
    if s < 90:
        return f"{s:.0f} s"
    if s < 90 * 60:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


class Progress:
    """A study's progress on ``stream`` (stderr): the start line at once, then the runs (one
    strategy on one plate) finished with the time taken and a rough time left, from the mean time
    a run has taken so far -- once ``per_plate`` runs (a plate's strategies) are done: the first
    run alone may be the quickest strategy (2 s of a grid read "about 32 min left" for hours).
    A terminal gets one line rewritten, a log one line a report."""

    def __init__(self, name: str, runs: int, checkpoint: Path, stream=None,
                 clock=time.monotonic, per_plate: int = 1):
        self.name, self.runs, self.checkpoint = name, runs, checkpoint
        self.per_plate = per_plate
        self.stream = sys.stderr if stream is None else stream
        self.clock = clock
        self.t0 = self.t_run = clock()
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.open = False  # a terminal line not yet ended

    def say(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    def __call__(self, done: int, total: int) -> None:
        now = self.clock()
        if done == 0:  # the runs are about to start: those the checkpoint holds are skipped
            self.t_run = now
            if total < self.runs:
                self.say(f"study {self.name}: {self.runs - total} of {count(self.runs, 'run')} "
                         f"already in {self.checkpoint}, {total} to run")
            return
        text = (f"study {self.name}: {done}/{count(total, 'run')} done, "
                f"{_duration(now - self.t0)}")
        if done < min(self.per_plate, total):
            text += ", time left once a plate's strategies are done"
        elif done < total:
            text += f", about {_duration((now - self.t_run) / done * (total - done))} left"
        if self.tty:
            print("\r" + text.ljust(72), end="" if done < total else "\n", file=self.stream,
                  flush=True)
            self.open = done < total
        else:
            self.say(text)

    def close(self) -> None:
        """End a terminal line left open (an interrupted study)."""
        if self.open:
            print(file=self.stream, flush=True)
            self.open = False


def _command(args) -> str:
    """The command line that ran this study, as a page shows it to run again (paths quoted
    for a shell where they need it; --quiet, which changes nothing written, left out)."""
    from shlex import quote

    words = ["adaptive-cal study", quote(args.study), "--json", quote(args.json)]
    for option, value in (("--out", args.out), ("--doc", args.doc), ("--plates", args.plates),
                          ("--strategies", args.strategies), ("--scheduler", args.scheduler),
                          ("--workers", args.workers or None)):
        if value is not None:
            words += [option, quote(str(value))]
    for item in args.set:
        words += ["--set", quote(item)]
    if getattr(args, "reuse_records", False):
        words.append("--reuse-records")
    return "OPENBLAS_NUM_THREADS=1 " + " ".join(words)


def _kept(checkpoint: Path, study, base) -> int:
    """The plate runs this study's checkpoint holds (0 where it cannot be read)."""
    from adaptive_cal.study.checkpoint import legacy_key, read_checkpoint, study_key

    try:  # the plates this study runs, not those of a longer study before it
        return sum(r["plate"] < study.plates for r in read_checkpoint(
            checkpoint, study_key(study, base), also=(legacy_key(study, base),)))
    except (OSError, ValueError):  # UnicodeDecodeError and JSON errors are ValueErrors
        return 0


def _code(records: list[dict]) -> dict:
    """Which code made the records: this code's fingerprint and how many runs were another's."""
    from adaptive_cal.study.checkpoint import code_fingerprint, other_code

    return {"fingerprint": code_fingerprint(), "runs": len(records),
            "runs_by_other_code": len(other_code(records))}


def _where(args) -> str:
    if args.scheduler:
        return f"on the Dask scheduler at {args.scheduler}"
    if args.workers:
        return f"on {count(args.workers, 'worker')} (Dask LocalCluster)"
    return "in this process (1 worker)"


#: what a study writes into --out (study.figures.write_summary and its checkpoint)
OUT_FILES = ("plates.jsonl", "plates.jsonl.lock", "table.md", "touches_vs_bound.png",
             "coverage.png", "example_plate.png")


def _check_outputs(args, study, checkpoint: Path) -> None:
    """Before any plate runs: --json and --doc overwrite neither the study file, its cell file,
    the checkpoint nor each other, and each can be written (its folder is not a file)."""
    from adaptive_cal.cli.common import UserError, check_writable, refuse_input_as_output

    if args.doc and not args.out:
        raise UserError(f"--doc {args.doc} needs --out DIR: the page links the table and the "
                        "figures the study writes there")
    inputs = [args.study, checkpoint]
    if isinstance(study.cell, str):
        from adaptive_cal.study.config import cell_path

        inputs.append(cell_path(study.cell, args.study))
    outs = [("--json", args.json)] + ([("--doc", args.doc)] if args.doc else [])
    for option, out in outs:
        refuse_input_as_output(option, out, inputs)
        if Path(out).is_dir():
            raise UserError(f"{option} {out}: a folder; give a file name")
        check_writable(option, out)  # its folder is a folder, and takes a file
    if args.out:  # the files the study writes into --out
        written = {(Path(args.out) / n).absolute(): n for n in OUT_FILES}
        for option, out in outs:
            if Path(out).absolute() in written:
                raise UserError(f"{option} {out}: the study writes its "
                                f"{written[Path(out).absolute()]} there (--out {args.out}); give "
                                "another file")
    out = Path(args.json)
    if out.is_file() and out.stat().st_size:
        try:
            earlier = json.loads(out.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError):
            earlier = None
        if not (isinstance(earlier, dict) and {"strategies", "bound"} <= earlier.keys()):
            raise UserError(f"--json {out}: exists and is not an earlier study's --json: it is "
                            "left as it is; give another file")
    if args.doc and Path(args.doc).absolute() == Path(args.json).absolute():
        raise UserError(f"--doc {args.doc} is --json {args.json}: give two files")


def ignored(study) -> list[str]:
    """The study's settings that change nothing, one line each: the drawn plate's keys where
    plate.surface_files gives the plates (an outside audit: ignored without a word). (A lower
    bound without the adaptive strategy says why in the summary's ``lower_bound.why_none``.)"""
    from adaptive_cal.study.config import PlateDistribution

    out = []
    plate, default = study.plate, PlateDistribution()
    if plate.surface_files is not None:
        drawn = [k for k in ("tilt_deg", "offset_mm", "form_pv_mm", "form_shapes")
                 if getattr(plate, k) != getattr(default, k)]
        if drawn:
            out.append(", ".join(f"plate.{k}" for k in drawn) + " not used: "
                       "plate.surface_files gives the plates (each map with the base cell's "
                       "simulation.effects on top)")
    return out


class _sigterm_as_ctrl_c:
    """SIGTERM (a service manager, a timeout) stops the study as Ctrl-C does: the runs finished
    are said to be kept (an outside audit: SIGTERM exited 143 without a word)."""

    def __enter__(self):
        import signal

        def stop(signum, frame):
            raise KeyboardInterrupt

        try:
            self.old = signal.signal(signal.SIGTERM, stop)
        except ValueError:  # not the main thread: leave SIGTERM as it is
            self.old = None
        return self

    def __exit__(self, *exc):
        import signal

        if self.old is not None:
            signal.signal(signal.SIGTERM, self.old)
        return False


def command(args) -> int:
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.doc import write_doc
    from adaptive_cal.study.overrides import apply_overrides
    from adaptive_cal.study.runner import connect, run_study
    from adaptive_cal.study.summary import summarise, table

    from adaptive_cal.cell.schema import ConfigError
    from adaptive_cal.study.overrides import check_command_line, edited

    check_command_line(args.plates, args.strategies)
    try:
        study, base = load_study(args.study)
    except ConfigError as error:  # a --set may mend what the file has wrong
        if not (args.set or args.plates or args.strategies):
            raise
        try:
            study, base = load_study(args.study, edit=lambda d: edited(
                d, plates=args.plates, strategies=args.strategies, settings=args.set))
        except ConfigError as again:  # not mended: the file's error, or what the change broke
            if str(again) == str(error):
                raise error from None
            changed = [i.partition("=")[0].strip() for i in args.set] + [
                k for k, v in (("plates", args.plates), ("strategies", args.strategies)) if v]
            whose = ("with the command line's changes" if any(k in str(again) for k in changed)
                     else "in the file, the command line's changes applied")
            raise ConfigError(f"{again} ({whose})") from None
    study = apply_overrides(study, base, plates=args.plates, strategies=args.strategies,
                            settings=args.set, study_path=args.study)
    out_json = Path(args.json)
    out_dir = Path(args.out) if args.out else None
    checkpoint = (out_dir / "plates.jsonl" if out_dir
                  else out_json.with_name(out_json.name + ".plates.jsonl"))
    _check_outputs(args, study, checkpoint)
    for line in ignored(study):
        print(f"warning: {line}", file=sys.stderr)
    runs = study.plates * len(study.strategies)
    progress = Progress(study.name, runs, checkpoint, per_plate=len(study.strategies))
    if not args.quiet:
        progress.say(f"study {study.name}: {count(study.plates, 'plate')} x "
                     f"{count(len(study.strategies), 'strategy', 'strategies')} = "
                     f"{count(runs, 'run')} {_where(args)}")
    client = None
    if args.scheduler or args.workers:
        from adaptive_cal.cli.common import UserError
        from adaptive_cal.study.runner import SchedulerError

        try:
            client = connect(args.scheduler, max(args.workers, 1))
        except SchedulerError as e:  # the address wrong or down, no Dask: the user's to fix
            raise UserError(f"--scheduler {args.scheduler}: {e}" if args.scheduler and
                            "lacks" not in str(e) else str(e)) from None
    try:
        with _sigterm_as_ctrl_c():
            records = run_study(study, base, checkpoint, client=client,
                                worker_setup=worker_setup,
                                progress=None if args.quiet else progress,
                                warn=lambda text: print(f"warning: {text}", file=sys.stderr),
                                reuse=args.reuse_records)
    except KeyboardInterrupt:
        progress.close()
        kept = _kept(checkpoint, study, base)
        progress.say(f"{count(kept, 'run')} finished, kept in {checkpoint}: the same command "
                     "again runs only the rest" if kept else
                     "no run had finished: nothing kept, the same command again starts over")
        raise
    finally:
        progress.close()
        if client is not None:
            client.close()
    summary = summarise(study, records)
    summary["code"] = _code(records)
    if summary["code"]["runs_by_other_code"]:  # kept on purpose, or made by workers of other code
        how = ("kept from other code (--reuse-records)" if args.reuse_records else
               "made by Dask workers running other code than this (install the same "
               "adaptive-cal and numerics libraries on every worker)")
        print(f"warning: {summary['code']['runs_by_other_code']} of {count(len(records), 'run')} "
              f"{how}: not this code's measurement", file=sys.stderr)
    summary["wall_s"] = round(time.monotonic() - progress.t0, 1)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    from adaptive_cal.formats.writing import provenance
    from adaptive_cal.run.folder import write_json

    summary.update(provenance())  # which code made these figures, and when

    write_json(out_json, summary)  # atomic; an infinite figure (no bound in the budget) as null
    if out_dir:
        from adaptive_cal.study.figures import write_summary

        write_summary(study, summary, records, base, out_dir)
    if args.doc:
        write_doc(Path(args.doc), study, summary, study_file=args.study,
                  out_dir=args.out or str(out_json.parent), base=base, command=_command(args))
    print(table(summary))
    return 0
