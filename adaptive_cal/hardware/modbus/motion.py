"""Motion through PLC data registers (``ModbusMotion``), above a ``ModbusLink`` (``adapter``).

One move: the PC writes target_x/y/z and reads them back (a register that does not hold what
was written refuses the move: start is never set), clears ``done`` and checks that it stays off,
sets ``start``, waits for ``done``, clears ``start`` -- also when the wait ends any other way.

Where the robot stands before the first move: read from ``actual_x/y/z`` where the register map
has them (the probe cycle then lifts straight up at the current x, y before it travels);
without them the first move is refused unless the cell file states that the robot starts
parked at or above the safe height (``parked_at_safe_height``).
"""
from __future__ import annotations

import logging
import math

from adaptive_cal.hardware.base import AdapterError

log = logging.getLogger(__name__)
TARGETS = ("target_x", "target_y", "target_z")
ACTUALS = ("actual_x", "actual_y", "actual_z")
ACTUAL_SETTLE_S = 0.3  # the job's 0.1 s position loop and a few PLC scans (``_check_arrived``)


class ModbusMotion:
    """Motion through PLC data registers and the start/done handshake (hw/plc-register-map.md)."""

    def __init__(self, link):
        self.link, self.pose = link, (math.nan, math.nan, math.nan)
        self.started = False  # no move started yet on this connection
        self.unfinished: str | None = None  # how the last move ended, where not in its done
        # a new connection's first done may end a move an earlier one left running (a Ctrl-C,
        # then --resume): believed, as after an unfinished move, only where actual_x/y/z agree
        self.first_done_checked = "actual_x" not in link.map
        self.read_first = None  # actual_x/y/z before the first move (``_first_move_allowed``)

    def move_to(self, x_mm: float, y_mm: float, z_mm: float) -> None:
        k = self.link
        k.check_fault()
        if not self.started:
            self._first_move_allowed((x_mm, y_mm, z_mm))
        if self.unfinished and "actual_x" not in k.map:
            self._refuse_after_unfinished((x_mm, y_mm, z_mm))
        self._write_target((x_mm, y_mm, z_mm))
        k.write_bit("start", False)  # one left set (a clear that failed) would give no edge:
        k.write_bit("done", False)   # it is off for the settle below, a scan or more
        self._done_stays_off()  # before start: a 'done' that is not ours would end the wait
        self.pose = (math.nan,) * 3  # unknown from the moment start is set until done
        self.started = True
        k.write_bit("start", True)
        try:
            start = k.clock()
            while True:
                k.check_fault()
                if k.read_bit("done"):
                    k.write_bit("start", False)
                    if self.unfinished or not self.first_done_checked:  # a stopped move's?
                        self._check_arrived((x_mm, y_mm, z_mm))
                    self.pose, self.unfinished = (x_mm, y_mm, z_mm), None
                    self.first_done_checked = True
                    return
                if k.clock() - start >= k.cfg.move_timeout_s:
                    raise AdapterError(
                        f"{k.where}: no 'done' ({k.map['done'].name}) within "
                        f"move_timeout_s={k.cfg.move_timeout_s} s; check the robot job")
                k.sleep(k.cfg.poll_s)
        except BaseException as err:  # fault, timeout, lost link, Ctrl-C: start must not stay set
            self.unfinished = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
            self._drop_start(err)
            raise

    def _refuse_after_unfinished(self, target) -> None:
        """The last move ended without its done (Ctrl-C, a timeout, a fault): the job may still
        be in it -- ACAL_TOUCH reads start only between moves -- and the PLC latches done when
        it ends, which the next wait would take for its own: an outside audit's retract after a
        stopped approach was reported done with the tip still down. Without actual_x/y/z to
        tell, raise before anything is written."""
        k = self.link
        raise AdapterError(
            f"{k.where}: the last move ended without 'done' ({k.map['done'].name}) "
            f"({self.unfinished}); the robot job may still be running it, and the PLC's next "
            f"'done' could be that move's: the move to x={target[0]:.3f} y={target[1]:.3f} "
            f"z={target[2]:.3f} mm was not sent. See where the robot stands and let its job "
            "finish or stop it at the pendant before continuing (mapping actual_x/y/z lets the "
            "PC check where the robot stands itself: hw/plc-register-map.md)")

    def _check_arrived(self, target, tol_mm: float = 1.0) -> None:
        """After a move that ended without done, and on a connection's first move, the next
        done is believed only where the PLC's actual_x/y/z put the robot at the target (within
        ``tol_mm``), read ``ACTUAL_SETTLE_S`` after it: the job writes where it stands only while
        it waits for start (every 0.1 s, hw/ACAL_TOUCH.JBI), so right at the done they can still
        hold where the stopped move began -- an audit's peer PLC read the safe height there with
        the tip down. A first move's done can be the end of a move an earlier connection left
        running (a Ctrl-C, then --resume): the job ignores a start while it moves."""
        k = self.link
        self.pose = (math.nan,) * 3
        k.sleep(max(ACTUAL_SETTLE_S, 3 * k.cfg.scan_s))
        here = self.position()
        if not all(abs(a - b) <= tol_mm for a, b in zip(here, target)):
            whose = (f"the stopped move's done ({self.unfinished})" if self.unfinished else
                     "the done of a move the job was still in when this connection began (an "
                     "earlier run stopped during a move?); this move's start went unseen")
            if not self.unfinished and here == self.read_first:
                whose = ("they read the same before the move and after it: either nobody "
                         "writes them (a register nobody writes reads 0; map them only once the "
                         "job and the ladder write them, hw/plc-register-map.md) or this 'done' "
                         "was " + whose)
            else:
                whose = "it was " + whose
            raise AdapterError(
                f"{k.where}: 'done' ({k.map['done'].name}) came, but actual_x/y/z put the robot "
                f"at {tuple(round(v, 3) for v in here)} mm, not at the target "
                f"{tuple(round(v, 3) for v in target)} mm: {whose}. See where the robot "
                "stands before continuing")

    def _write_target(self, xyz: tuple[float, float, float]) -> None:
        """Write the three target registers, then read them back: each must hold the very words
        written. A PLC program, HMI or gateway that writes them too (or maps them elsewhere)
        would have the robot go to a target the PC never checked. Raise before ``start``.

        Equal words do not prove the word order: the PLC stores the words as sent, whatever
        order it reads them in (docs/adapters/modbus.md, commissioning)."""
        k = self.link
        sent = {role: k.to_words(role, v) for role, v in zip(TARGETS, xyz)}  # all fit, or none
        for role, words in sent.items():
            k.write_words(role, words)
        for role, words in sent.items():
            got = k.read_words(role, len(words))
            if list(got) != list(words):
                raise AdapterError(
                    f"{k.where}: {role} ({k.map[role].name}) reads back "
                    f"{k.from_words(got):.4f} mm (registers {got}) after the PC wrote "
                    f"{k.from_words(words):.4f} mm (registers {words}); start "
                    f"({k.map['start'].name}) was not set and nothing moved. Something else "
                    "writes the target registers (a ladder rung, an HMI screen, a gateway "
                    "mapping): check robot.modbus.registers against the PLC program")

    def _done_stays_off(self) -> None:
        """``done`` must read off, and stay off for done_settle_s (several PLC scans), after the
        PC cleared it: a PLC that copies the robot's output into it (the job keeps OT#(1) on until
        the next start) would end the next wait before the robot moves. Raise before start."""
        k = self.link
        settle = max(k.cfg.done_settle_s, k.cfg.scan_s)  # start, cleared with done: off a scan too
        t0 = k.clock()
        while True:
            if k.read_bit("done"):
                a, s = k.map["done"].name, k.map["start"].name
                if self.unfinished or not self.first_done_checked:
                    self._late_done(a, s)
                raise AdapterError(
                    f"{k.where}: 'done' ({a}) is set again after the PC cleared it; start ({s}) "
                    "was not set and nothing moved. The PLC must latch done when the robot "
                    "finishes and leave clearing it to the PC (hw/plc-register-map.md, "
                    "handshake); it must not copy the robot's done output into it")
            if k.clock() - t0 >= settle:
                return
            k.sleep(min(k.cfg.poll_s, settle))

    def _late_done(self, done: str, start: str) -> None:
        """``done`` set during the settle after a move that ended without it (two quick Ctrl-Cs
        in an approach), or on a connection's first move: most likely that move's own late done,
        not a PLC that copies the robot's output (which a third audit's message blamed)."""
        k = self.link
        whose = (f"the move stopped before ({self.unfinished})" if self.unfinished else
                 "a move the robot job was still in when this connection began (an earlier "
                 "run stopped during a move?)")
        raise AdapterError(
            f"{k.where}: 'done' ({done}) came after the PC cleared it, most likely the late done "
            f"of {whose}: the robot job may have gone on with that move. Start ({start}) was not "
            "set and nothing was sent. See where the robot stands before continuing; if this "
            "happens with no move stopped, the PLC copies the robot's done output into it "
            "(hw/plc-register-map.md, handshake)")

    def _drop_start(self, err: BaseException) -> None:
        """Clear ``start`` after a move that did not end in done; a level-triggered PLC or job
        would otherwise move the robot when the fault is cleared, with no PC involved."""
        k, s = self.link, self.link.map["start"].name
        try:
            k.write_bit("start", False)
        except Exception as e:
            msg = (f"{k.where}: START ({s}) MAY STILL BE SET: clearing it failed ({e}). Clear "
                   f"{s} at the HMI before clearing any fault, or the robot may move by itself "
                   f"when the fault clears. What stopped the move: {err}")
            if isinstance(err, AdapterError):
                raise AdapterError(msg) from err
            log.error("%s", msg)  # Ctrl-C and the like go on as they are; the danger is logged

    def _first_move_allowed(self, target: tuple[float, float, float]) -> None:
        """The first move starts from where the robot stands: known (read), or stated parked at
        the safe height in the cell file; else raise before anything is written."""
        k, here = self.link, self.position()
        self.read_first = here  # to tell registers nobody writes from a stale done (below)
        if all(map(math.isfinite, here)) or k.cfg.parked_at_safe_height:
            return
        x, y, z = target
        said = ("robot.modbus.registers maps no actual_x/actual_y/actual_z" if "actual_x" not
                in k.map else f"actual_x/y/z read {here}, not a position")
        raise AdapterError(
            f"{k.where}: the robot's position is unknown ({said}), so the first move would go "
            f"straight to x={x:.3f} y={y:.3f} z={z:.3f} mm from wherever the robot stands, "
            "perhaps across the plate; start was not set and nothing moved. Map the PLC "
            "registers the job writes its position into (robot.modbus.registers.actual_x/y/z, "
            "hw/plc-register-map.md), or park the robot at or above robot.safe_height_mm, "
            "clear of the plate and fixtures, and state that every run starts there with "
            "robot.modbus.parked_at_safe_height: true (and the same in probe.modbus)")

    def position(self) -> tuple[float, float, float]:
        """Where the tip is (mm, workplane frame): the last target reached; before the first
        move (or after a move that did not end in done) the PLC's actual_x/y/z where mapped,
        else NaN."""
        if all(map(math.isfinite, self.pose)) or "actual_x" not in self.link.map:
            return self.pose
        k = self.link
        words = [k.read_words(role, k.words) for role in ACTUALS]
        here = tuple(k.from_words(w) for w in words)
        if k.words == 2:  # commissioning aid: what the other word order would have read
            log.info("%s: the robot is at %s mm (actual_x/y/z); with the other word order it "
                     "would read %s", k.where, tuple(round(v, 4) for v in here),
                     tuple(round(k.from_words(w[::-1]), 4) for w in words))
        return here

    def close(self) -> None:
        self.link.close()
