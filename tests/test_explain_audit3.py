"""explain on degenerate input, from an outside audit (/tmp/audit3-explain):

- touches on one line not parallel to an axis, or at two points, were calibrated (a tilt of
  87 deg, or ``unexplained`` at p 0.9999997); the projector of a rank-deficient nuisance did not
  span it;
- readings exactly the nominal crashed (ZeroDivisionError); identical readings reported a serial
  correlation and "1e14 sigma" computed on 1e-17 round-off;
- explain() in memory let through what the reader refuses (IndexError, NaN in the findings).
"""
import json
import warnings

import numpy as np
import pytest

from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.evidence import Projector
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.formats.recording import Recording, RecordingError

CELL = """name: audit cell
workplane: {x_mm: [-225, 225], y_mm: [-185, 185], edge_margin_mm: 10}
robot: {adapter: sim, base_xy_mm: [0, -650], touch_time_s: 3}
probe: {adapter: sim, stroke_mm: 10, usable_mm: [0.5, 9.5], zero_mm: 5.0,
        resolution_mm: 0.0001, noise_std_mm: 0.005}
simulation:
  seed: 0
  effects: {tilt: {a: 0.0, b: 0.0, c: 0.0}}
  unknown: [tilt]
  noise_std_mm: 0.005
"""


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    path = tmp_path_factory.mktemp("cell") / "cell.yaml"
    path.write_text(CELL)
    return load_cell(path)


def _serpentine(nx=12, ny=6):
    xs, ys = np.linspace(-210, 210, nx), np.linspace(-170, 170, ny)
    return np.array([(x, y) for j, y in enumerate(ys) for x in (xs if j % 2 == 0 else xs[::-1])])


def _rec(P, reading, **k):
    n = len(P)
    cols = dict(seq=np.arange(n), t_s=3.0 * np.arange(n), x_mm=P[:, 0].copy(),
                y_mm=P[:, 1].copy(), z_mm=np.zeros(n), reading_mm=reading)
    cols.update(k)
    return Recording(**cols)


def _plane(P, rng, noise=0.005):
    return 0.004 * P[:, 0] - 0.003 * P[:, 1] + 5.1 + noise * rng.standard_normal(len(P))


def _strict(findings):
    def bad(c):
        raise ValueError(f"non-JSON constant {c}")
    return json.loads(json.dumps(findings), parse_constant=bad)


# 1. touches on one line --------------------------------------------------------------------

def test_touches_on_a_diagonal_line_are_refused_naming_the_line(cell):
    d = np.linspace(-150, 150, 72)
    P = np.column_stack([d, 0.5 * d])
    with pytest.raises(RecordingError, match=r"lie on the line y = 0\.5 x \(columns x_mm, y_mm\)"):
        explain(_rec(P, _plane(P, np.random.default_rng(5))), cell)


def test_touches_at_two_points_are_refused_naming_them(cell):
    P = np.array([[0, 0], [100, 100]] * 6, float)
    with pytest.raises(RecordingError, match=r"two points only, \(0, 0\) and \(100, 100\), "
                                             r"on y = x"):
        explain(_rec(P, _plane(P, np.random.default_rng(5))), cell)


def test_touches_nearly_on_one_line_are_refused_and_a_thin_strip_is_not(cell):
    rng = np.random.default_rng(3)
    d = np.linspace(-150, 150, 72)
    near = np.column_stack([d, 0.5 * d + 0.01 * rng.standard_normal(72)])  # 10 um across 335 mm
    with pytest.raises(RecordingError, match="within .* um RMS of the line y = 0.5 x"):
        explain(_rec(near, _plane(near, rng)), cell, identifiability=False)
    strip = np.column_stack([d, 0.5 * d + np.tile([-1.0, 1.0], 36)])  # 2 mm wide: an area
    assert explain(_rec(strip, _plane(strip, rng)), cell, identifiability=False).findings


def test_the_line_test_is_flatness_s():
    from adaptive_cal.analysis import flatness_intervals
    from adaptive_cal.analysis.explain import layout
    assert layout.LINE_RATIO == flatness_intervals.LINE_RATIO


def test_the_projector_spans_a_rank_deficient_nuisance():
    x = np.array([0, 100.0] * 6)
    N = np.column_stack([x, x, np.ones_like(x)])
    P = Projector.of(N)
    assert P.rank == 2 and np.abs(P(N)).max() < 1e-10


def test_the_projector_of_a_full_rank_nuisance_is_unchanged():
    P = _serpentine()
    N = np.column_stack([P, np.ones(len(P)), P[:, 0] ** 2])
    q, _ = np.linalg.qr(N)
    a = np.random.default_rng(0).standard_normal((len(P), 3))
    assert np.abs(Projector.of(N)(a) - (a - q @ (q.T @ a))).max() < 1e-12


def test_a_test_on_columns_the_nuisance_spans_has_no_degrees_of_freedom(cell):
    """The indication of a level plate, given position, is round-off: not tested (it was a
    p-value drawn from the round-off)."""
    P = _serpentine()
    f = explain(_rec(P, _plane(P, np.random.default_rng(1))), cell).findings
    assert f["mismatch"]["by"]["indication"]["p_value_given_position"] == 1.0


# 2, 3. readings exactly the nominal, or identical -----------------------------------------

def test_readings_exactly_the_nominal_give_none_readout_limited(cell):
    P = _serpentine()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning either
        f = _strict(explain(_rec(P, np.full(len(P), 5.0)), cell).findings)
    assert f["verdict"] == "none" and f["readout_limited"]["rms_mm"] == 0.0
    assert all(c["log_bayes_factor"] == 0.0 for c in f["candidates"])
    assert f["readings"]["noise"]["distribution"] == "gaussian"
    assert "sigma" not in json.dumps(f["not_identifiable"])


def test_identical_readings_report_no_structure_of_round_off(cell):
    P = _serpentine()
    f = _strict(explain(_rec(P, np.full(len(P), 5.123456)), cell).findings)
    assert f["verdict"] == "none" and "readout_limited" in f
    s = f["structure_after_model"]
    assert s["tests"] == {} and "finding" not in s and "readout" in s["note"]
    assert "serial" not in f["readings"]["noise"]
    assert "sigma" not in json.dumps(f["not_identifiable"])


# 4. explain() in memory ----------------------------------------------------------------------

@pytest.mark.parametrize("change, match", [
    (dict(reading_mm=np.ones(69)), "column reading_mm has 69 values and seq has 72"),
    (dict(flags=(frozenset({"rejected"}),)), "flags has 1 entries for 72 touches"),
    (dict(reading_mm=np.r_[1e200, np.ones(71)]), r"row 0 \(seq 0\): column reading_mm = 1e\+200"),
    (dict(x_mm=np.r_[2e4, np.zeros(71)]), r"column x_mm = 20000 is beyond \+-10000"),
    (dict(t_s=np.r_[np.inf, np.arange(71.0)]), "column t_s = inf is beyond"),
    (dict(t_s=np.r_[-1.0, np.arange(71.0)]), "column t_s = -1 is negative"),
    (dict(seq=np.zeros(72, int)), "row 1: column seq = 0 does not increase after row 0's 0"),
    (dict(seq=np.arange(72) + 0.5), "column seq = 0.5 is not a non-negative integer"),
    (dict(x_mm=np.zeros((72, 2))), r"column x_mm has shape \(72, 2\)"),
])
def test_what_the_reader_refuses_is_refused_in_memory(cell, change, match):
    P = _serpentine()
    with pytest.raises(RecordingError, match=match):
        explain(_rec(P, _plane(P, np.random.default_rng(0)), **change), cell)


def test_seq_restarts_in_each_round_of_one_recording(cell):
    P = _serpentine()
    rng = np.random.default_rng(4)
    rec = _rec(np.vstack([P, P]), np.r_[_plane(P, rng), _plane(P, rng)],
               seq=np.r_[np.arange(72), np.arange(72)], t_s=3.0 * np.arange(144))
    rec = Recording(**{**rec.__dict__, "extra": {"round": np.repeat([0.0, 1.0], 72)}})
    assert len(explain(rec, cell, identifiability=False).findings["calibration"]) == 2


def test_plain_lists_are_taken_as_arrays(cell):
    P = _serpentine()
    rng = np.random.default_rng(0)
    a = explain(_rec(P, _plane(P, rng)), cell, identifiability=False).findings
    lists = _rec(P, _plane(P, np.random.default_rng(0)))
    lists = Recording(*(list(getattr(lists, c)) for c in
                        ("seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm")))
    b = explain(lists, cell, identifiability=False).findings
    assert a["verdict"] == b["verdict"] and a["calibration"] == b["calibration"]


@pytest.mark.parametrize("threshold", [float("nan"), float("inf"), "1", None, True])
def test_the_threshold_must_be_a_finite_number(cell, threshold):
    P = _serpentine()
    with pytest.raises(ValueError, match=f"threshold = {threshold!r}"):
        explain(_rec(P, _plane(P, np.random.default_rng(0))), cell, threshold=threshold)
