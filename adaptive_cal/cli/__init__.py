"""``adaptive-cal``: the command line. Each subcommand lives in its own module that provides
``add_arguments(parser)`` and ``command(args) -> int``; this file only dispatches.

Errors go to stderr with a non-zero exit and no traceback unless ``--debug``. Building the parser
imports every command module, so those import only the standard library at their top level: the
heavy engine loads inside ``command(args)``, and ``--help`` stays fast (tests/test_cli_help.py,
benchmarks/bench_cli_help.py). ``main`` is the one place that sets process-wide switches (BLAS
threads, JAX x64), and only once a command runs.

Ctrl-C ends every command with "interrupted" and status 130 wherever it lands: before the command
starts, inside jaxlib's native import (held back until it is done), in a garbage-collector
callback (delivered again), wrapped by Python in another error; an interrupted command line
then leaves without the interpreter's teardown (``_leave_now``). ``run`` finishes its touch
first and ``emulate`` ends on it with 0, as they say.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from adaptive_cal import __version__
from adaptive_cal.cli.common import DefaultsShown, UserError

# name -> (module, one-line help)
SUBCOMMANDS = {
    "explain": ("adaptive_cal.cli.explain", "where simulation and recordings differ: the physics left out"),
    "run": ("adaptive_cal.cli.run", "map a workplane: plan touches, drive the cell, stop at the bound"),
    "flatness": ("adaptive_cal.cli.flatness", "flatness and tilt correction of a recording"),
    "emulate": ("adaptive_cal.cli.emulate", "serve an emulated cell (HSES, Modbus PLC, gauge) on loopback"),
    "study": ("adaptive_cal.cli.study", "simulation studies: strategies on synthetic plates, lower bound, Dask"),
    "report": ("adaptive_cal.cli.report", "one self-contained HTML page of a run folder, for whoever adjusts the robot"),
    "compensate": ("adaptive_cal.cli.compensate", "apply a run's map to a toolpath (G-code or CSV), or export it on a grid"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command (``only``: just that command's options are loaded, the others
    are listed by name and help line -- what ``main`` uses, so one help imports one module)."""
    parser = argparse.ArgumentParser(
        prog="adaptive-cal",
        description="Plans and runs probe measurements on robot cells (mm, s, deg throughout).")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"adaptive-cal {__version__}",
                        help="the version (result.json and recordings carry it too)")
    sub = parser.add_subparsers(dest="subcommand", metavar="COMMAND")
    for name, (module, help_) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_,
                           formatter_class=DefaultsShown)
        p.set_defaults(_module=module)
        if only is None or only == name:
            importlib.import_module(module).add_arguments(p)
            for action in p._actions:  # an option with a value, given twice, is refused
                if type(action) is argparse._StoreAction and action.option_strings:
                    action.__class__ = _Once
    return parser


class _Once(argparse._StoreAction):
    """An option that takes a value refuses a second one (argparse keeps the last: `run --robot
    a.yaml ... --robot b.yaml` ran b.yaml without a word)."""

    def __call__(self, parser, namespace, values, option_string=None):
        seen = namespace.__dict__.setdefault("_given", {})
        if self.dest in seen:
            parser.error(f"{option_string} given twice ({seen[self.dest]}, then {values}): give "
                         "it once")
        seen[self.dest] = values
        super().__call__(parser, namespace, values, option_string)


def _chosen(argv: list[str]) -> str:
    """The command named on the line ('' for none): the first word that is not an option."""
    words = [a for a in argv if not a.startswith("-")]
    return words[0] if words else ""


def main(argv: list[str] | None = None) -> int:
    code = _guarded(argv)
    if code == 130 and argv is None:  # this process's own command line, interrupted
        _leave_now(code)
    return code


def _guarded(argv: list[str] | None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # before the command started (the parser, the imports)
        pass
    except Exception as e:
        if not _by_ctrl_c(e):  # else the same, wrapped by Python in a class body's __set_name__
            raise
    print("adaptive-cal: interrupted", file=sys.stderr)
    return 130


def _leave_now(code: int) -> None:
    """End an interrupted command without the interpreter's teardown, once everything it wrote
    is closed (the recording row by row, the results whole) and stdout / stderr are flushed.
    XLA's threads, stopped mid-work by the Ctrl-C, crashed that teardown: a segmentation fault
    (status -11) after "interrupted", in 2 of 40 Ctrl-Cs during a run on a loaded 2-core machine
    (0 of 60 without the teardown); a late Ctrl-C there killed the process too (status -2). A
    caller's ``main([...])`` returns as always."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # a closed pipe, a closed stream
            pass
    os._exit(code)


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--debug" in argv[1:]:  # `adaptive-cal run ... --debug` as well as `adaptive-cal --debug run`
        argv = ["--debug"] + [a for a in argv if a != "--debug"]
    parser = build_parser(only=_chosen(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "_module", None):
        parser.print_help()
        return 2
    # Our matrices are small (K <= ~500): one BLAS thread is fastest, and a threaded OpenBLAS
    # that spins against other processes on a shared 2-core machine is 100x slower. Set before
    # numpy loads (the command modules import it inside command(), below).
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # JAX in float64, without loading JAX for the commands that never use it (explain loads in
    # about half the time without it): JAX reads this when it is first imported
    os.environ["JAX_ENABLE_X64"] = "True"
    if "jax" in sys.modules:
        sys.modules["jax"].config.update("jax_enable_x64", True)
    # a stale matplotlib font cache makes every figure log "findfont: ... not found" by the
    # dozen on stderr (the fallback font is used): noise around what the command says
    import logging

    logging.getLogger("matplotlib.font_manager").setLevel(logging.ERROR)
    # pymodbus logs each failed reconnect ("Connection to ... failed", "Repeating....") between
    # the adapter's own lines, which say what failed and what to do (an outside audit)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    from adaptive_cal.hardware.base import AdapterError
    from adaptive_cal.cell.schema import ConfigError
    from adaptive_cal.formats.recording import RecordingError

    if args.subcommand in JAX_COMMANDS:
        from adaptive_cal.cli import jax_cache

        jax_cache.enable()  # what an earlier command compiled is loaded, not compiled again
        if "jax" not in sys.modules:
            _import_ctrl_c_held("jax")
    kept = _KeptCtrlC()
    try:
        with kept:
            return int(importlib.import_module(args._module).command(args) or 0)
    except (UserError, ConfigError, RecordingError, AdapterError, FileNotFoundError,
            FileExistsError, PermissionError, NotADirectoryError, IsADirectoryError,
            ValueError) as e:
        if args.debug:
            raise
        notes = "".join(f"\n  {n}" for n in getattr(e, "__notes__", ()))
        print(f"adaptive-cal {args.subcommand}: error: {_said(e)}{notes}", file=sys.stderr)
        return 130 if getattr(e, "interrupted", False) else 2
    except KeyboardInterrupt:
        return _interrupted(args)
    except BrokenPipeError:  # the reader of stdout left (`| head`): not an error of ours
        try:  # nothing more reaches the closed pipe, not even Python's flush at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return 0
    except OSError as e:  # a disk full, a device gone: the system's words, not an internal error
        if args.debug:
            raise
        print(f"adaptive-cal {args.subcommand}: error: {_said(e)}", file=sys.stderr)
        return 2
    except Exception as e:  # a bug, not bad input: still no traceback unless --debug
        if _by_ctrl_c(e):  # a Ctrl-C that landed inside an import or a descriptor's set-up
            return _interrupted(args)
        if args.debug:
            raise
        print(f"adaptive-cal {args.subcommand}: internal error: {type(e).__name__}: {e} "
              "(run again with --debug for the traceback, and please report it)", file=sys.stderr)
        return 1


#: the commands that load JAX (explain and emulate do not: they start faster without it)
JAX_COMMANDS = ("run", "flatness", "report", "study", "compensate")


def _import_ctrl_c_held(name: str) -> None:
    """Import ``name`` with SIGINT held back by the OS: a Ctrl-C inside jaxlib's native import
    aborted the process ("terminate called after throwing an instance of
    'nanobind::python_error'", status -6). Held, it arrives once the import is done, as an
    ordinary KeyboardInterrupt (at most the import's second later)."""
    import signal

    try:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    except (AttributeError, OSError, ValueError):  # no POSIX signal masks here
        importlib.import_module(name)
        return
    try:
        importlib.import_module(name)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


class _KeptCtrlC:
    """While a command runs, ``sys.unraisablehook``: a Ctrl-C that lands in a garbage-collector
    callback (XLA's) cannot be raised there -- Python printed "Exception ignored ...
    KeyboardInterrupt" and went on, and `report` wrote its page with exit status 0 as if no one
    had pressed it. Such a Ctrl-C is delivered again to the main thread once it has left the
    callback (a timer thread's ``interrupt_main``), where it stops the command as any Ctrl-C
    does; a command that ends normally after one was lost ends as interrupted. Other
    unraisable errors go to the hook that was there."""

    TRIES = 5  # deliveries again, should one land in a callback too

    def __enter__(self):
        self.previous, sys.unraisablehook = sys.unraisablehook, self
        self.lost, self.timer, self.tries = 0, None, 0
        return self

    def __exit__(self, kind, value, tb) -> None:
        sys.unraisablehook = self.previous
        if self.timer is not None:
            self.timer.cancel()
            self.timer.join()
        if self.lost and kind is None:
            raise KeyboardInterrupt  # the command ran on past a Ctrl-C: it was interrupted

    def __call__(self, unraisable) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            self.previous(unraisable)
            return
        self.lost += 1
        if self.tries < self.TRIES and (self.timer is None or not self.timer.is_alive()):
            import _thread  # raised here it would be lost again: from outside, a moment on
            import threading

            self.tries += 1
            self.timer = threading.Timer(0.05, _thread.interrupt_main)
            self.timer.daemon = True
            self.timer.start()


def _interrupted(args) -> int:
    """Ctrl-C: say so (for run, where the touches are kept and how to go on); exit 130."""
    out = getattr(args, "out", None) or getattr(args, "resume", None)
    from adaptive_cal.report.status import quoted

    kept = (f"; the touches taken are kept in {out}/recording.csv: adaptive-cal run --resume "
            f"{quoted(out)} continues it" if args.subcommand == "run" and out
            and os.path.isfile(os.path.join(out, "recording.csv")) else "")
    print(f"adaptive-cal {args.subcommand}: interrupted{kept}", file=sys.stderr)
    return 130


def _by_ctrl_c(e: BaseException) -> bool:
    """Whether ``e`` was raised while a KeyboardInterrupt was handled, or from one: Python wraps
    a Ctrl-C that lands in a class body's __set_name__ (matplotlib's import) in a RuntimeError,
    which is no bug of ours to report."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _said(e: BaseException) -> str:
    """An error as the user reads it: an OS error on a path given as "PATH: what is wrong", the
    path named first ("[Errno 17] File exists: 'out'" says neither that 'out' is a file nor that
    a folder was wanted); everything else as its own message."""
    name = getattr(e, "filename", None)
    if not isinstance(e, OSError) or name is None or not e.strerror:
        return str(e)
    if isinstance(e, FileExistsError) and os.path.isfile(name):
        return f"{name}: a file is in the way where a folder is needed"
    if isinstance(e, NotADirectoryError):
        return f"{name}: part of this path is a file, not a folder"
    return f"{name}: {e.strerror}"
