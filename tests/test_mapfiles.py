"""Height-map files as cells and studies name them (formats/mapfiles.py), after an outside audit
(2026-12-01): a coarse map with no node inside the workplane was refused with a numpy message,
a coarse map steeper than the probe reaches was taken (a 16-touch run 'true error 11,294 um'),
a study in a folder named with brackets globbed a sibling folder's maps, and a study's inline
cell read its map relative to the current folder. Oracles: a known plane; brute-force
evaluation of the bilinear map on a dense grid; the file system's own listing."""
import glob

import numpy as np
import pytest
import yaml

from adaptive_cal.cell.schema import ConfigError, load_cell, load_yaml
from adaptive_cal.formats.heightmap import load_heightmap, write_heightmap
from adaptive_cal.formats.mapfiles import beside_glob, plane_of
from adaptive_cal.study.config import load_study

from helpers import SIM_CELL

X_MM, Y_MM = (-225.0, 225.0), (-185.0, 185.0)  # sim-cell.yaml's workplane


def _map(path, xs, ys, f):
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return load_heightmap(write_heightmap(path, xs, ys, f(X, Y)))


def test_a_plane_on_a_coarse_grid_with_no_node_inside_the_workplane(tmp_path):
    """A 2 x 2 grid around the workplane covers it; its plane is the map's (bilinear reproduces
    a plane exactly), its form none."""
    hm = _map(tmp_path / "p.csv", [-300.0, 300.0], [-200.0, 200.0],
              lambda x, y: 1e-3 * x - 2e-3 * y + 0.1)
    a, b, c, form = plane_of(hm, X_MM, Y_MM)
    assert np.allclose([a, b, c], [1e-3, -2e-3, 0.1], rtol=0, atol=1e-12)
    assert form < 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_form_is_the_largest_departure_anywhere_on_the_workplane(tmp_path, seed):
    """Brute force: the departure from plane_of's plane on a 1,601 x 1,601 grid over the
    workplane never exceeds its form, and reaches it (the grid holds the node lines)."""
    rng = np.random.default_rng(seed)
    xs = rng.uniform(-300, -230) + 85.0 * np.arange(8)  # a regular grid at a random offset
    ys = rng.uniform(-250, -190) + 65.0 * np.arange(8)
    z = rng.normal(0.0, 0.05, (xs.size, ys.size))
    hm = _map(tmp_path / "p.csv", xs, ys, lambda x, y: z)
    a, b, c, form = plane_of(hm, X_MM, Y_MM)
    gx = np.unique(np.r_[np.linspace(*X_MM, 1601), hm.x_mm[np.abs(hm.x_mm) < X_MM[1]]])
    gy = np.unique(np.r_[np.linspace(*Y_MM, 1601), hm.y_mm[np.abs(hm.y_mm) < Y_MM[1]]])
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    dep = np.abs(hm(X, Y) - (a * X + b * Y + c))  # the workplane's centre is 0, 0
    assert dep.max() == pytest.approx(form, rel=1e-12, abs=1e-15)


def test_a_coarse_map_steeper_than_the_probe_reaches_is_refused_at_load(tmp_path):
    """z = 0.06 |x| on nodes at x = -300, 0, 300: 13.5 mm high at the workplane's sides. The
    map's nodes inside the workplane (x = 0 only) read it as flat; the plate stands 6.8 mm up
    on average (7.0 with sim-cell.yaml's tilt effect)."""
    _map(tmp_path / "plate.csv", [-300.0, 0.0, 300.0], [-200.0, 200.0],
         lambda x, y: 0.06 * np.abs(x) + 0 * y)
    data = load_yaml(SIM_CELL)
    data["simulation"] = {**data["simulation"], "surface_file": "plate.csv"}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"simulation.surface_file: .*plate.csv: its plane "
                                          r"stands \+7\.\d+ mm at the plate centre"):
        load_cell(tmp_path / "cell.yaml")


def test_a_study_glob_is_relative_to_its_folder_even_with_brackets_in_its_name(tmp_path):
    mine, other = tmp_path / "sdir[12]" / "maps", tmp_path / "sdir1" / "maps"
    for folder, name in ((mine, "mine.csv"), (other, "other.csv")):
        folder.mkdir(parents=True)
        (folder / name).write_text("x\n")
    found = glob.glob(beside_glob("maps/*.csv", tmp_path / "sdir[12]" / "study.yaml"))
    assert found == [str(mine / "mine.csv")]
    assert beside_glob("/abs/*.csv", tmp_path / "sdir[12]" / "study.yaml") == "/abs/*.csv"


def test_a_studys_inline_cell_reads_its_map_beside_the_study_file(tmp_path, monkeypatch):
    """An inline ``cell:`` is part of the study file: its simulation.surface_file is relative to
    that file, as a cell file's is to itself, whatever folder the command runs in."""
    folder = tmp_path / "study"
    (folder / "maps").mkdir(parents=True)
    _map(folder / "maps" / "base.csv", np.linspace(-225, 225, 10), np.linspace(-185, 185, 8),
         lambda x, y: 1e-4 * x + 0 * y)
    data = load_yaml(SIM_CELL.parent / "study-smoke.yaml")
    cell = load_yaml(SIM_CELL)
    cell["simulation"] = {**cell["simulation"], "surface_file": "maps/base.csv"}
    data["cell"] = cell
    (folder / "s.yaml").write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)  # not the study's folder
    study, base = load_study(folder / "s.yaml")
    assert base["simulation"]["surface_file"] == str(folder / "maps" / "base.csv")
