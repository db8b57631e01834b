"""benchmarks/plates/generate.py: independent of adaptive_cal (imports and modules loaded),
deterministic, maps in the DESIGN.md format covering the cell's workplane, and each family's
feature as published (sizes checked against the stated figures; the rough field's std and its
Matern-3/2 correlation at one length scale by Monte Carlo over plates)."""
import ast
import subprocess
import sys

import numpy as np
import pytest

from adaptive_cal.cell.schema import load_cell
from adaptive_cal.formats.heightmap import load_heightmap

from helpers import ROOT, SIM_CELL

GEN = ROOT / "benchmarks" / "plates" / "generate.py"
sys.path.insert(0, str(GEN.parent))
import generate  # noqa: E402

UM = 1e-3


def test_generator_imports_only_numpy_scipy_yaml_and_the_stdlib():
    tree = ast.parse(GEN.read_text())
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            roots.add((node.module or "").split(".")[0])
    third_party = roots - set(sys.stdlib_module_names) - {"__future__"}
    assert third_party <= {"numpy", "scipy", "yaml"}, third_party
    code = (f"import sys; sys.path.insert(0, {str(GEN.parent)!r}); import generate; "
            "generate.plate('rough', 0, 1, *generate.workplane()); "
            "print(sorted(m for m in sys.modules if m.startswith('adaptive_cal')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_written_maps_load_cover_the_workplane_and_are_deterministic(tmp_path):
    fams = ("dent", "seam")
    m1 = generate.generate(tmp_path / "a", 2, fams)
    m2 = generate.generate(tmp_path / "b", 2, fams)
    assert m1["plates"] == m2["plates"]
    wp = load_cell(SIM_CELL).workplane
    for name in m1["plates"]:
        a = (tmp_path / "a" / name).read_text()
        assert a == (tmp_path / "b" / name).read_text()
        assert a.startswith("x_mm,y_mm,height_mm\n")
        assert load_heightmap(tmp_path / "a" / name).covers(wp.x_mm, wp.y_mm)
    first, second = (tmp_path / "a/dent/plate-000.csv", tmp_path / "a/dent/plate-001.csv")
    assert first.read_text() != second.read_text()


@pytest.mark.parametrize("family", generate.FAMILIES)
def test_every_plate_is_tilted_within_one_degree(family):
    x_mm, y_mm = generate.workplane()
    for i in range(3):
        xs, ys, z, d = generate.plate(family, i, 5, x_mm, y_mm)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        coef = np.linalg.lstsq(np.column_stack([X.ravel(), Y.ravel(), np.ones(X.size)]),
                               z.ravel(), rcond=None)[0]
        # form and features tilt the least-squares plane a little (< 5e-4: 0.03 deg)
        assert np.all(np.abs(coef[:2]) < np.tan(np.radians(1.0)) + 5e-4)
        assert np.allclose(coef[:2], [d["slope_x"], d["slope_y"]], atol=5e-4)


def _feature(family, i=0):
    x_mm, y_mm = generate.workplane()
    xs, ys = generate.grid(x_mm, y_mm)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return X, Y, *generate.feature(family, np.random.default_rng([9, i]), X, Y, x_mm, y_mm)


def test_features_have_the_stated_sizes():
    _, _, h, d = _feature("dent")
    assert np.isclose(h.min(), -30 * UM)  # centred on a node: the map holds the full depth
    assert np.sum(h < -1e-12) * 25.0 <= np.pi * 20.0**2 * 1.2  # inside radius 20 mm
    X, Y, h, _ = _feature("edge")
    assert np.isclose(h.min(), -20 * UM) and h[45, 37] == 0.0  # the corner, the centre
    assert np.all(h[(np.abs(X) < 225 - 25) & (np.abs(Y) < 185 - 25)] == 0.0)
    _, _, h, _ = _feature("ripple")
    assert 5.5 * UM < h.max() <= 6 * UM and -6 * UM <= h.min() < -5.5 * UM
    _, _, h, d = _feature("seam")
    assert set(np.unique(np.abs(h))) == {0.0, 15 * UM}


def test_rough_field_has_20_um_std_and_matern_correlation_at_its_length_scale():
    """Matern-3/2 at lag r = l: (1 + sqrt 3) exp(-sqrt 3) = 0.483. Pooled over 12 plates; the
    bounds (+-15 % on the std, +-0.1 on the correlation) allow for the spatial averaging of one
    450 x 370 mm plate at a 60 mm length scale."""
    var, corr = [], []
    for i in range(12):
        _, _, h, _ = _feature("rough", i)
        var.append(np.mean(h**2))
        lag = 12  # 12 x 5 mm = 60 mm
        corr.append(np.mean(h[:-lag] * h[lag:]))
    std = np.sqrt(np.mean(var))
    assert 17 * UM < std < 23 * UM
    assert abs(np.mean(corr) / np.mean(var) - (1 + np.sqrt(3)) * np.exp(-np.sqrt(3))) < 0.1


def test_noisy_family_states_student_t_noise_with_1_to_2_percent_outliers():
    x_mm, y_mm = generate.workplane()
    spec = generate.plate("noisy", 0, 3, x_mm, y_mm)[3]["noise"]
    assert spec["kind"] == "student_t" and spec["dof"] == 3.0
    assert 0.01 <= spec["outlier_rate"] <= 0.02
    e = generate.reading_noise_mm(spec, np.random.default_rng(0), 200_000)
    from scipy import stats

    r = spec["outlier_rate"]
    share = np.mean(np.abs(e) > 0.03)
    # oracle: t3 tail beyond 30 um, plus the gross errors beyond it (P(|N(0, 50 um)| > 30 um))
    expected = (1 - r) * 2 * stats.t.sf(0.03 / spec["scale_mm"], 3) + r * 2 * stats.norm.sf(0.6)
    assert abs(share - expected) < 0.0015
