"""Figures: saved as valid PNGs, and their content (units, scale, annotations, values) is right."""
import struct

import numpy as np
import pytest
from matplotlib.collections import QuadMesh
from matplotlib.patches import Rectangle

from adaptive_cal.report import figures as plots

PLATE_X, PLATE_Y = (-225.0, 225.0), (-185.0, 185.0)


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    return len(data), width, height


def _save(fig, tmp_path, name):
    path = tmp_path / name
    fig.savefig(path, dpi=80)
    n_bytes, width, height = _png_size(path)
    assert 5_000 < n_bytes < 5_000_000
    assert 300 < width < 3000 and 200 < height < 3000
    return path


def _surface(n_touches=40, remove_tilt=True, **kw):
    x = np.linspace(*PLATE_X, 46)
    y = np.linspace(*PLATE_Y, 38)
    gx, gy = np.meshgrid(x, y, indexing="ij")
    plane = 0.014 * gx + 0.002 * gy + 2.6
    bump = 0.1 * np.exp(-((gx - 50) ** 2 + (gy + 40) ** 2) / 80**2)
    std = 0.002 + 0.01 * (np.abs(gx) / 225) ** 2
    rng = np.random.default_rng(0)
    touches = np.column_stack([rng.uniform(-200, 200, n_touches), rng.uniform(-165, 165, n_touches)])
    fig = plots.surface_figure(x, y, plane + bump, std, touches, PLATE_X, PLATE_Y,
                               keep_outs=[((-225, -150), (100, 185))], next_xy_mm=(10.0, -20.0),
                               title="round 0", remove_tilt=remove_tilt, **kw)
    return fig, dict(x=x, y=y, plane=plane, bump=bump, std=std)


def _panel(fig, label):
    return next(ax for ax in fig.axes if ax.get_label() == label)


def _mesh_um(ax):
    """The map's values at its grid nodes. The mesh is drawn ``plots.FINER`` x finer, bilinear
    between the nodes: checked here, each finer value inside the range of its cell's corners."""
    mesh = next(c for c in ax.collections if isinstance(c, QuadMesh))
    fine, k = np.asarray(mesh.get_array()), plots.FINER
    nodes = fine[::k, ::k]
    corners = np.stack([nodes[:-1, :-1], nodes[1:, :-1], nodes[:-1, 1:], nodes[1:, 1:]])
    lo, hi = corners.min(0), corners.max(0)
    tol = 1e-9 * max(1.0, np.abs(nodes).max())
    for i in range(k):
        for j in range(k):  # the finer values at offset (i, j) inside each cell
            inside = fine[i::k, j::k][: lo.shape[0], : lo.shape[1]]
            assert np.all(inside >= lo - tol) and np.all(inside <= hi + tol)
    return nodes, mesh


def test_surface_figure_saves_and_labels(tmp_path):
    fig, _ = _surface()
    _save(fig, tmp_path, "surface.png")
    mean_ax, std_ax = _panel(fig, "mean"), _panel(fig, "std")
    for ax in (mean_ax, std_ax):
        assert "(mm)" in ax.get_xlabel() and "(mm)" in ax.get_ylabel()
        assert ax.get_aspect() == 1.0
        assert ax.get_xlim() == PLATE_X and ax.get_ylim() == PLATE_Y
        hatched = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_hatch()]
        assert len(hatched) == 1
        assert hatched[0].get_x() == -225 and hatched[0].get_width() == 75
        assert hatched[0].get_y() == 100 and hatched[0].get_height() == 85
        stars = [ln for ln in ax.get_lines() if ln.get_marker() == "*"]
        assert len(stars) == 1 and tuple(stars[0].get_xydata()[0]) == (10.0, -20.0)
    bar_labels = [ax.get_ylabel() for ax in fig.axes if ax not in (mean_ax, std_ax)]
    assert len(bar_labels) == 2 and all("um" in s for s in bar_labels)
    assert "tilt removed" in fig.get_suptitle()


def test_surface_touches_numbered_in_order():
    fig, _ = _surface(n_touches=40)
    texts = [t.get_text() for t in _panel(fig, "mean").texts]
    # touches close together share one label ("3,4"): every seq once, labels in order of first touch
    assert sorted(int(s) for t in texts for s in t.split(",")) == list(range(40))
    assert [int(t.split(",")[0]) for t in texts] == sorted(int(t.split(",")[0]) for t in texts)
    assert len(_panel(fig, "std").texts) == 0


def test_surface_many_touches_markers_only():
    fig, _ = _surface(n_touches=81)
    mean_ax = _panel(fig, "mean")
    assert len(mean_ax.texts) == 0
    touches = [ln for ln in mean_ax.get_lines() if ln.get_label() == "touches"]
    assert len(touches) == 1 and len(touches[0].get_xdata()) == 81


def test_surface_values_in_um_and_tilt_removed():
    """A plane plus a bump: removing the LS plane of the map leaves bump - LS plane of the bump."""
    fig, d = _surface(remove_tilt=True)
    gx, gy = np.meshgrid(d["x"], d["y"], indexing="ij")
    design = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    coef = np.linalg.lstsq(design, d["bump"].ravel(), rcond=None)[0]
    expected_um = (d["bump"].ravel() - design @ coef).reshape(gx.shape) * 1000
    mean_um, _ = _mesh_um(_panel(fig, "mean"))
    np.testing.assert_allclose(mean_um, expected_um.T, atol=1e-9)
    std_um, _ = _mesh_um(_panel(fig, "std"))
    np.testing.assert_allclose(std_um, d["std"].T * 1000, atol=1e-12)

    fig, d = _surface(remove_tilt=False)
    mean_um, _ = _mesh_um(_panel(fig, "mean"))
    np.testing.assert_allclose(mean_um, (d["plane"] + d["bump"]).T * 1000, atol=1e-9)
    assert "tilt removed" not in fig.get_suptitle()


def test_surface_rejects_transposed_maps():
    x, y = np.linspace(0, 1, 5), np.linspace(0, 1, 4)
    with pytest.raises(ValueError, match="nx, ny"):
        plots.surface_figure(x, y, np.zeros((4, 5)), np.zeros((4, 5)), np.zeros((0, 2)),
                             (0, 1), (0, 1))


def test_convergence_figure(tmp_path):
    touches = np.arange(1, 41)
    mean_std = 0.05 / np.sqrt(touches)
    max_std = 0.12 / np.sqrt(touches)
    true_rms = 0.04 / np.sqrt(touches)
    fig = plots.convergence_figure(touches, mean_std, max_std, bound_mean_mm=0.01,
                                   bound_max_mm=0.02, true_rms_mm=true_rms)
    _save(fig, tmp_path, "convergence.png")
    ax = fig.axes[0]
    assert ax.get_yscale() == "log" and "um" in ax.get_ylabel()
    ydata = [np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()]
    np.testing.assert_allclose(ydata[0], mean_std * 1000)
    np.testing.assert_allclose(ydata[1], max_std * 1000)
    dashed = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
    assert sorted(float(ln.get_ydata()[0]) for ln in dashed) == [10.0, 20.0]
    dotted = [ln for ln in ax.get_lines() if ln.get_linestyle() == ":"]
    assert len(dotted) == 1
    np.testing.assert_allclose(dotted[0].get_ydata(), true_rms * 1000)

    bare = plots.convergence_figure(touches, mean_std, max_std)
    assert len(bare.axes[0].get_lines()) == 2


def test_residual_figure(tmp_path):
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-200, 200, 40), rng.uniform(-165, 165, 40)
    residual = rng.normal(0.002, 0.01, 40)
    fig = plots.residual_figure(x, y, residual, "round 0 residuals")
    _save(fig, tmp_path, "residual.png")
    ax, bar = fig.axes
    points = ax.collections[0]
    np.testing.assert_allclose(points.get_array(), residual * 1000)
    assert points.norm.vmin == pytest.approx(-np.abs(residual).max() * 1000)
    assert points.norm.vmax == pytest.approx(np.abs(residual).max() * 1000)
    assert points.get_cmap().name == "RdBu_r"
    assert "um" in bar.get_ylabel()
    assert "(mm)" in ax.get_xlabel() and "(mm)" in ax.get_ylabel()
    assert ax.get_aspect() == 1.0
    assert ax.get_title() == "round 0 residuals"


def test_touch_labels_are_readable_and_never_overprint():
    from adaptive_cal.report.figures import touch_labels

    xy = np.array([[0.0, 0.0], [100.0, 50.0], [100.2, 50.1], [300.0, 200.0], [0.5, 0.3]])
    labels = touch_labels(xy)
    assert [t for t, _ in labels] == ["0,4", "1,2", "3"]  # a retake joins its first touch's label
    fig, _ = _surface(n_touches=40)
    assert all(t.get_fontsize() >= 8 for t in _panel(fig, "mean").texts)


def test_a_cell_name_with_dollar_signs_is_drawn_as_typed(tmp_path):
    """An odd number of "$" used to reach matplotlib's mathtext and fail after all touches."""
    x, y = np.linspace(-200, 200, 4), np.linspace(-150, 150, 5)
    fig = plots.surface_figure(x, y, np.zeros((4, 5)), np.ones((4, 5)) * 1e-3, np.zeros((0, 2)),
                               (-200, 200), (-150, 150), title="plate $3 of 5 ($ price")
    fig.savefig(tmp_path / "s.png")  # renders the title: raises on unbalanced mathtext
    assert fig._suptitle.get_text() == r"plate \$3 of 5 (\$ price (tilt removed)"
