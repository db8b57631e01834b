"""Height maps (formats/heightmap.py) as the simulated truth and as study plates; outliers in the
simulated readings. Oracles: bilinear interpolation reproduces a bilinear function exactly; the
simulator's readings against the study's own draws; the outlier share by Monte Carlo."""
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

from adaptive_cal.cell.schema import ConfigError, load_cell, load_yaml
from adaptive_cal.formats.heightmap import (HEADER, HeightMapError, load_heightmap, parse_heightmap,
                                            write_heightmap)
from adaptive_cal.simulation.cell import SimulatedCell
from adaptive_cal.study.config import load_study
from adaptive_cal.study.plates import heights_at, plate_cell, sample_plate, truth

from helpers import SIM_CELL, sim_cell

XS = np.linspace(-225, 225, 10)
YS = np.linspace(-185, 185, 8)


def bilinear(x, y):
    return 0.3 + 1e-3 * x - 2e-3 * y + 1e-5 * x * y


def write_map(path, xs=XS, ys=YS, f=bilinear):
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return write_heightmap(path, xs, ys, f(X, Y))


def cell_with_map(tmp_path, name="plate.csv", **sim):
    data = load_yaml(SIM_CELL)
    data["simulation"] = {**data["simulation"], "surface_file": name, **sim}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_bilinear_map_is_reproduced_exactly_in_any_row_order(tmp_path):
    path = write_map(tmp_path / "m.csv")
    lines = path.read_text().splitlines()
    rng = np.random.default_rng(0)
    shuffled = [lines[0]] + [lines[1 + i] for i in rng.permutation(len(lines) - 1)]
    m = parse_heightmap("\n".join(shuffled) + "\n", "shuffled")
    x, y = rng.uniform(-225, 225, 500), rng.uniform(-185, 185, 500)
    assert np.allclose(m(x, y), bilinear(x, y), atol=1e-9)
    assert np.allclose(load_heightmap(path)(x, y), bilinear(x, y), atol=1e-9)
    assert m.covers((-225, 225), (-185, 185)) and not m.covers((-230, 225), (-185, 185))


def test_the_fast_and_the_careful_reader_give_the_same_map(tmp_path, monkeypatch):
    """A well-formed map is read by numpy's C reader; the line-by-line reader (which names a
    fault's line) is the oracle: the same nodes and heights, bit for bit, in a shuffled order."""
    import adaptive_cal.formats.heightmap as hm
    rng = np.random.default_rng(1)
    xs, ys = np.linspace(-225, 225, 91), np.linspace(-185, 185, 75)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    rows = np.column_stack([X.ravel(), Y.ravel(), rng.normal(0, 1e-2, X.size)])
    shuffled = rng.permutation(rows).tolist()
    text = HEADER + "\n" + "\n".join(f"{a!r},{b!r},{c!r}" for a, b, c in shuffled)
    fast = parse_heightmap(text + "\n", "m")
    monkeypatch.setattr(hm, "_fast_numbers", lambda _text: None)
    careful = parse_heightmap(text + "\n", "m")
    for a, b in ((fast.x_mm, careful.x_mm), (fast.y_mm, careful.y_mm), (fast.z_mm, careful.z_mm)):
        assert np.array_equal(a, b)
    assert np.array_equal(fast.z_mm, rows[:, 2].reshape(91, 75))


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_round_off_in_node_positions_is_one_node_with_any_line_ending(newline):
    """0.1 + 0.2 written beside 0.3 is the same node (a writer's round-off), not an irregular
    grid; a BOM, CRLF or old-Mac CR line ends and a trailing blank line are read alike."""
    lines = ["\ufeff" + HEADER, "0,0,1", "0.30000000000000004,0,2", "0,1,3", "0.3,1,4", ""]
    m = parse_heightmap(newline.join(lines), "m")
    assert np.allclose(m.x_mm, [0, 0.3]) and np.array_equal(m.z_mm, [[1, 3], [2, 4]])


@pytest.mark.parametrize("edit, words", [
    (lambda ls: ["x,y,z"] + ls[1:], ["line 1", "x_mm,y_mm,height_mm", "'x,y,z'"]),
    (lambda ls: ls[1:], ["line 1", HEADER]),
    (lambda ls: ls[:5] + ["-225,-132.857143,abc"] + ls[6:], ["line 6", "height_mm", "'abc'"]),
    (lambda ls: ls[:5] + ["-225,-132.857143,"] + ls[6:], ["line 6", "height_mm", "''"]),
    (lambda ls: ls[:5] + ["-225,nan,0.1"] + ls[6:], ["line 6", "y_mm", "'nan'"]),
    (lambda ls: ls[:3] + ls[4:], ["not a regular grid", "missing"]),
    (lambda ls: ls + ["-225,-185,0.2"], ["given twice", "first on line 2"]),
    (lambda ls: ls[:7] + ["1,2"] + ls[8:], ["line 8", "3 values"]),
])
def test_bad_maps_are_refused_naming_file_line_and_value(tmp_path, edit, words):
    lines = write_map(tmp_path / "m.csv").read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(edit(lines)) + "\n")
    with pytest.raises(HeightMapError) as e:
        load_heightmap(bad)
    assert str(bad) in str(e.value)
    for w in words:
        assert w in str(e.value)


def test_irregular_grid_is_refused(tmp_path):
    path = write_map(tmp_path / "m.csv", xs=np.array([-225, -100, 0, 225.0]))
    with pytest.raises(HeightMapError, match="not a regular grid: x_mm nodes 0 and 225 are 225 mm "
                       "apart, the grid's spacing is 150 mm"):
        load_heightmap(path)


def test_cell_takes_its_truth_from_a_map_relative_to_the_cell_file(tmp_path):
    write_map(tmp_path / "plate.csv")
    cell = load_cell(cell_with_map(tmp_path))
    sim = SimulatedCell.from_cell(cell)
    x, y = np.array([-100.0, 3.0, 200.0]), np.array([50.0, -7.0, 180.0])
    without = SimulatedCell.from_cell(sim_cell())
    # the map adds to simulation.effects (tilt and form of sim-cell.yaml)
    assert np.allclose(sim.surface_mm(x, y), without.surface_mm(x, y) + bilinear(x, y))


def test_a_map_that_does_not_cover_the_workplane_is_refused(tmp_path):
    write_map(tmp_path / "plate.csv", xs=np.linspace(-200, 225, 10))
    with pytest.raises(ConfigError) as e:
        load_cell(cell_with_map(tmp_path))
    msg = str(e.value)
    assert "simulation.surface_file" in msg and "plate.csv" in msg and "does not cover" in msg
    assert "x_mm=[-200, 225]" in msg
    assert msg.count("simulation.surface_file") == 1, msg  # the key once, not "key: key: ..."


def test_a_missing_map_is_refused_naming_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"simulation.surface_file: .*nope.csv: cannot read"):
        load_cell(cell_with_map(tmp_path, "nope.csv"))


@pytest.mark.parametrize("rate", [0.5, -0.01, 0.9])
def test_outlier_rate_outside_zero_to_half_is_refused_naming_the_key(rate):
    with pytest.raises(ConfigError, match="simulation.outlier_rate"):
        sim_cell(simulation={"outlier_rate": rate})


def _readings(cell, n):
    sim = SimulatedCell.from_cell(cell)
    out = []
    for k in range(n):
        sim.move_to(10.0 * (k % 7), -5.0 * (k % 5), 0.0)
        out.append(sim.read().reading_mm)
    return np.array(out)


def test_outliers_replace_the_stated_share_and_leave_other_readings_as_they_were():
    n, rate = 3000, 0.2
    clean = _readings(sim_cell(), n)
    dirty = _readings(sim_cell(simulation={"outlier_rate": rate, "outlier_mm": 1.0}), n)
    hit = np.abs(dirty - clean) > 1e-9
    # the other draws are untouched: readings without a gross error are bit-for-bit the same
    assert np.array_equal(dirty[~hit], clean[~hit])
    # Monte Carlo: share within 4.5 binomial sigma of the rate (|N(0, 1 mm)| < 1e-9: never)
    assert abs(hit.mean() - rate) < 4.5 * np.sqrt(rate * (1 - rate) / n)
    assert 0.8 < np.std(dirty[hit] - clean[hit]) < 1.2


@pytest.mark.parametrize("dof", [2, 1.5, 0])
def test_student_t_noise_needs_more_than_two_degrees_of_freedom(dof):
    with pytest.raises(ConfigError, match="simulation.noise_dof"):
        sim_cell(simulation={"noise_dof": dof})


@pytest.mark.parametrize("dof", [3.0, 6.0])
def test_student_t_noise_is_t_distributed_with_the_stated_standard_deviation(dof):
    n, std = 3000, 0.05
    still = {"repeatability_mm": 0.0, "xy_repeatability_mm": 0.0}
    clean = _readings(sim_cell(simulation={**still, "noise_std_mm": 0.0}), n)
    noisy = _readings(sim_cell(simulation={**still, "noise_std_mm": std, "noise_dof": dof}), n)
    # oracle: scipy's Student-t, scaled so that its standard deviation is noise_std_mm; the
    # probe's 0.1 um resolution is 0.3 % of the scale, far below the KS test's resolution here
    z = (noisy - clean) / (std * np.sqrt((dof - 2) / dof))
    assert stats.kstest(z, stats.t(dof).cdf).pvalue > 1e-3
    # and it is not the Gaussian of the same standard deviation
    assert stats.kstest((noisy - clean) / std, stats.norm.cdf).pvalue < 1e-3


@pytest.mark.parametrize("noise", [{"outlier_rate": 0.3, "outlier_mm": 0.5},
                                   {"noise_dof": 3.0, "noise_std_mm": 0.05, "outlier_rate": 0.02}])
def test_study_designs_see_the_simulators_readings_outliers_included(tmp_path, noise):
    write_map(tmp_path / "plate.csv")
    cell = load_cell(cell_with_map(tmp_path, repeatability_mm=0.0, **noise))
    sim = SimulatedCell.from_cell(cell)
    xy = np.array([[-200.0 + 10 * k, 150.0 - 7 * k] for k in range(40)])  # inside the stroke
    read = []
    for x, y in xy:
        sim.move_to(x, y, 0.0)
        read.append(sim.read().reading_mm - cell.probe.zero_mm)
    expected = heights_at(cell, xy)
    assert np.allclose(read, expected, atol=1.01e-4)  # the probe's resolution
    assert np.ptp(np.array(read) - truth(cell)(xy[:, 0], xy[:, 1])) > 0.1  # the errors are there


def _study(tmp_path, files):
    maps = tmp_path / "maps"
    maps.mkdir()
    for i in range(files):
        write_map(maps / f"p{i}.csv", f=lambda x, y, i=i: bilinear(x, y) + 0.01 * i)
    data = load_yaml(SIM_CELL.parent / "study-smoke.yaml")
    data["cell"] = str(SIM_CELL)
    data["plate"] = {**data["plate"], "surface_files": "maps/p*.csv"}
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_study_plates_are_the_maps_in_turn_with_noise_drawn_as_before(tmp_path):
    study, base = load_study(_study(tmp_path, 2))
    no_maps = study.plate.model_copy(update={"surface_files": None})
    plain = study.model_copy(update={"plate": no_maps})
    for i in range(3):
        p, q = sample_plate(study, i), sample_plate(plain, i)
        assert p.surface_file.endswith(f"p{i % 2}.csv") and p.effects == {}
        assert (p.noise_std_mm, p.seed) == (q.noise_std_mm, q.seed)
        cell = plate_cell(study, base, p)
        # the base cell's effects (sim-cell.yaml's tilt and form) add on top (DESIGN.md)
        effects = SimulatedCell.from_cell(sim_cell()).surface_mm(0.0, 0.0)
        assert np.isclose(truth(cell)(0.0, 0.0), bilinear(0.0, 0.0) + 0.01 * (i % 2) + effects)


def test_study_glob_matching_nothing_or_a_bad_map_is_refused(tmp_path):
    path = _study(tmp_path, 1)
    (tmp_path / "maps" / "p1.csv").write_text("x_mm,y_mm,height_mm\n0,0,1\n")
    with pytest.raises(ConfigError, match=r"plate.surface_files: .*p1.csv: x_mm takes one value"):
        load_study(path)
    data = load_yaml(path)
    data["plate"]["surface_files"] = "nothing/*.csv"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"plate.surface_files=.*nothing/\*.csv' matches no file"):
        load_study(path)


def test_study_map_beyond_the_probes_reach_is_refused_naming_it(tmp_path):
    """A map 6 mm above the nominal plate, or 100 m: every touch at the stroke's end. Refused
    at load as a drawn plate is (``check_feasible``), naming the file and what is out of reach;
    before, such a study ran (the 100 m map reported a true RMS of 5e7 um)."""
    path = _study(tmp_path, 1)
    write_map(tmp_path / "maps" / "p1.csv", f=lambda x, y: bilinear(x, y) + 6.0)
    with pytest.raises(ConfigError, match=r"p1.csv is beyond the probe's reach: .* a height of "
                                          r"\+6\.\d+ mm at the plate centre"):
        load_study(path)
    write_map(tmp_path / "maps" / "p1.csv",  # an 8 mm bump: more form than the stroke holds
              f=lambda x, y: bilinear(x, y) + 8.0 * np.exp(-(x * x + y * y) / 100.0 ** 2))
    with pytest.raises(ConfigError, match=r"p1.csv is beyond the probe's reach: .* and [5-9]\.\d+ "
                                          r"mm of form about it") as e:
        load_study(path)
    assert "in um?" not in str(e.value)
    write_map(tmp_path / "maps" / "p1.csv",  # a plate's heights written in um: +-300 "mm"
              f=lambda x, y: 1e3 * 0.3 * (x / 225.0) ** 2)
    with pytest.raises(ConfigError, match=r"heights in um\? a map's heights are mm"):
        load_study(path)


def test_set_surface_files_is_relative_to_the_study_file_as_in_the_file(tmp_path, monkeypatch):
    """--set plate.surface_files=maps/p*.csv names the maps as the study file would: relative
    to the study file, not to the folder the command runs in (which found nothing)."""
    from adaptive_cal.study.overrides import apply_overrides
    path = _study(tmp_path, 2)
    study, base = load_study(path)
    monkeypatch.chdir(tmp_path.parent)  # elsewhere
    moved = apply_overrides(study, base, settings=["plate.surface_files=maps/p1.csv"],
                            study_path=path)
    assert moved.plate.surface_files == str(tmp_path / "maps" / "p1.csv")


def test_an_empty_map_name_is_refused_as_empty_not_as_a_folder(tmp_path):
    data = load_yaml(SIM_CELL)
    data["simulation"] = {**data["simulation"], "surface_file": ""}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"simulation.surface_file: String should have at least "
                                          r"1 character \(got ''\)"):
        load_cell(path)


def test_a_run_folder_keeps_a_relative_map_findable(tmp_path):
    """The run folder's copy of the cell names the map by an absolute path: --resume and report
    read the cell from the run folder, where the relative name would not resolve."""
    from adaptive_cal.cli.run import _copy_cell

    (tmp_path / "maps").mkdir()
    write_map(tmp_path / "maps" / "plate.csv")
    cell_path = cell_with_map(tmp_path, name="maps/plate.csv")
    out = tmp_path / "runs" / "a"
    out.mkdir(parents=True)
    _copy_cell(out, cell_path)
    copied = load_cell(out / "cell.yaml")
    assert copied.simulation.surface_file == str((tmp_path / "maps" / "plate.csv").resolve())
    x, y = np.array([-100.0, 200.0]), np.array([50.0, 180.0])
    assert np.allclose(SimulatedCell.from_cell(copied).surface_mm(x, y),
                       SimulatedCell.from_cell(load_cell(cell_path)).surface_mm(x, y))


def test_a_folder_given_as_the_map_is_refused_naming_the_key(tmp_path):
    (tmp_path / "plate.csv").mkdir()  # a folder where the file should be
    with pytest.raises(ConfigError) as e:
        load_cell(cell_with_map(tmp_path))
    msg = str(e.value)
    assert "simulation.surface_file: " in msg and "plate.csv: a folder, not a height map" in msg
    assert "Is a directory" not in msg
    (tmp_path / "s").mkdir()
    path = _study(tmp_path / "s", 1)
    (tmp_path / "s" / "maps" / "p9.csv").mkdir()  # the glob maps/p*.csv matches a folder too
    with pytest.raises(ConfigError, match=r"plate\.surface_files: .*p9\.csv: a folder, not a "):
        load_study(path)


def test_a_map_with_more_columns_is_refused_saying_how_to_write_one():
    # DESIGN.md fixes the header to exactly x_mm,y_mm,height_mm (a stable format): the reader
    # stays strict and points at compensate --grid --heights-only
    text = "x_mm,y_mm,height_mm,std_mm\n0,0,1,0.001\n"
    with pytest.raises(HeightMapError, match=r"line 1: expected the header .*--heights-only"):
        parse_heightmap(text, "g.csv")


def test_study_glob_double_star_matches_every_depth_and_records_name_their_map(tmp_path):
    # '**' is any depth of folders, none included (glob's recursive form): the maps at the top,
    # one and two levels down are all plates, not only those exactly one level down
    from adaptive_cal.study.config import surface_files
    from adaptive_cal.study.tasks import _Reported

    path = _study(tmp_path, 1)
    for sub in ("a", "a/b"):
        (tmp_path / "maps" / sub).mkdir()
        write_map(tmp_path / "maps" / sub / "p.csv", f=bilinear)
    data = load_yaml(path)
    data["plate"]["surface_files"] = "maps/**/p*.csv"
    path.write_text(yaml.safe_dump(data))
    study, _ = load_study(path)
    names = [Path(f).relative_to(tmp_path / "maps").as_posix() for f in surface_files(study)]
    assert names == ["a/b/p.csv", "a/p.csv", "p0.csv"]
    seen = []
    out = _Reported(seen.append, {"surface_file": "maps/a/p.csv"})
    out.append({"strategy": "adaptive"})
    assert out[0]["surface_file"] == seen[0]["surface_file"] == "maps/a/p.csv"


@pytest.mark.parametrize("height, words", [
    # the map's plane 8 mm up (sim-cell's tilt effect adds c = 0.2): past the +-4.5 mm stroke
    (lambda x, y: 8.0 + 0 * x, ["+8.200 mm at the plate centre (with the tilt effect's c)",
                                "+-4.5 mm", "(heights in um? a map's are mm)"]),
    # a map in um read as mm: 15 um of offset and +-50 um of form
    (lambda x, y: 15.0 + 50.0 * np.sin(x / 40.0), ["+15.", "heights in um?"]),
    # one node 999 mm high: its form is far past 20 x the stroke's half
    (lambda x, y: np.where((x == XS[4]) & (y == YS[3]), 999.0, 0.0), ["form 9", "heights in um?"]),
])
def test_a_simulated_map_out_of_the_probes_reach_is_refused_before_a_touch(tmp_path, height, words):
    """An outside audit (2026-11-30): a map in um by mistake made one touch past the stroke, then
    a message that never named the map; a 999 mm spike ran to a 'true error' of 34 mm."""
    write_map(tmp_path / "plate.csv", f=height)
    with pytest.raises(ConfigError) as e:
        load_cell(cell_with_map(tmp_path))
    msg = str(e.value)
    assert "simulation.surface_file: " in msg and "plate.csv" in msg
    for w in words:
        assert w in msg, msg


def test_a_map_a_few_mm_off_that_the_probe_still_reaches_is_taken(tmp_path):
    write_map(tmp_path / "plate.csv", f=lambda x, y: 3.0 + 1e-3 * x)
    assert load_cell(cell_with_map(tmp_path)).simulation.surface_file.endswith("plate.csv")


def test_gross_errors_of_no_size_are_refused_naming_both_keys():
    with pytest.raises(ConfigError, match="outlier_mm: 0 with outlier_rate 0.1"):
        sim_cell(simulation={"outlier_rate": 0.1, "outlier_mm": 0.0})
    assert sim_cell(simulation={"outlier_rate": 0.0, "outlier_mm": 0.0}).simulation.outlier_mm == 0


@pytest.mark.parametrize("header, hint", [
    ("x_mm;y_mm;height_mm", "separated by ';'"),
    ("x_mm\ty_mm\theight_mm", "separated by tabs"),
    ("X_MM,Y_MM,HEIGHT_MM", "lower case and the heights mm"),
    ("x_mm,y_mm,height_um", "lower case and the heights mm"),
    ("x_mm,y_mm,height_mm,", "the comma at its end makes an empty fourth column"),
])
def test_a_wrong_header_says_what_is_wrong_with_it(header, hint):
    with pytest.raises(HeightMapError, match="line 1: expected the header") as e:
        parse_heightmap(header + "\n0,0,1\n", "g.csv")
    assert hint in str(e.value)


def test_what_reads_a_run_leaves_out_a_map_edited_past_use_and_says_so(tmp_path, capsys):
    """report, flatness and compensate read the run's belief, not the simulated truth: a map
    gone since the run was left out with a note, but one edited past use stopped them."""
    from adaptive_cal.cell.run_cell import load_run_cell

    lines = write_map(tmp_path / "plate.csv").read_text().splitlines()
    path = cell_with_map(tmp_path)
    assert load_run_cell(path).simulation.surface_file.endswith("plate.csv")
    (tmp_path / "plate.csv").write_text("\n".join(lines[:5] + ["-225,-132.857143,abc"]
                                                  + lines[6:]) + "\n")
    with pytest.raises(ConfigError, match="line 6"):
        load_cell(path)  # --resume simulates on: it needs the map
    cell = load_run_cell(path)
    assert cell.simulation.surface_file is None
    err = capsys.readouterr().err
    assert "plate.csv cannot be used now" in err and "line 6" in err and "left out" in err
    (tmp_path / "plate.csv").unlink()
    assert load_run_cell(path).simulation.surface_file is None
    assert "plate.csv is gone; left out" in capsys.readouterr().err
