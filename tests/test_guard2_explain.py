"""explain's suggestions and rounds: suggested touches only where a run could touch them (the
cell's own rule, as the planner's candidates), at an approach height that follows the plate;
one recording given twice as two rounds is refused, naming both."""
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.candidates import Context
from adaptive_cal.analysis.explain.design import build_design
from adaptive_cal.analysis.explain.identify import _gap_touches
from adaptive_cal.formats.recording import RecordingError, read_recording

from helpers import ROOT, SIM_CELL, sim_cell

KEEP_OUT = {"x_mm": [-140, -100], "y_mm": [40, 70]}
TILT = (0.01, -0.005)  # mm/mm: the plate rises 4.5 mm along x


def _write(path, xy, zero=5.0, noise=0.002, seed=0):
    rng = np.random.default_rng(seed)
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    for i, (x, y) in enumerate(xy):
        surface = TILT[0] * x + TILT[1] * y + 0.3
        z = 0.5 * surface  # an approach that follows the plate only half way
        reading = surface - z + zero + noise * rng.standard_normal()
        lines.append(f"{i},{4.0 * i:.1f},{x:.4f},{y:.4f},{z:.4f},{reading:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _sparse_design(tmp_path):
    # a coarse ring of touches: the largest gaps are at the keep-out and on the plate's edge
    xs = [-200, -60, 60, 200]
    ys = [-160, 0, 160]
    xy = [(x, y) for y in ys for x in xs]
    cell = sim_cell(workplane={"keep_outs": [KEEP_OUT]})
    return cell, build_design([read_recording(_write(tmp_path / "r.csv", xy))], cell)


def test_gap_touches_land_only_where_a_run_could_touch(tmp_path):
    cell, design = _sparse_design(tmp_path)
    wp = cell.workplane
    got = _gap_touches(Context.of(design), count=12)
    assert len(got["touches"]) == 12
    for t in got["touches"]:
        assert wp.allows(t["x_mm"], t["y_mm"]), t
    # the same design without the cell's rule suggests places no run could touch: the filter
    # above is what keeps them out
    free = _gap_touches(Context.of(replace(design, allows=None)), count=12)
    assert any(not wp.allows(t["x_mm"], t["y_mm"]) for t in free["touches"])
    # the coverage statement is about the whole plate, as before
    assert got["fill_distance_mm"] == free["fill_distance_mm"]


def test_gap_touches_approach_at_the_fitted_plane_not_one_median_height(tmp_path):
    _, design = _sparse_design(tmp_path)
    got = _gap_touches(Context.of(design), count=6)
    assert "plane fitted" in got["description"]
    for t in got["touches"]:
        surface = TILT[0] * t["x_mm"] + TILT[1] * t["y_mm"] + 0.3
        # expected reading there: surface - z + zero, near the recorded readings (about 5.15)
        expected = surface - t["z_mm"] + 5.0
        assert abs(expected - np.median(design.reading_mm)) < 0.02, (t, expected)
    zs = {round(t["z_mm"], 2) for t in got["touches"]}
    assert len(zs) > 1  # not one height for all


def _rounds_of(tmp_path, *names_seeds):
    xy = [(x, y) for y in (-160, -60, 40, 140) for x in (-200, -100, 0, 100, 200)]
    return [_write(tmp_path / name, xy, seed=seed) for name, seed in names_seeds]


def test_one_recording_given_twice_is_refused_naming_both(tmp_path):
    cell = sim_cell()
    a, b = _rounds_of(tmp_path, ("a.csv", 1), ("b.csv", 2))
    explain([a, b], cell)  # two real rounds: fine
    with pytest.raises(RecordingError, match=f"{a} and {a} are the same file"):
        explain([a, a], cell)
    sub = tmp_path / "sub"
    sub.mkdir()
    with pytest.raises(RecordingError, match="are the same file"):  # another spelling of it
        explain([a, b, sub / ".." / "a.csv"], cell)
    copy = tmp_path / "copy.csv"
    copy.write_text(a.read_text())
    with pytest.raises(RecordingError, match=f"{a} and {copy} hold the same rows"):
        explain([a, copy], cell)


def test_the_cli_says_so_with_exit_2(tmp_path):
    a, = _rounds_of(tmp_path, ("a.csv", 1))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    p = subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "explain", str(a), str(a),
                        "--robot", str(SIM_CELL), "--no-figures"], capture_output=True, text=True,
                       env=env, timeout=300, cwd=ROOT)
    assert p.returncode == 2, p.stderr
    assert f"{a} and {a} are the same file" in p.stderr and "Traceback" not in p.stderr


def test_a_touch_off_the_workplane_is_refused_naming_it(tmp_path):
    # one check (Workplane.first_outside) for replay and explain: the first fused touch off the
    # plate, its column and value, and how many such touches there are
    xy = [(x, y) for y in (-150, 0, 150) for x in (-200, -60, 60, 200)]
    xy[5] = (-60, 900.0)
    xy[7] = (260.0, 0)  # x and y both: x is named first, counting x only
    with pytest.raises(RecordingError, match=r"touch seq 7: column x_mm = 260 lies outside the "
                       r"workplane x_mm \[-225, 225\] of the cell file \(1 such touches\)"):
        build_design([read_recording(_write(tmp_path / "r.csv", xy))], sim_cell())
    wp = sim_cell().workplane
    assert wp.first_outside([0.0, 225.0 + 1e-10], [-185.0, 185.0]) is None  # round-off allowed
    assert wp.first_outside([0.0, 1.0], [186.0, -300.0]) == ("y_mm", 0, 2)


def test_a_rounded_copy_of_a_round_is_refused_a_genuine_repeat_is_not(tmp_path):
    """Only exact copies were refused: a recording re-written with its readings rounded to 1 um
    passed as a second round (its missing scatter read as structure). Refused now when the
    readings at the same positions differ by less than 0.2 x the stated noise (sim cell:
    probe.noise_std_mm 5 um, so 1 um); two genuine rounds (2 um noise each) pass."""
    cell = sim_cell()
    a, b = _rounds_of(tmp_path, ("a.csv", 1), ("b.csv", 2))
    lines = a.read_text().splitlines()
    rounded = lines[:2] + [",".join(p[:5] + [f"{float(p[5]):.3f}"])
                           for p in (line.split(",") for line in lines[2:])]
    copy = tmp_path / "rounded.csv"
    copy.write_text("\n".join(rounded) + "\n")
    with pytest.raises(RecordingError, match=rf"{a} and {copy} touch the same positions and "
                                             r"their readings differ by 0\.\d+ um RMS, below 1 um "
                                             r"from probe.noise_std_mm"):
        explain([a, copy], cell)
    explain([a, b], cell)


def test_a_recording_whose_rows_are_all_flagged_says_which_flags(tmp_path):
    """Every row flagged invalid: the message said 'marks the others gated or rejected'."""
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm,flags"]
    lines += [f"{i},,{-200 + 10 * i},0,0,5.0,{'invalid;rejected' if i % 2 else 'gated'}"
              for i in range(12)]
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"12 rows, 0 of them fused \(the column flags marks "
                                             r"the others gated/invalid/rejected\)"):
        explain([read_recording(tmp_path / "r.csv")], sim_cell())


def test_a_recording_built_in_memory_with_nan_readings_is_refused_naming_the_row(tmp_path):
    """The reader refuses NaN in a file; a Recording made in a notebook reached numpy's 'SVD did
    not converge' (outside speed audit)."""
    lines = ["# adaptive-cal recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm"]
    lines += [f"{i},,{-200 + 20 * i},{(-1) ** i * 50},0,5.0" for i in range(20)]
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    rec = read_recording(tmp_path / "r.csv")
    nan = replace(rec, reading_mm=np.where(np.arange(20) >= 3, np.nan, rec.reading_mm))
    with pytest.raises(RecordingError, match=r"seq 3: reading_mm is not a finite number \(17 "):
        explain([nan], sim_cell())


def test_the_workplane_rule_on_arrays_is_the_rule_point_by_point():
    """``workplane.allowed`` (explain's suggestions ask it of 150,000 places at once on a
    1200 x 800 mm plate; ``allows`` asks it of one) answers as the rule does point by point:
    inside the margin and outside every keep-out (``kept_out``), the edges of both included."""
    wp = sim_cell(workplane={"keep_outs": [KEEP_OUT, {"x_mm": [100, 160], "y_mm": [-185, -120]}],
                             "edge_margin_mm": 12}).workplane
    rng = np.random.default_rng(5)
    x = rng.uniform(wp.x_mm[0] - 20, wp.x_mm[1] + 20, 5000)
    y = rng.uniform(wp.y_mm[0] - 20, wp.y_mm[1] + 20, 5000)
    x[:40], y[40:80] = wp.x_mm[0] + 12, wp.y_mm[1] - 12  # on the margin's edge
    x[80:120], y[80:120] = KEEP_OUT["x_mm"][1], np.linspace(*KEEP_OUT["y_mm"], 40)  # a keep-out's
    got = wp.allowed(x, y)
    assert got.dtype == bool and got.shape == x.shape
    m = 12.0
    rule = [wp.x_mm[0] + m <= u <= wp.x_mm[1] - m and wp.y_mm[0] + m <= v <= wp.y_mm[1] - m
            and not wp.kept_out(float(u), float(v)) for u, v in zip(x, y)]
    assert np.array_equal(got, rule)
    assert [wp.allows(float(u), float(v)) for u, v in zip(x[:200], y[:200])] == rule[:200]
    assert 0.3 < got.mean() < 0.95
