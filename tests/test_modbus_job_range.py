"""hw/ACAL_TOUCH.JBI checks the target against a box held in the job before MOVL: a small
interpreter of the INFORM the job uses runs one move. It reads the job as written here, not as
a controller would (the job is NOT CHECKED on a controller)."""
import re
import struct

import pytest

from adaptive_cal.cell.schema import load_cell
from tests.conftest import ROOT

JOB = (ROOT / "hw" / "ACAL_TOUCH.JBI").read_text()
CELL = load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml")


def run_one_move(target_counts, here_um=(0.0, 0.0, 50_000.0), each_line=None):
    """Run the job from its first line with start (IN#(1)) on and fault (IN#(2)) off, the
    target D001..D003 in 0.1 um counts (the fieldbus copies it before start) and the robot at
    ``here_um`` (user frame 1); stop at the end of the move (WAIT IN#(1)=OFF) or at PAUSE.
    ``each_line(d, line)`` runs after every line, as the fieldbus mapping or the PLC may read
    or write the D variables between any two lines.
    Returns (how it stopped, the MOVL targets in um, the last done output, the D variables)."""
    lines = [s.strip() for s in JOB[JOB.index("//INST"):].splitlines()]
    lines = lines[lines.index("NOP") + 1:lines.index("END")]
    labels = {s: i for i, s in enumerate(lines) if s.startswith("*")}
    d = {f"D{n:03d}": 0 for n in range(100)}
    d.update(D001=target_counts[0], D002=target_counts[1], D003=target_counts[2])
    inputs, p001, moves, done, px = {1: True, 2: False}, [0.0] * 3, [], None, {}
    pc = 0
    while pc < len(lines):
        s, pc = lines[pc], pc + 1
        if each_line is not None:
            each_line(d, lines[pc - 2] if pc > 1 else "")  # after the line before this one
        if not s or s.startswith(("'", "*")) or s.startswith("TIMER T="):
            continue
        if s == "WAIT IN#(1)=OFF":
            return "done", moves, done, d
        if s == "PAUSE":
            return "paused", moves, done, d
        if m := re.fullmatch(r"SET (D\d{3}) (-?\d+)", s):
            d[m.group(1)] = int(m.group(2))
        elif m := re.fullmatch(r"SET (D\d{3}) (D\d{3})", s):
            d[m.group(1)] = d[m.group(2)]
        elif m := re.fullmatch(r"(DIV|MUL) (D\d{3}) (\d+)", s):
            a, k = d[m.group(2)], int(m.group(3))
            d[m.group(2)] = int(a / k) if m.group(1) == "DIV" else a * k  # DIV: towards zero
        elif m := re.fullmatch(r"SETE P001 \((\d)\) (D\d{3})", s):
            p001[int(m.group(1)) - 1] = d[m.group(2)]
        elif m := re.fullmatch(r"GETS PX(\d{3}) \$PX000", s):
            px[m.group(1)] = "pulses"
        elif m := re.fullmatch(r"CNVRT PX(\d{3}) PX(\d{3}) UF#\(1\)", s):
            assert px[m.group(2)] == "pulses"
            px[m.group(1)] = here_um  # the current position, XYZ in user frame 1 (um)
        elif m := re.fullmatch(r"GETE (D\d{3}) P(\d{3}) \((\d)\)", s):
            d[m.group(1)] = round(px[m.group(2)][int(m.group(3)) - 1])
        elif s.startswith("MOVL P001"):
            moves.append(tuple(p001))
        elif m := re.fullmatch(r"DOUT OT#\(1\) (ON|OFF)", s):
            done = m.group(1) == "ON"
        elif m := re.fullmatch(r"JUMP (\*\w+) IF IN#\((\d)\)=(ON|OFF)", s):
            if inputs[int(m.group(2))] == (m.group(3) == "ON"):
                pc = labels[m.group(1)]
        elif m := re.fullmatch(r"JUMP (\*\w+) IF (D\d{3})([<>])(D\d{3})", s):
            a, b = d[m.group(2)], d[m.group(4)]
            if (a < b) if m.group(3) == "<" else (a > b):
                pc = labels[m.group(1)]
        elif m := re.fullmatch(r"JUMP (\*\w+)", s):
            pc = labels[m.group(1)]
        else:
            raise AssertionError(f"the test's interpreter does not know {s!r}")
    raise AssertionError("ran off the end of the job")


def box_counts():
    ws, scale = CELL.workspace, CELL.robot.modbus.scale
    return [(round(lo * scale), round(hi * scale)) for lo, hi in (ws.x_mm, ws.y_mm, ws.z_mm)]


def test_a_target_inside_the_box_moves():
    how, moves, done, _ = run_one_move((1_000_000, -1_850_000, 150_000))
    assert how == "done" and moves == [(100_000, -185_000, 15_000)] and done  # um


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("side", [0, 1])
def test_a_target_outside_the_box_faults_before_movl(axis, side):
    target = [0, 0, 150_000]
    lo, hi = box_counts()[axis]
    target[axis] = (lo - 1) if side == 0 else (hi + 1)
    how, moves, done, _ = run_one_move(tuple(target))
    assert how == "paused" and moves == [] and not done
    target[axis] = lo if side == 0 else hi  # the edge itself is inside
    assert run_one_move(tuple(target))[0] == "done"


def test_a_swapped_word_order_that_lands_outside_the_box_does_not_move():
    """z = -0.001 mm written low word first ([0xFFF6, 0xFFFF]) and read high word first is
    -589825 counts (-59 mm): below the box's z, so the job faults instead of going there.
    (An x or y that small swaps to a value inside a +-230 mm box: the commissioning check in
    docs/adapters/modbus.md is what finds those.)"""
    swapped = struct.unpack(">i", struct.pack(">HH", 0xFFF6, 0xFFFF))[0]
    assert swapped == -589825
    how, moves, _, _ = run_one_move((0, 0, swapped))
    assert how == "paused" and moves == []


def test_the_jobs_box_is_the_emulated_cells_workspace():
    """The example values in the job are the emulated cell's workspace x scale; a cell of its
    own sets its own (hw/README.md says how)."""
    sets = dict(re.findall(r"^SET (D02[1-6]) (-?\d+)$", JOB, re.M))
    got = [(int(sets[f"D02{2 * i + 1}"]), int(sets[f"D02{2 * i + 2}"])) for i in range(3)]
    assert got == box_counts()


def test_while_it_waits_the_job_writes_where_the_tip_is_in_the_targets_unit():
    """D011..D013 (the PLC's actual_x/y/z) hold the current position in 0.1 um counts, the
    unit the PC decodes with robot.modbus.scale."""
    *_, d = run_one_move((0, 0, 150_000), here_um=(120_000.0, -80_000.0, 2_000.0))
    assert (d["D011"], d["D012"], d["D013"]) == (1_200_000, -800_000, 20_000)
    assert [c / CELL.robot.modbus.scale for c in (d["D011"], d["D012"], d["D013"])] == [
        120.0, -80.0, 2.0]


def test_the_job_keeps_the_controllers_length_limits():
    """A job comment and ///COMM hold up to 32 characters (NX100 job data format): the job's
    comments said their prose in lines up to 75 long; the long form is hw/README.md now."""
    long = [s for s in JOB.splitlines()
            if (s.startswith("'") and len(s) - 1 > 32)
            or (s.startswith("///COMM ") and len(s) - len("///COMM ") > 32)]
    assert not long, long
    name = re.search(r"^//NAME (\S+)$", JOB, re.M).group(1)
    assert len(name) <= 32


def test_a_fieldbus_copy_between_any_two_lines_changes_neither_the_move_nor_its_check():
    """An outside audit (2026-11-29): the job checked D001..D003, then divided them in place
    and set P001 from them. A fieldbus mapping that copies D100.. to D001.. again between the
    DIV and the SETE sent the robot 10 x too far with the check passed; a start on registers
    already divided moved it to a tenth of the target. The job now copies the target once
    into D041..D043 and never changes D001..D003."""
    target = (1_000_000, -1_850_000, 150_000)

    def fieldbus(d, _line):  # the mapping writes D001..D003 from the PLC at any moment
        d.update(D001=target[0], D002=target[1], D003=target[2])

    how, moves, done, d = run_one_move(target, each_line=fieldbus)
    assert how == "done" and moves == [(100_000, -185_000, 15_000)] and done
    assert (d["D001"], d["D002"], d["D003"]) == target  # the input registers as written
    # a second start on the same registers moves to the same place
    assert run_one_move((d["D001"], d["D002"], d["D003"]))[1] == moves


def test_the_pc_never_reads_a_half_made_tip_position():
    """D011..D013 went through GETE (um) and MUL 10 (counts) in place: a read between the two
    decoded a tenth of where the tip is (12, -8, 0.2 mm for 120, -80, 2 mm). Each now changes
    once, from nothing to the position in counts."""
    seen = set()
    run_one_move((0, 0, 150_000), here_um=(120_000.0, -80_000.0, 2_000.0),
                 each_line=lambda d, _: seen.add((d["D011"], d["D012"], d["D013"])))
    assert seen <= {(0, 0, 0), (1_200_000, 0, 0), (1_200_000, -800_000, 0),
                    (1_200_000, -800_000, 20_000)}, seen


def test_done_stays_off_for_a_plc_scan_before_the_move():
    """A zero-length move (the retract ends where the next target starts) took OT#(1) off and
    on again within a few ms: a PLC latching done on its rising edge, scanning slower, missed
    it. The job holds done off for a TIMER first."""
    lines = [s.strip() for s in JOB[JOB.index("//INST"):].splitlines()]
    off = lines.index("DOUT OT#(1) OFF")
    nxt = next(s for s in lines[off + 1:] if s and not s.startswith("'"))
    assert re.fullmatch(r"TIMER T=0\.\d+", nxt) and float(nxt.split("=")[1]) >= 0.05
