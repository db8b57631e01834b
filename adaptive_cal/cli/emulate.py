"""``adaptive-cal emulate --robot CELL.yaml``: serve an emulated cell on loopback.

Serves the HSES controller, Modbus PLC and serial gauge that the cell file names (ports from the
file), all backed by the simulated plate of its ``simulation`` block, until Ctrl-C or
``--seconds``. Run ``adaptive-cal run --robot CELL.yaml`` against it from another shell.
"""
from __future__ import annotations

import argparse
import time

from adaptive_cal.cli.common import seconds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, metavar="CELL.yaml",
                        help="cell file whose robot/probe blocks name the loopback ports")
    parser.add_argument("--move-s", type=seconds(positive=False), default=0.02,
                        help="time every emulated move takes (s)")
    parser.add_argument("--seconds", type=seconds(positive=True), default=None,
                        help="stop after this many seconds (default: until Ctrl-C)")


def command(args: argparse.Namespace) -> int:
    from adaptive_cal.cell.schema import load_cell
    from adaptive_cal.simulation.emulator import start_emulator

    from adaptive_cal.cli.common import UserError

    cell = load_cell(args.robot)
    try:
        emu = start_emulator(cell, move_s=args.move_s)
    except OSError as e:  # a port another program (or emulator) holds
        raise UserError(f"{args.robot}: cannot serve its devices on 127.0.0.1 ({e.strerror or e}"
                        "): another emulator or program holds a port the cell file names; stop "
                        "it, or give the cell other ports") from None
    ports = ", ".join(f"{k} 127.0.0.1:{v}" for k, v in emu.ports().items())
    if not ports:  # said alone: no "emulator stopped" line before it
        emu.close()
        raise UserError(f"{args.robot}: nothing to serve -- its robot and probe are "
                        "simulated (adapter sim); emulate serves hses, modbus and serial "
                        "cells (e.g. configs/cell-hses-emulated.yaml)")
    try:
        print(f"emulating '{cell.name}': {ports} (plate seed {emu.robot.sim.sim.seed}); "
              "Ctrl-C stops", flush=True)
        end = None if args.seconds is None else time.monotonic() + args.seconds
        while end is None or time.monotonic() < end:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        emu.close()
        print(f"emulator stopped after {emu.robot.moves} moves and {emu.robot.readings} "
              "readings", flush=True)
    return 0
