"""adaptive-cal compensate: toolpath parsing and writing, splitting against a brute-force check,
refusals, the grid export, and the acceptance test on the simulated cell (the compensated
engraving follows the TRUE plate within the tolerance where the map is confident)."""
import contextlib
import io
import json
import re

import numpy as np
import pytest

from adaptive_cal.analysis import compensate as cp
from adaptive_cal.analysis import flatness as fl
from adaptive_cal.cell.build import survey_plan
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.cli import main
from adaptive_cal.formats.toolpath import ToolpathError, read_toolpath, write_toolpath
from adaptive_cal.gaussian.belief import Z95
from adaptive_cal.run import session
from adaptive_cal.run.heightmap import load_map
from adaptive_cal.simulation.cell import SimulatedCell

from helpers import ROOT, sim_cell

EXAMPLE = ROOT / "configs" / "engrave-example.gcode"
PLATE = ((-200.0, 200.0), (-150.0, 150.0))
T = 0.01

PROGRAM = """%
(header) ; two comment styles
G21 G90
G0 Z5 (safe)
G0 X-100 Y-50
G1 Z-0.1 F100
G1 X100 ; modal Y and Z
Y50
X-100 Y-50 ; diagonal
M5
G0 Z5
%
"""


def flat(mean=0.0, std=0.0):
    return lambda x, y: (np.full(np.shape(x), mean, float), np.full(np.shape(x), std, float))


def wavy(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    return 0.05 * np.sin(x / 30.0) + 1e-5 * x * y + 0.2, np.full(x.shape, 0.001)


# -- parsing and writing -------------------------------------------------------------------------

def test_gcode_round_trip_is_verbatim_and_modal_coordinates_are_resolved():
    path = read_toolpath(PROGRAM, "p")
    assert write_toolpath(path, {}) == PROGRAM
    ends = [(m.line, m.cut, m.end) for m in path.moves]
    assert ends == [(4, False, (None, None, 5.0)), (5, False, (-100.0, -50.0, 5.0)),
                    (6, True, (-100.0, -50.0, -0.1)), (7, True, (100.0, -50.0, -0.1)),
                    (8, True, (100.0, 50.0, -0.1)), (9, True, (-100.0, -50.0, -0.1)),
                    (11, False, (-100.0, -50.0, 5.0))]
    assert path.moves[3].start == (-100.0, -50.0, -0.1)


def test_zero_map_changes_only_formatting_and_keeps_every_comment():
    path = read_toolpath(PROGRAM, "p")
    res = cp.compensate(path, flat(), PLATE, T, top_mm=0.0, name="p")
    assert res.added == 0 and not res.wide
    text = write_toolpath(path, res.pieces)
    again = read_toolpath(text, "out")
    assert [m.end for m in again.moves] == [m.end for m in path.moves]
    for comment in ("(header)", "; two comment styles", "(safe)", "; modal Y and Z", "; diagonal"):
        assert comment in text
    assert "M5" in text.splitlines() and text.startswith("%\n")


def test_a_raised_map_raises_every_z_and_crlf_is_kept():
    text = PROGRAM.replace("\n", "\r\n")
    path = read_toolpath(text, "p")
    res = cp.compensate(path, flat(0.25), PLATE, T, top_mm=0.4, name="p")
    out = write_toolpath(path, res.pieces, header_comment="made by a test")
    assert "\r\n" in out and "\n" not in out.replace("\r\n", "")
    again = read_toolpath(out, "out")
    first, across, *rest = again.moves
    assert first.end[2] == pytest.approx(5.4)  # X, Y unknown yet: raised by the highest height
    # the level rapid from there goes across at that height, then down on its own
    assert across.end == pytest.approx((-100.0, -50.0, 5.4)) and not across.cut
    for a, b in zip(rest, path.moves[1:]):
        assert a.end[:2] == b.end[:2] and a.end[2] == pytest.approx(b.end[2] + 0.25)


def test_csv_round_trip_keeps_other_columns_and_inserted_rows_copy_them():
    text = "id,x_mm,y_mm,z_mm,feed\na,-100,0,-0.1,300\nb,100,0,-0.1,600\n"
    path = read_toolpath(text, "pts.csv")
    assert write_toolpath(path, {}) == text
    res = cp.compensate(path, wavy, PLATE, T, top_mm=1.0, name="pts.csv")
    assert res.added > 0
    rows = [r.split(",") for r in write_toolpath(path, res.pieces).splitlines()]
    assert rows[0] == ["id", "x_mm", "y_mm", "z_mm", "feed"]
    assert rows[1][0] == "a" and rows[-1][0] == "b" and all(r[4] == "600" for r in rows[2:])
    xs = [float(r[1]) for r in rows[1:]]
    assert xs == sorted(xs) and len(rows) == 3 + res.added


@pytest.mark.parametrize("program, words", [
    ("G20\nG0 X0 Y0 Z1\n", ["line 1", "G20", "inches"]),
    ("G91\nG0 X1\n", ["line 1", "G91", "relative"]),
    ("G0 X0 Y0 Z1\nG2 X10 Y0 I5 J0\n", ["line 2", "G2", "arc"]),
    ("G0 X0 Y0 Z1\nG3 X10 Y0 R5\n", ["line 2", "G3", "arc"]),
    ("G0 X0 Y0 Z1\nG1 X10 A90\n", ["line 2", "A"]),
    ("G0 X0 Y0 Z1\nG1 X#1\n", ["line 2", "cannot read"]),
    ("G0 X0 Y0 Z1\nG1 X1.0.5 Y2\n", ["line 2", "cannot read 'X1.0.5'"]),  # the word, not '.5'
    ("G0 X0 Y0 Z1 (open\n", ["line 1", "parenthesis"]),
    ("X0 Y0 Z1\n", ["line 1", "before any G0 or G1"]),
    ("G0 X0 Y0 Z1\nG33 X1\n", ["line 2", "G33", "not supported"]),
    ("x_mm,y_mm\n1,2\n", ["line 1", "z_mm"]),
    ("x_mm,y_mm,z_mm\n1,2,3\n1,two,3\n", ["line 3", "y_mm", "'two'"]),
    ("x_mm,y_mm,z_mm\n1,2,3\n1,2\n", ["line 3", "2 fields"]),
    ("x_mm,y_mm,z_mm\nnan,2,3\n", ["line 2", "finite"]),
])
def test_unsupported_input_is_refused_naming_the_line(program, words):
    with pytest.raises(ToolpathError) as e:
        read_toolpath(program, "prog")
    for w in words:
        assert w in str(e.value)


@pytest.mark.parametrize("program, words", [
    ("G0 X0 Y0 Z1\nG1 X300\n", ["line 2", "(300, 0) mm is outside", "x [-200, 200]"]),
    ("G0 Z1\nG1 X10\n", ["line 2", "not known"]),
    ("G1 X0 Y0 Z1\n", ["line 1", "not known"]),
])
def test_paths_that_cannot_be_compensated_are_refused(program, words):
    with pytest.raises(ToolpathError) as e:
        cp.compensate(read_toolpath(program, "prog"), flat(), PLATE, T, top_mm=0.0, name="prog")
    for w in words:
        assert w in str(e.value)


# -- splitting against brute force ---------------------------------------------------------------

def _greedy_count(surface, limit):
    """Brute force: from each kept sample the farthest sample whose chord holds everywhere."""
    i, count, n = 0, 0, len(surface)
    while i < n - 1:
        j = n - 1
        while j > i + 1:
            t = np.linspace(0, 1, j - i + 1)[1:-1]
            chord = surface[i] + t * (surface[j] - surface[i])
            if np.all(np.abs(chord - surface[i + 1:j]) <= limit[i + 1:j]):
                break
            j -= 1
        i, count = j, count + 1
    return count


@pytest.mark.parametrize("std", [0.0, 0.001, 0.004])
def test_split_path_follows_the_map_within_the_budget_checked_by_brute_force(std):
    height = lambda x, y: (wavy(x, y)[0], np.full(np.shape(x), std))
    path = read_toolpath("G0 X-190 Y-140 Z1\nG1 Z-0.1\nG1 X190 Y140 Z-0.3\n", "p")
    res = cp.compensate(path, height, PLATE, T, top_mm=1.0, name="p")
    pts = np.array(res.pieces[2])
    assert res.added == len(pts) - 1 > 5
    # every kept point lies on programmed + mapped
    t = (pts[:, 0] + 190) / 380
    assert np.allclose(pts[:, 2], -0.1 - 0.2 * t + height(pts[:, 0], pts[:, 1])[0], atol=1e-12)
    # brute force: the output polyline at 0.01 mm steps against programmed + mapped
    full = np.r_[[[-190.0, -140.0, -0.1 + height(-190.0, -140.0)[0]]], pts]
    s = np.linspace(0, 1, 47_500)
    x, y = -190 + 380 * s, -140 + 280 * s
    out_z = np.interp(x, full[:, 0], full[:, 2])
    err = np.abs(out_z - (-0.1 - 0.2 * s + height(x, y)[0]))
    assert err.max() <= T - Z95 * std + 1e-6  # the budget, plus the sampling slack (<< 1 um)
    assert res.max_deviation_mm <= T - Z95 * std
    # no worse than twice the fewest points a brute-force search finds on the same samples
    ts = cp.samples(np.hypot(380, 280))
    surf = -0.1 - 0.2 * ts + height(-190 + 380 * ts, -140 + 280 * ts)[0]
    best = _greedy_count(surf, np.full(len(ts), T - Z95 * std))
    assert len(pts) <= 2 * best


def test_bisect_holds_its_own_condition_on_random_data():
    rng = np.random.default_rng(3)
    for _ in range(20):
        surface = np.cumsum(rng.normal(size=200)) * 0.01
        limit = rng.uniform(0.005, 0.02, 200)
        kept = cp.bisect(surface, limit)
        assert kept[0] == 0 and kept[-1] == 199 and kept == sorted(set(kept))
        out = np.interp(np.arange(200), kept, surface[kept])
        assert np.all(np.abs(out - surface) <= limit + 1e-15)


def test_a_plane_needs_no_split_and_a_plunge_is_one_piece():
    plane = lambda x, y: (0.01 * np.asarray(x) - 0.02 * np.asarray(y), np.zeros(np.shape(x)))
    path = read_toolpath("G0 X-190 Y-140 Z1\nG1 Z-0.1\nG1 X190 Y140\n", "p")
    res = cp.compensate(path, plane, PLATE, T, top_mm=1.0, name="p")
    assert res.added == 0 and len(res.pieces[1]) == 1 and res.max_deviation_mm < 1e-12


def test_wide_band_is_reported_where_it_is():
    def height(x, y):
        x = np.asarray(x, float)
        return np.zeros(x.shape), np.where(x > 50, 0.008, 0.001)  # band 15.7 um past x = 50

    path = read_toolpath("G0 X0 Y0 Z1\nG1 Z0\nG1 X40\nG1 X100 Y10\n", "p")
    res = cp.compensate(path, height, PLATE, T, top_mm=0.0, name="p")
    assert [w.line for w in res.wide] == [4]
    w = res.wide[0]
    assert w.x_mm > 50 and w.band_mm == pytest.approx(Z95 * 0.008)
    msg = cp.refusal(res.wide, T, "p")
    assert "line 4" in msg and "15.7 um" in msg and "10.0 um" in msg and "--mark" in msg


# -- the simulated cell ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    out = tmp_path_factory.mktemp("compensate") / "run"
    cell = sim_cell()
    session.run(cell, out, progress=False)
    (out / "cell.yaml").write_text((ROOT / "configs" / "sim-cell.yaml").read_text())
    return out, SimulatedCell.from_cell(cell).surface_mm


@pytest.mark.parametrize("frame", ["nominal", "corrected"])
def test_engraving_follows_the_true_plate_within_tolerance_where_the_map_is_confident(
        mapped, tmp_path, frame, capsys):
    run_dir, truth = mapped
    out = tmp_path / "out.gcode"
    assert main(["compensate", str(EXAMPLE), "--map", str(run_dir), "--out", str(out),
                 "--frame", frame]) == 0
    assert "points added by splitting" in capsys.readouterr().out
    # the header in the file's unit (mm) with the terminal's (um) beside it
    assert "tolerance 0.01 mm = 10 um)" in out.read_text().splitlines()[0]
    from adaptive_cal import __version__

    # which version bent the path, and when (a machined part traced to the code)
    assert re.match(rf"\(adaptive-cal {re.escape(__version__)} compensate, "
                    r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ: map ", out.read_text())
    hmap = load_map(run_dir)
    a, b, c = hmap.plane_abc if frame == "corrected" else (0, 0, 0)
    true = lambda x, y: truth(x, y) - (a * x + b * y + c)
    prog, comp = read_toolpath(EXAMPLE.read_text(), "in"), read_toolpath(out.read_text(), "out")
    # the example engraves at a constant depth: every cut that moves in x, y is at Z -0.1 mm
    assert all(m.start[2] == m.end[2] == -0.1 for m in prog.moves
               if m.cut and m.start[:2] != m.end[:2])
    worst, checked = 0.0, 0
    for m in comp.moves:  # each output cut, sampled 0.1 mm apart
        if not m.cut or m.start[:2] == m.end[:2]:
            continue
        p0, p1 = np.array(m.start), np.array(m.end)
        s = np.linspace(0, 1, int(np.hypot(*(p1 - p0)[:2]) / 0.1) + 2)
        xyz = p0 + s[:, None] * (p1 - p0)
        band = Z95 * hmap.height(frame)(xyz[:, 0], xyz[:, 1])[1]
        err = np.abs(xyz[:, 2] - (-0.1) - true(xyz[:, 0], xyz[:, 1]))[band <= T]
        checked += err.size
        worst = max(worst, err.max(initial=0.0))
    print(f"{frame}: worst error against the true plate {worst * 1e3:.2f} um at {checked} samples")
    assert checked > 10_000 and worst <= T, f"{worst * 1e3:.2f} um"


def test_the_corrected_frame_removes_the_plane_the_run_proposed(mapped):
    run_dir, _ = mapped
    hmap = load_map(run_dir)
    plan = survey_plan(load_cell(run_dir / "cell.yaml"))
    x, y = plan.eval_xy.T
    nominal = hmap.height("nominal")(x, y)[0]
    tilt = fl.plane_tilt(x, y, nominal)
    assert hmap.plane_abc == pytest.approx((tilt["a"], tilt["b"], tilt["c"]), abs=1e-12)
    corrected = hmap.height("corrected")(x, y)[0]
    left = fl.least_squares_plane(x, y, corrected)
    assert abs(left.a) < 1e-12 and abs(left.b) < 1e-12 and abs(left.c) < 1e-12


def test_grid_export_covers_the_workplane_and_matches_the_map(mapped, tmp_path):
    run_dir, truth = mapped
    grid = tmp_path / "map.csv"
    assert main(["compensate", "--map", str(run_dir), "--grid", str(grid), "--step-mm", "7"]) == 0
    lines = grid.read_text().splitlines()
    assert lines[0] == "x_mm,y_mm,height_mm,std_mm"
    x, y, h, s = np.loadtxt(grid, delimiter=",", skiprows=1).T
    assert (x.min(), x.max(), y.min(), y.max()) == (-225, 225, -185, 185)
    assert np.diff(np.unique(x)).max() <= 7 and np.diff(np.unique(y)).max() <= 7
    mean, std = load_map(run_dir).height("nominal")(x, y)
    # written to 1e-6 mm, at positions written to 1e-4 mm: on a plate tilted ~0.014 mm/mm the
    # position rounding adds up to ~0.7e-6 mm to the height's own 0.5e-6 mm
    assert np.allclose(h, mean, atol=2e-6) and np.allclose(s, std, atol=1e-6)
    assert np.sqrt(np.mean((h - truth(x, y)) ** 2)) < 0.01  # it is the plate


def test_cli_refuses_a_wide_band_and_marks_it_with_mark(mapped, tmp_path, capsys):
    run_dir, _ = mapped
    prog = tmp_path / "edge.gcode"
    prog.write_text("G0 X-225 Y-185 Z5\nG1 Z-0.1\nG1 X225\nG0 Z5\n")  # along the edge: wide band
    out = tmp_path / "out.gcode"
    assert main(["compensate", str(prog), "--map", str(run_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "band exceeds the tolerance 10.0 um" in err and "line 3" in err and not out.exists()
    assert main(["compensate", str(prog), "--map", str(run_dir), "--out", str(out), "--mark"]) == 0
    marked = [ln for ln in out.read_text().splitlines() if "exceeds the tolerance" in ln]
    assert marked and all(ln.startswith("G1") for ln in marked)
    assert "NOT within the tolerance" in capsys.readouterr().out


@pytest.mark.parametrize("argv, words", [
    (["--map", "nowhere", "--grid", "g.csv"], ["nowhere", "no such folder"]),
    (["--map", "RUN"], ["PROGRAM and --out"]),
    (["P", "--map", "RUN", "--grid", "g.csv"], ["not both"]),
    (["P", "--map", "RUN", "--out", "o", "--tolerance-mm", "0"], ["--tolerance-mm", "positive"]),
    (["missing.gcode", "--map", "RUN", "--out", "o"], ["missing.gcode", "no such file"]),
])
def test_bad_command_lines_give_clear_errors(mapped, argv, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "P").write_text("G0 X0 Y0 Z1\n")
    argv = [str(mapped[0]) if a == "RUN" else a for a in argv]
    assert main(["compensate", *argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    for w in words:
        assert w in err


def test_result_json_tilt_is_what_the_map_uses(mapped):
    run_dir, _ = mapped
    tilt = json.loads((run_dir / "result.json").read_text())["tilt"]
    assert load_map(run_dir).plane_abc == (tilt["a"], tilt["b"], tilt["c"])


def test_a_gcode_comment_naming_columns_is_still_gcode():
    path = read_toolpath("; columns x_mm, y_mm, z_mm\nG0 X1 Y2 Z3\n", "p")
    assert path.kind == "gcode" and path.moves[0].end == (1.0, 2.0, 3.0)


# -- input guards (the grid round trip, its size, the tolerance, the program's encoding) ---------

def test_heights_only_grid_is_a_height_map_a_cell_can_use(mapped, tmp_path, capsys):
    from adaptive_cal.formats.heightmap import load_heightmap, parse_heightmap

    run_dir, truth = mapped
    full, bare = tmp_path / "map.csv", tmp_path / "plate.csv"
    assert main(["compensate", "--map", str(run_dir), "--grid", str(full), "--step-mm", "9"]) == 0
    assert main(["compensate", "--map", str(run_dir), "--grid", str(bare), "--step-mm", "9",
                 "--heights-only"]) == 0
    assert "heights only" in capsys.readouterr().out
    assert bare.read_text().splitlines()[0] == "x_mm,y_mm,height_mm"
    # the same nodes and heights as the first three columns of the full grid
    a = np.loadtxt(full, delimiter=",", skiprows=1)
    assert np.array_equal(np.loadtxt(bare, delimiter=",", skiprows=1), a[:, :3])
    # the full grid is not a height map (the format fixes its header): the reader says how
    with pytest.raises(ValueError, match="--heights-only"):
        parse_heightmap(full.read_text(), str(full))
    hm = load_heightmap(bare)
    x, y = np.array([-100.0, 13.0, 200.0]), np.array([-50.0, 77.0, 150.0])
    assert np.sqrt(np.mean((hm(x, y) - truth(x, y)) ** 2)) < 0.01  # it is the plate
    cell = sim_cell(simulation={"surface_file": str(bare)})  # a simulated cell takes it
    assert cell.simulation.surface_file == str(bare)


def test_a_grid_finer_than_a_height_map_holds_is_refused_before_any_work(mapped, tmp_path,
                                                                         capsys):
    run_dir, _ = mapped
    grid = tmp_path / "g.csv"
    assert main(["compensate", "--map", str(run_dir), "--grid", str(grid), "--step-mm",
                 "0.001"]) == 2
    err = capsys.readouterr().err
    assert "--step-mm 0.001" in err and "166,500,820,001 nodes" in err and "4,000,000" in err
    assert "internal error" not in err and not grid.exists()
    for step in ("inf", "nan", "-1"):
        assert main(["compensate", "--map", str(run_dir), "--grid", str(grid), "--step-mm",
                     step]) == 2
        assert f"--step-mm {step}" in capsys.readouterr().err
    assert not grid.exists()


def test_grid_axes_stop_at_the_height_map_reader_limit():
    from adaptive_cal.cli.common import UserError
    from adaptive_cal.cli.compensate import grid_axes
    from adaptive_cal.formats.heightmap import MAX_NODES

    plate = ((-225.0, 225.0), (-185.0, 185.0))
    xs, ys = grid_axes(plate, 0.205)  # 2196 x 1806 nodes: just inside
    assert len(xs) * len(ys) <= MAX_NODES and (xs[0], xs[-1], ys[0], ys[-1]) == (-225, 225, -185, 185)
    with pytest.raises(UserError, match="--step-mm 0.204"):  # 2207 x 1815: just over
        grid_axes(plate, 0.204)


@pytest.mark.parametrize("tolerance, words", [
    ("inf", ["--tolerance-mm inf", "finite"]), ("nan", ["--tolerance-mm nan", "finite"]),
    ("1e-9", ["--tolerance-mm 1e-09", "0.0001 mm (0.1 um)", "4 decimals"]),
    ("5e-5", ["--tolerance-mm 5e-05", "0.0001 mm"]),
])
def test_a_tolerance_no_output_can_hold_is_refused(tolerance, words, capsys, tmp_path):
    prog = tmp_path / "p.gcode"
    prog.write_text("G0 X0 Y0 Z1\n")
    assert main(["compensate", str(prog), "--map", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--tolerance-mm", tolerance]) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, err
    assert not (tmp_path / "o").exists()


def test_a_program_that_is_not_utf8_names_the_file_and_line(mapped, tmp_path, capsys):
    run_dir, _ = mapped
    prog = tmp_path / "latin1.gcode"
    prog.write_bytes(b"G0 X0 Y0 Z1\n(first cut)\nG1 X10 (Durchmesser \xf8 6)\n")
    out = tmp_path / "o.gcode"
    assert main(["compensate", str(prog), "--map", str(run_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{prog}:3: not UTF-8" in err and "0xf8, byte 21 of the line" in err
    assert "codec" not in err
    assert not out.exists()


# -- the margin no touch reaches ------------------------------------------------------------------

REACH = ((-190.0, 190.0), (-140.0, 140.0))  # PLATE less a 10 mm edge margin


def _outside_brute(x, y):
    """Distance from (x, y) to the box REACH by brute force over a dense grid of its edge."""
    (x0, x1), (y0, y1) = REACH
    if x0 <= x <= x1 and y0 <= y <= y1:
        return 0.0
    s = np.linspace(0, 1, 200_001)
    edge = np.concatenate([np.c_[x0 + (x1 - x0) * s, np.full_like(s, y0)],
                           np.c_[x0 + (x1 - x0) * s, np.full_like(s, y1)],
                           np.c_[np.full_like(s, x0), y0 + (y1 - y0) * s],
                           np.c_[np.full_like(s, x1), y0 + (y1 - y0) * s]])
    return float(np.hypot(edge[:, 0] - x, edge[:, 1] - y).min())


def test_a_cut_into_the_margin_is_reported_with_its_furthest_sample():
    path = read_toolpath("G0 X0 Y0 Z1\nG1 Z0\nG1 X190\nG1 X196 Y146\nG0 Z1\nG0 X195 Y0\n"
                         "G1 Z0\n", "p")
    res = cp.compensate(path, flat(std=0.001), PLATE, T, top_mm=0.0, name="p", reach_mm=REACH)
    # line 3 ends on the box's edge (reachable); line 4 runs out to its corner + (6, 6) mm; the
    # rapid on line 6 is not a cut; the plunge on line 7 lies 5 mm outside
    assert [b.line for b in res.beyond] == [4, 7]
    corner, plunge = res.beyond
    assert (corner.x_mm, corner.y_mm) == pytest.approx((196.0, 146.0))
    assert corner.outside_mm == pytest.approx(_outside_brute(196.0, 146.0), abs=1e-5)
    assert plunge.outside_mm == pytest.approx(_outside_brute(195.0, 0.0), abs=1e-5)
    assert not res.wide  # the band (2 um) is inside the tolerance: only the reach refuses
    msg = cp.refusal(res.wide, T, "p", beyond=res.beyond, reach_mm=REACH)
    assert "line 4 at (196.0, 146.0) mm, 8.5 mm beyond it" in msg
    assert "x [-190, 190] mm, y [-140, 140] mm" in msg and "extrapolation" in msg
    assert "band exceeds" not in msg and "--mark" in msg
    # without a reach (touches could reach the whole plate) nothing is reported
    assert not cp.compensate(path, flat(std=0.001), PLATE, T, top_mm=0.0, name="p").beyond


def test_cli_refuses_a_cut_into_the_unreachable_margin_and_marks_it(mapped, tmp_path, capsys):
    run_dir, _ = mapped
    hmap = load_map(run_dir)
    (x0, x1), (y0, y1) = hmap.reach_mm
    assert ((x0, x1), (y0, y1)) == ((-215, 215), (-175, 175))  # sim-cell: 10 mm margin
    prog = tmp_path / "face.gcode"
    prog.write_text("G0 X0. Y0. Z5.\nG1 Z-0.1\nG1 X200.\nG1 X220.\nG0 Z5.\n")
    out = tmp_path / "out.gcode"
    # a tolerance the band meets everywhere on the path: only the margin refuses line 4
    argv = ["compensate", str(prog), "--map", str(run_dir), "--out", str(out),
            "--tolerance-mm", "0.05"]
    band = Z95 * hmap.height()(np.linspace(0, 220, 441), np.zeros(441))[1]
    assert band.max() < 0.05
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "line 4 at (220.0, 0.0) mm, 5.0 mm beyond it" in err and "line 3" not in err
    assert "band exceeds" not in err and not out.exists()
    assert main(argv + ["--mark"]) == 0
    marked = [ln for ln in out.read_text().splitlines() if "extrapolated" in ln]
    assert len(marked) == 1 and marked[0].startswith("G1") and "5.0 mm beyond" in marked[0]
    assert "the map is extrapolated: the output is NOT within" in capsys.readouterr().out


def test_grid_export_says_where_the_map_is_extrapolated(mapped, tmp_path, capsys):
    run_dir, _ = mapped
    assert main(["compensate", "--map", str(run_dir), "--grid", str(tmp_path / "g.csv")]) == 0
    assert ("outside x [-215, 215] mm, y [-175, 175] mm (the workplane's edge margin) the map "
            "is an extrapolation") in capsys.readouterr().out


@pytest.mark.parametrize("code", ["M2", "M30", "M0", "M1", "M60"])
def test_a_stop_or_end_on_a_split_cut_goes_with_its_last_piece(mapped, tmp_path, code):
    """M0, M1, M2, M30 and M60 act after the line's motion. On a split cut they stayed on the
    first piece: the program ended (or paused, the cutter in the cut) 25 mm into a 200 mm cut,
    with six moves after its end -- and compensate refused its own output (an audit,
    2026-11-24). Now they end the last piece, and the output reads back."""
    run_dir, _ = mapped
    prog = tmp_path / "p.gcode"
    prog.write_text(f"G21 G90\nG0 X-150. Y-100. Z5.\nG1 Z-0.1 F100\nG1 X-150. Y100. {code} (end)\n")
    out = tmp_path / "o.gcode"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["compensate", str(prog), "--map", str(run_dir), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    cut = [ln for ln in lines[3:] if ln.startswith("G1 X")]
    assert len(cut) > 2  # split
    has = [re.search(rf"\bM{int(code[1:])}\b", ln) is not None for ln in cut]
    assert has == [False] * (len(cut) - 1) + [True]
    assert "(end)" in cut[0]  # the line's comment stays on it, with the first piece
    assert cut[-1].startswith("G1 X-150.0000 Y100.0000 Z")
    back = tmp_path / "o2.gcode"  # the output reads back; compensating it again is refused
    assert read_toolpath(out.read_text(), "o").compensated[0] == 1
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["compensate", str(out), "--map", str(run_dir), "--out", str(back)]) == 2
    assert not back.exists()


def test_a_tolerance_that_looks_like_um_typed_as_mm_is_warned(capsys):
    from adaptive_cal.cli.compensate import check_tolerance

    check_tolerance(10.0)  # meant 10 um: valid, but said
    assert "warning: --tolerance-mm 10 is 10000 um -- um given as mm? (10 um is 0.01)" in \
        capsys.readouterr().err
    check_tolerance(0.05)
    assert capsys.readouterr().err == ""


def test_a_level_rapid_the_map_tilts_goes_across_at_the_higher_end_then_up_or_down_alone():
    """A rapid in X, Y only, whose ends the map raises by different heights, is written as two
    rapids: across at the higher end's Z and the Z change on its own (first when rising, last
    when descending). Raised as one, a control that moves each axis of a rapid at its own speed
    finished Z first and ran 0.5 mm into an outside audit's plate."""
    def tilted(x, y):
        x = np.asarray(x, float)
        return 0.01 * x, np.full(x.shape, 0.001)

    text = "G21 G90\nG0 X100 Y0 Z5\nG0 X-100 Y0\nG0 X100 Y0\nM2\n"
    path = read_toolpath(text, "p")
    res = cp.compensate(path, tilted, PLATE, T, top_mm=1.0, name="p")
    moves = read_toolpath(write_toolpath(path, res.pieces), "out").moves
    ends = [tuple(round(v, 4) for v in m.end) for m in moves]
    assert ends == [(100, 0, 6), (-100, 0, 6), (-100, 0, 4), (-100, 0, 6), (100, 0, 6)]
    assert not any(m.cut for m in moves)
    for m in moves[1:]:  # every rapid moves in X, Y or in Z, never both
        assert (m.start[:2] == m.end[:2]) != (m.start[2] == m.end[2])


def test_cli_refuses_a_cut_over_a_keep_out_and_marks_it(mapped, tmp_path, capsys):
    """sim-cell's clamp, keep_outs[0] (x -40..10, y 60..110 mm), was cut through in silence (an
    outside audit): refused naming the line and the keep-out; --mark marks that line."""
    run_dir, _ = mapped
    assert load_map(run_dir).keep_outs == (((-40.0, 10.0), (60.0, 110.0)),)
    prog = tmp_path / "clamp.gcode"
    prog.write_text("G0 X-60. Y85. Z5.\nG1 Z-0.1\nG1 X30.\nG1 Y140.\nG0 Z5.\n")
    out = tmp_path / "out.gcode"
    argv = ["compensate", str(prog), "--map", str(run_dir), "--out", str(out),
            "--tolerance-mm", "0.05"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "1 cut(s) pass over a keep-out" in err and "line 3 at" in err
    assert "keep_outs[0] (x -40..10, y 60..110 mm)" in err and not out.exists()
    assert main(argv + ["--mark"]) == 0
    marked = [ln for ln in out.read_text().splitlines() if "keep_outs[0]" in ln]
    assert len(marked) == 1 and marked[0].startswith("G1 X30.")
    assert "passes over a keep-out: the output is NOT within" in capsys.readouterr().out


@pytest.mark.parametrize("broken", ["mean", "cov", "negative"])
def test_a_map_whose_arrays_are_not_a_posterior_is_refused(mapped, tmp_path, capsys, broken):
    """A NaN mean wrote Znan with exit 0; a NaN or negated covariance switched the band check
    off (an outside audit). The saved map is refused, naming the file and the array."""
    import shutil

    run_dir, _ = mapped
    bad = tmp_path / "run"
    shutil.copytree(run_dir, bad)
    data = dict(np.load(bad / "belief.npz"))
    if broken == "mean":
        data["mean"][5] = np.nan
    elif broken == "cov":
        data["cov"][5, 5] = np.nan
    else:
        data["cov"] = -data["cov"]
    np.savez(bad / "belief.npz", **data)
    prog = tmp_path / "p.gcode"
    prog.write_text("G0 X0. Y0. Z5.\nG1 Z-0.1\nG1 X20.\n")
    assert main(["compensate", str(prog), "--map", str(bad), "--out",
                 str(tmp_path / "o.gcode")]) == 2
    err = capsys.readouterr().err
    name = "mean" if broken == "mean" else "cov"
    assert f"belief.npz: array '{name}' is not a map's" in err
    assert not (tmp_path / "o.gcode").exists()


def test_grid_export_says_how_far_its_bilinear_reading_departs_from_the_map(mapped, tmp_path,
                                                                            capsys):
    """A 2 x 2 grid (--step-mm 1000) read bilinearly departs from the map by some 0.2 mm at
    its centre: said, and warned about past the tolerance (an outside audit: it was silent);
    a 5 mm grid by well under 1 um."""
    run_dir, _ = mapped
    assert main(["compensate", "--map", str(run_dir), "--grid", str(tmp_path / "g.csv"),
                 "--step-mm", "1000"]) == 0
    said = capsys.readouterr()
    gap = float(re.search(r"departs from the map by up to ([0-9.]+) um", said.out).group(1))
    assert gap > 50 and "warning: that is more than the tolerance 10 um" in said.err
    assert main(["compensate", "--map", str(run_dir), "--grid", str(tmp_path / "g5.csv"),
                 "--step-mm", "5"]) == 0
    said = capsys.readouterr()
    gap = float(re.search(r"departs from the map by up to ([0-9.]+) um", said.out).group(1))
    assert gap < 1.0 and "warning" not in said.err


def test_an_output_named_for_the_other_format_is_warned_about(mapped, tmp_path, capsys):
    """The output keeps the program's format: CSV rows written to a .gcode name are said (an
    outside audit); a neutral name is not."""
    run_dir, _ = mapped
    prog = tmp_path / "pts.csv"
    prog.write_text("x_mm,y_mm,z_mm\n0,0,-0.1\n20,0,-0.1\n")
    for name, warned in (("o.gcode", True), ("o.txt", False), ("o.csv", False)):
        assert main(["compensate", str(prog), "--map", str(run_dir), "--out",
                     str(tmp_path / name)]) == 0
        err = capsys.readouterr().err
        assert ("holds CSV rows (the output keeps the program's format)" in err) == warned, name


def test_the_cut_farthest_from_every_touch_is_found_and_said(mapped, tmp_path, capsys):
    """An outside audit: a 50 um boss 44 mm from the nearest touch was cut over at 10 um with a
    narrow band and nothing said. The cut sample farthest from the run's fused touches is named
    (checked by brute force over the samples); a feature narrower than that can hide there."""
    path = read_toolpath("G0 X-150 Y-100 Z1\nG1 Z0\nG1 X150\nG1 Y100\n", "p")
    touched = np.array([[-150.0, -100.0], [0.0, -100.0], [150.0, 40.0]])
    res = cp.compensate(path, flat(std=0.001), PLATE, T, top_mm=0.0, name="p",
                        touched_xy=touched)
    far = res.farthest
    # brute force: the samples of both cuts, each one's distance to its nearest touch
    xs = np.r_[np.linspace(-150, 150, 601), np.full(401, 150.0)]
    ys = np.r_[np.full(601, -100.0), np.linspace(-100, 100, 401)]
    d = np.min(np.hypot(xs[:, None] - touched[:, 0], ys[:, None] - touched[:, 1]), axis=1)
    assert far.distance_mm == pytest.approx(d.max(), abs=1e-9)
    k = int(np.argmax(d))
    assert (far.x_mm, far.y_mm) == (pytest.approx(xs[k]), pytest.approx(ys[k]))  # (150, -100)
    assert far.line in (3, 4)  # the corner ends line 3 and starts line 4
    assert cp.compensate(path, flat(std=0.001), PLATE, T, top_mm=0.0, name="p").farthest is None

    run_dir, _ = mapped
    hmap = load_map(run_dir)
    assert hmap.touched_xy is not None and len(hmap.touched_xy) >= 10
    out = tmp_path / "out.gcode"
    assert main(["compensate", str(EXAMPLE), "--map", str(run_dir), "--out", str(out),
                 "--tolerance-mm", "0.05", "--mark"]) == 0
    said = capsys.readouterr().out
    line = next(ln for ln in said.splitlines() if ln.startswith("the cuts pass up to "))
    assert "mm from the nearest touch (line " in line and "can lie there unseen" in line
    # the recording gone: the map still compensates, without this line
    (run_dir / "recording.csv").rename(run_dir / "recording.kept")
    try:
        assert main(["compensate", str(EXAMPLE), "--map", str(run_dir), "--out", str(out),
                     "--tolerance-mm", "0.05", "--mark"]) == 0
        said = capsys.readouterr().out
        assert "the cuts pass up to" not in said
        assert "how far the cuts pass from a touch is not known: no readable recording.csv" in said
    finally:
        (run_dir / "recording.kept").rename(run_dir / "recording.csv")


def test_a_reading_judged_a_gross_error_is_no_touch_of_the_plate(tmp_path):
    """An outside review: a fused row of any outlier weight counted as a touch in compensate's
    farthest-from-a-touch line; one judged more likely a gross error than not (outlier=P, P >=
    0.5) tells nothing of the plate there, and a gated row none either."""
    from adaptive_cal.run.heightmap import _touched

    rec = tmp_path / "recording.csv"
    rec.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,flags\n"
                   "0,0,0,0,0,5.0,\n1,4,10,0,0,5.0,outlier=0.90\n2,8,20,0,0,5.0,outlier=0.20\n"
                   "3,12,30,0,0,5.0,gated\n")
    assert _touched(rec).tolist() == [[0.0, 0.0], [20.0, 0.0]]
    assert _touched(tmp_path / "none.csv") is None
