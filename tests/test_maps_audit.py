"""Height maps in studies and files, from an outside audit: the study's checkpoint key covers its
maps' names and bytes; an off-grid value and a grid just short of the workplane are named
exactly; compensate --heights-only round-trips a small workplane's edges; map plates keep the
base cell's effects; a plate failing on Dask workers logs no worker traceback."""
import argparse
import hashlib
import json

import numpy as np
import pytest
import yaml

from adaptive_cal.cell.schema import load_yaml, parse_cell
from adaptive_cal.formats.heightmap import (HEADER, HeightMapError, load_heightmap,
                                            parse_heightmap, write_heightmap)
from adaptive_cal.simulation.cell import SimulatedCell
from adaptive_cal.study.checkpoint import Checkpoint, read_checkpoint, study_key
from adaptive_cal.study.config import load_study, parse_study
from adaptive_cal.study.plates import plate_cell, sample_plate, truth

from helpers import SIM_CELL

XS, YS = np.linspace(-225, 225, 10), np.linspace(-185, 185, 8)


def plane(x, y, c=0.3):
    return c + 1e-3 * x - 2e-3 * y


def write_map(path, xs=XS, ys=YS, c=0.3):
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return write_heightmap(path, xs, ys, plane(X, Y, c))


def map_study(tmp_path, files=2, cell=None):
    (tmp_path / "maps").mkdir(exist_ok=True)
    for i in range(files):
        write_map(tmp_path / "maps" / f"p{i}.csv", c=0.3 + 0.01 * i)
    data = load_yaml(SIM_CELL.parent / "study-smoke.yaml")
    data["cell"] = str(cell or SIM_CELL)
    data["plate"] = {**data["plate"], "surface_files": "maps/p*.csv"}
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


# -- 1. the checkpoint key covers the maps ------------------------------------------------------

def test_a_map_added_or_rewritten_makes_another_study_and_the_rerun_says_so(tmp_path):
    """Before, the key hashed the glob, not what it matched: a map added (shifting plate i to
    another file) or rewritten in place reused the old plates' records without a word."""
    study, base = load_study(map_study(tmp_path))
    first = study_key(study, base)
    assert study_key(study, base) == first  # the same maps: the same study
    write_map(tmp_path / "maps" / "p0a.csv", c=0.25)  # sorts between p0 and p1
    added = study_key(study, base)
    (tmp_path / "maps" / "p0a.csv").unlink()
    assert study_key(study, base) == first
    write_map(tmp_path / "maps" / "p1.csv", c=0.35)  # the same name, other heights
    rewritten = study_key(study, base)
    assert len({first, added, rewritten}) == 3
    ck = tmp_path / "plates.jsonl"
    Checkpoint(ck, first).close()
    with pytest.raises(ValueError, match=r"plates of this study over other height maps .*"
                                         r"rewritten since"):
        read_checkpoint(ck, rewritten)
    legacy = tmp_path / "legacy.jsonl"  # a map study's checkpoint from before: settings only
    Checkpoint(legacy, first.split("-")[0]).close()
    with pytest.raises(ValueError, match="written before a study's key covered its maps"):
        read_checkpoint(legacy, first)
    from adaptive_cal.study.runner import run_study
    with pytest.raises(ValueError, match="other height maps"):  # refused before any plate runs
        run_study(study, base, ck)


def test_the_base_cells_own_map_is_in_the_key_and_a_study_without_maps_keeps_its_key(tmp_path):
    write_map(tmp_path / "own.csv")
    study, base = load_study(SIM_CELL.parent / "study-smoke.yaml")
    # a study without maps: its settings (but the plate count) and base cell alone
    settings = {k: v for k, v in study.model_dump(mode="json").items() if k != "plates"}
    text = json.dumps({"study": settings, "cell": base}, sort_keys=True, default=str)
    assert study_key(study, base) == hashlib.sha256(text.encode()).hexdigest()[:16]
    own = {**base, "simulation": {**base["simulation"], "surface_file": str(tmp_path / "own.csv")}}
    before = study_key(study, own)
    write_map(tmp_path / "own.csv", c=0.4)
    assert study_key(study, own) != before


# -- 2. and 3. the reader names the off-grid line and the shortfall ----------------------------

def _grid_rows():
    X, Y = np.meshgrid(np.linspace(-225, 225, 19), np.linspace(-185, 185, 15), indexing="ij")
    return np.column_stack([X.ravel(), Y.ravel(), (0.001 * X).ravel()]).tolist()


@pytest.mark.parametrize("column, value, name", [(0, 57.0, "x_mm"), (1, 12.5, "y_mm")])
def test_an_off_grid_value_is_refused_naming_its_line_and_value(column, value, name):
    """One row's coordinate typed wrong (file line 42): the message named no line."""
    rows = _grid_rows()
    rows[40][column] = value
    text = HEADER + "\n" + "".join("%r,%r,%r\n" % tuple(r) for r in rows)
    with pytest.raises(HeightMapError) as e:
        parse_heightmap(text, "typo.csv")
    msg = str(e.value)
    assert msg.startswith("typo.csv, line 42: not a regular grid"), msg
    assert f"{name} {value!r} lies" in msg and "on 1 row(s)" in msg


def test_an_irregular_grid_names_the_first_line_of_the_node_farthest_off():
    """Every node on as many rows: the one farthest from its place is named, by its first line."""
    X, Y = np.meshgrid([-225.0, -100.0, 0.0, 225.0], [-185.0, 185.0], indexing="ij")
    rows = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)]).tolist()
    text = HEADER + "\n" + "".join("%r,%r,%r\n" % tuple(r) for r in rows)
    with pytest.raises(HeightMapError, match=r"^m, line 6: not a regular grid: x_mm nodes 0 and "
                                             r"225 .* x_mm 0.0 lies 75 mm from its place\)$"):
        parse_heightmap(text, "m")


def test_a_grid_just_short_of_the_workplane_prints_the_digits_that_differ(tmp_path):
    """0.5 um short: the spans printed with {:g} read the same as the workplane's."""
    path = write_map(tmp_path / "m.csv", ys=np.linspace(-184.9995, 185, 8))
    with pytest.raises(HeightMapError) as e:
        load_heightmap(path).check_covers((-225.0, 225.0), (-185.0, 185.0))
    msg = str(e.value)
    assert "y_mm=[-184.9995, 185]" in msg and "x_mm=[-225, 225]" in msg, msg
    assert "0.0005 mm short of y_mm=-185.0" in msg


# -- 4. compensate --grid --heights-only round-trips the workplane's edges ----------------------

class _FlatMap:
    """What compensate's grid export reads of a run's map: a plane on a small workplane."""

    plate_mm = ((-30.00004, 30.00004), (-10.00004, 10.00004))
    reach_mm = None

    def height(self, frame):
        return lambda x, y: (plane(x, y), np.full(np.shape(x), 1e-3))


def test_heights_only_grid_of_a_small_workplane_covers_its_workplane(tmp_path, capsys):
    """Written with 4 decimals, the ends -30.00004 read back as -30.0000: the export did not
    cover its own workplane and was refused as simulation.surface_file."""
    from adaptive_cal.cli.compensate import _grid

    out = tmp_path / "g.csv"
    args = argparse.Namespace(step_mm=1.0, frame="nominal", heights_only=True, grid=str(out),
                              tolerance_mm=0.01)
    assert _grid(_FlatMap(), args) == 0
    hm = load_heightmap(out)
    hm.check_covers(*_FlatMap.plate_mm)  # no error
    assert (hm.x_mm[0], hm.x_mm[-1]) == (-30.00004, 30.00004)
    x, y = np.array([-29.9, 3.3, 30.0]), np.array([-10.0, 0.7, 9.9])
    assert np.allclose(hm(x, y), plane(x, y), atol=2e-6)
    assert "nodes" in capsys.readouterr().out


def test_grid_positions_stay_readable():
    from adaptive_cal.cli.compensate import grid_text

    text = grid_text(np.linspace(-225, 225, 91))  # 5 mm: linspace gives -219.99999999999997
    assert list(text) == [str(v) for v in range(-225, 230, 5)]
    assert list(grid_text([-1e-14, 26.428571428571416, 0.1 + 0.2])) == ["0", "26.4285714286",
                                                                       "0.3"]


# -- 5. a map plate keeps the base cell's effects ----------------------------------------------

def test_map_plates_keep_the_base_cells_effects_on_top_drawn_plates_replace_them(tmp_path):
    """DESIGN.md "Height maps": effects under simulation.effects add on top of the map; a
    study's map plates dropped them (the base cell's tilt, thermal drift) without a word."""
    cell = load_yaml(SIM_CELL)
    cell["simulation"]["effects"] = {**cell["simulation"]["effects"],
                                     "thermal_drift": {"rate_mm_per_s": 0.001}}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    study, base = load_study(map_study(tmp_path, cell=tmp_path / "cell.yaml"))
    plate = sample_plate(study, 1)
    c = plate_cell(study, base, plate)
    assert c.simulation.effects == cell["simulation"]["effects"]
    assert c.simulation.surface_file.endswith("p1.csv")
    alone = plate_cell(study, {**base, "simulation": {**base["simulation"], "effects": {}}}, plate)
    x, y = np.array([-100.0, 20.0]), np.array([50.0, -150.0])
    effects = SimulatedCell.from_cell(parse_cell(base)).surface_mm(x, y)  # the base, no map
    assert np.allclose(truth(c)(x, y), truth(alone)(x, y) + effects)
    assert np.allclose(truth(alone)(x, y), plane(x, y, 0.31))  # the map alone
    # a drawn plate (no maps): its own tilt and form take the base cell's place, as before
    flat = parse_study({**study.model_dump(mode="json"),
                        "plate": {**study.plate.model_dump(mode="json"), "surface_files": None}})
    drawn = sample_plate(flat, 1)
    assert plate_cell(flat, base, drawn).simulation.effects == drawn.effects


# -- 6. a failing plate on Dask workers: the error, without a worker's traceback log ------------

def _broken_setup():
    raise ValueError("plate broke")


def test_a_plate_failing_on_a_dask_worker_logs_no_worker_traceback(tmp_path, capfd):
    from adaptive_cal.study.runner import connect, run_study

    study, base = load_study(SIM_CELL.parent / "study-smoke.yaml")
    data = study.model_dump(mode="json")
    data.update(plates=1, strategies=["adaptive"], lower_bound={"plates": 0})
    client = connect(None, 1)
    try:
        with pytest.raises(ValueError, match="plate broke"):  # the caller's to report
            run_study(parse_study(data), base, tmp_path / "ck.jsonl", client=client,
                      worker_setup=_broken_setup)
    finally:
        client.close()
    err = capfd.readouterr().err
    assert "Compute Failed" not in err and "Traceback" not in err, err


# -- 7. a flat zero plate: no strategy reaches the true target without a touch ------------------

def test_a_zero_plate_credits_no_strategy_with_zero_touches(tmp_path):
    """The prior's mean is 0: on a flat zero map it is the truth before any touch. A study's
    touches to the true target counted that as reached at 0 touches for adaptive (an outside
    audit, 2026-11-29), against the grid's smallest grid: no measurement, no credit."""
    from adaptive_cal.study.runner import run_study

    (tmp_path / "maps").mkdir()
    X, Y = np.meshgrid(XS, YS, indexing="ij")
    write_heightmap(tmp_path / "maps" / "zero.csv", XS, YS, 0.0 * X)
    cell = load_yaml(SIM_CELL)
    cell["simulation"]["effects"] = {}  # the map alone: a flat zero plate
    cell["simulation"]["repeatability_mm"] = 0.0
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    data = load_yaml(SIM_CELL.parent / "study-smoke.yaml")
    data.update(cell="cell.yaml", plates=1, strategies=["adaptive", "grid"],
                lower_bound={"plates": 0})
    data["plate"] = {**data["plate"], "surface_files": "maps/*.csv", "noise_std_mm": [0.002, 0.002]}
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(data))
    study, base = load_study(path)
    records = run_study(study, base, tmp_path / "ck.jsonl")
    assert {r["strategy"] for r in records} == {"adaptive", "grid"}
    for r in records:
        assert r["touches_true"] is not None and r["touches_true"] >= 1, r
