"""explain's speed (issue 15, item 8): the vectorised searches give the answers of the plain loops
they replace (kept here as slow references), and bad input of any size gets a clear message.

The figures against the targets are printed by benchmarks/bench_explain_speed.py.
"""
import numpy as np
import pytest

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import (DEFECT_MAX_SHARE, DEFECT_MIN_TOUCHES,
                                                      DEFECT_MIN_WEIGHT, Context, bump_candidate,
                                                      bump_record, nameable_reach, prior_grid,
                                                      score_effect)
from adaptive_cal.analysis.explain.evidence import log_evidence_columns_mixture
from adaptive_cal.analysis.explain.design import build_design
from adaptive_cal.analysis.explain.identify import _approach_plane, _gap_touches
from adaptive_cal.analysis.explain.locate import peaks, smoothing_grid, where
from adaptive_cal.formats.recording import Recording
from adaptive_cal.effects.plate import defect_regressor_sparse
from adaptive_cal.simulation.concealed import WORKPLANE, ZERO_MM, generator_cell, serpentine


def _recording(x, y, seed=0, rounds=1, path="speed"):
    rng = np.random.default_rng(seed)
    out = []
    for r in range(rounds):
        n = x.size
        reading = ZERO_MM + 0.002 * x - 0.001 * y + 0.005 * rng.standard_normal(n)
        out.append(Recording(np.arange(n), 4.0 * np.arange(n), x, y, np.zeros(n), reading,
                             path=f"{path}-{r}"))
    return out


def _designs():
    rng = np.random.default_rng(7)
    sx, sy = serpentine(10, 4)
    gx, gy = serpentine(16, 12, raster=True)
    return {
        "random 300": _recording(rng.uniform(*WORKPLANE["x_mm"], 300),
                                 rng.uniform(*WORKPLANE["y_mm"], 300), 1),
        "S-path 10 x 4": _recording(sx, sy, 2),
        "S-path, 3 rounds": _recording(sx, sy, 3, rounds=3),
        "raster 16 x 12": _recording(gx, gy, 4),
        "random 40": _recording(rng.uniform(*WORKPLANE["x_mm"], 40),
                                rng.uniform(*WORKPLANE["y_mm"], 40), 5),
    }


def _gap_touches_loop(ctx, count=4):
    """The loop before issue 15 item 8 (the reference): distances to every touch, every time;
    the fill distance over the whole plate, the touches among the places the cell allows, each
    at the height of the plane fitted to the last round (``identify._approach_plane``)."""
    d = ctx.design
    gx, gy = effects.defect_centres(d.geometry, 10.0)
    px, py = list(d.features.x_mm), list(d.features.y_mm)
    fill0 = float(np.max(np.min(np.hypot(gx[:, None] - np.asarray(px),
                                         gy[:, None] - np.asarray(py)), 1)))
    if d.allows is not None:
        ok = np.array([d.allows(float(x), float(y)) for x, y in zip(gx, gy)], bool)
        gx, gy = gx[ok], gy[ok]
    (a, b, c), indication = _approach_plane(d)
    touches = []
    for k in range(count):
        dist = np.min(np.hypot(gx[:, None] - np.asarray(px), gy[:, None] - np.asarray(py)), 1)
        i = int(np.argmax(dist))
        touches.append({"x_mm": float(gx[i]), "y_mm": float(gy[i]),
                        "z_mm": round(float(a * gx[i] + b * gy[i] + c - indication), 4),
                        "order": int((d.round_index == d.rounds - 1).sum()) + k})
        px.append(gx[i]), py.append(gy[i])
    return {"touches": touches, "fill_distance_mm": fill0}


@pytest.fixture(scope="module")
def contexts():
    cell = generator_cell()
    return {name: Context.of(build_design(recs, cell)) for name, recs in _designs().items()}


def test_gap_touches_equal_the_loop(contexts):
    """Same touches, same order, same fill distance (exactly) on random, S-path, multi-round
    (every position three times) and raster designs."""
    for name, ctx in contexts.items():
        fast, slow = _gap_touches(ctx), _gap_touches_loop(ctx)
        assert fast["touches"] == slow["touches"], name
        assert fast["fill_distance_mm"] == slow["fill_distance_mm"], name
        assert fast["fill_distance_mm"] > 0.0


def _nameable_reach_dense(X):
    """The dense form before issue 15 item 8 (the reference)."""
    w2 = X * X
    total = w2.sum(axis=0)
    lone = w2.max(axis=0, initial=0.0) > DEFECT_MAX_SHARE * np.maximum(total, 1e-300)
    return np.where(lone, 0, np.count_nonzero(X >= DEFECT_MIN_WEIGHT, axis=0))


def _centres_dense(ctx, effect):
    """``candidates._centres`` before issue 15 item 8 (the reference): dense touches x centres
    chunks, each projected; the prior and the candidate from the evidences are the shared
    ``bump_record`` / ``bump_candidate``."""
    d = ctx.design
    taus = prior_grid(effect, effect.searched)
    records, classes = [], 0
    radii = effect.grid(d.features, d.geometry)["radius_mm"]
    chunk = max(1, int(min(2_000_000 // max(d.n, 1), 400_000 // taus.size)))
    for radius in radii:
        radius = float(radius)
        gx, gy = effects.defect_centres(d.geometry, radius)
        lz = np.empty(gx.size)
        bt = np.empty(gx.size, int)
        counts, named = [], []
        for s in range(0, gx.size, chunk):
            X = effects.defect_regressor_grid(d.features, gx[s:s + chunk], gy[s:s + chunk], radius)
            seen = np.flatnonzero(_nameable_reach_dense(X) >= DEFECT_MIN_TOUCHES)
            lz[s:s + chunk], bt[s:s + chunk] = ctx.log_z0, 0
            counts.append(np.count_nonzero(X, axis=0))
            named.append(np.isin(np.arange(X.shape[1]), seen))
            if seen.size:
                lz[s + seen], bt[s + seen] = log_evidence_columns_mixture(
                    ctx.project(X[:, seen]), ctx.yt, taus, ctx.m)
        named = np.concatenate(named)
        classes += int(np.count_nonzero(named))
        records.append(bump_record(radius, gx, gy, lz, bt, np.concatenate(counts), named,
                                   len(radii)))
    return bump_candidate(ctx, effect, records, classes, taus)


def test_sparse_defect_regressor_is_the_dense_one():
    """The same numbers, entry for entry (exactly), and no stored zeros."""
    rng = np.random.default_rng(3)
    (x0, x1), (y0, y1) = WORKPLANE["x_mm"], WORKPLANE["y_mm"]
    x = np.concatenate([rng.uniform(x0, x1, 500), [x0, x1, x0, x1, 0.0, 0.0]])
    y = np.concatenate([rng.uniform(y0, y1, 500), [y0, y1, y1, y0, 0.0, 0.0]])  # corners, twice
    n = x.size
    f = effects.Features(x, y, np.arange(n, dtype=float), np.zeros(n), np.zeros(n))
    for radius in (15.0, 30.0, 60.0):
        gx, gy = effects.defect_centres(generator_cell().geometry, radius)
        dense = effects.defect_regressor_grid(f, gx, gy, radius)
        sparse = defect_regressor_sparse(f, generator_cell().geometry, radius, chunk=97)
        assert np.array_equal(sparse.toarray(), dense)
        assert sparse.nnz == np.count_nonzero(dense) > 0
        assert np.array_equal(nameable_reach(sparse), _nameable_reach_dense(dense))


def _with_bump(recs, seed):
    """The recordings with a 40 um bump of radius 30 mm near a touch of the first one."""
    rng = np.random.default_rng(seed)
    r0 = recs[0]
    i = rng.integers(len(r0))
    cx, cy = r0.x_mm[i] + 8.0, r0.y_mm[i] - 5.0
    out = []
    for r in recs:
        bump = effects.local_defect.reading_change(
            effects.Features(r.x_mm, r.y_mm, r.t_s, np.zeros(len(r)), np.zeros(len(r))),
            {"x_mm": cx, "y_mm": cy, "height_mm": 0.04, "radius_mm": 30.0}, None)
        out.append(Recording(r.seq, r.t_s, r.x_mm, r.y_mm, r.z_mm, r.reading_mm + bump,
                             path=r.path))
    return out


@pytest.mark.parametrize("bump", [False, True])
def test_centre_search_equals_the_dense_one(bump):
    """``_centres`` (sparse bells, the projection from |x|^2 - |Q^T x|^2) against the dense
    chunks it replaces: the same best centre and radius, the same number of nameable centres,
    evidence and posterior to rounding, with and without a bump, on every design."""
    cell = generator_cell()
    for k, (name, recs) in enumerate(_designs().items()):
        ctx = Context.of(build_design(_with_bump(recs, k) if bump else recs, cell))
        fast = score_effect(ctx, effects.local_defect)
        slow = _centres_dense(ctx, effects.local_defect)
        if slow is None:
            assert fast is None, name
            continue
        assert fast.fixed == slow.fixed and fast.searched == slow.searched, name
        assert fast.log_bf == pytest.approx(slow.log_bf, rel=1e-9, abs=1e-9), name
        assert fast.look_elsewhere == pytest.approx(slow.look_elsewhere, rel=1e-9, abs=1e-9)
        for key in ("x_mm", "y_mm", "radius_mm"):
            assert fast.nonlinear_mean[key] == pytest.approx(slow.nonlinear_mean[key], abs=1e-6)
            assert fast.nonlinear_std[key] == pytest.approx(slow.nonlinear_std[key], abs=1e-6)
        assert np.allclose(fast.mean, slow.mean, rtol=1e-9, atol=1e-12), name
        assert np.array_equal(fast.prior_var, slow.prior_var), name


def _where_dense(ctx, residual, sigma_mm, top=3):
    """``locate.where`` before issue 15 item 8 (the reference): the kernel at every touch, on the
    shared grid and bandwidth (``smoothing_grid``) and peak picking (``peaks``)."""
    d = ctx.design
    gx, gy, h = smoothing_grid(d)
    out = []
    for s in range(0, gx.size, 400):
        k = np.exp(-0.5 * ((gx[s:s + 400, None] - d.features.x_mm) ** 2
                           + (gy[s:s + 400, None] - d.features.y_mm) ** 2) / h ** 2)
        wsum = k.sum(1)
        out.append(np.stack([k @ residual / np.maximum(wsum, 1e-300), wsum], 1))
    sm = np.concatenate(out)
    return peaks(d, gx, gy, h, sm[:, 0], sm[:, 1], residual, sigma_mm, top)


@pytest.mark.parametrize("bump", [False, True])
def test_where_equals_the_dense_kernel(bump):
    """The peaks of the smoothed residual: same places, touches and shares, values to 1e-12."""
    cell = generator_cell()
    for k, (name, recs) in enumerate(_designs().items()):
        ctx = Context.of(build_design(_with_bump(recs, k) if bump else recs, cell))
        fast, slow = where(ctx, ctx.yt, 0.005), _where_dense(ctx, ctx.yt, 0.005)
        assert len(fast) == len(slow) > 0, name
        for a, b in zip(fast, slow):
            assert {k: a[k] for k in ("x_mm", "y_mm", "touches")} == \
                {k: b[k] for k in ("x_mm", "y_mm", "touches")}, name
            for key in ("residual_mm", "z", "share_of_residual_ss"):
                assert a[key] == pytest.approx(b[key], rel=1e-12, abs=1e-15), (name, key)


# -- bad input: a clear message, never a ZeroDivisionError or an out-of-memory kill ---------------

def _cli(argv, capsys):
    from adaptive_cal.cli import main

    code = main(argv)
    return code, capsys.readouterr().err


@pytest.fixture()
def cell_file(tmp_path):
    import yaml

    cell = {"name": "bad input", "workplane": {**{k: list(v) for k, v in WORKPLANE.items()},
                                               "edge_margin_mm": 0},
            "robot": {"adapter": "sim", "touch_time_s": 4},
            "probe": {"adapter": "sim", "zero_mm": ZERO_MM},
            "simulation": {"effects": {}, "unknown": ["tilt"]}}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    return path


def _write(path, rows, flags=""):
    body = "".join(f"{k},{4 * k},{(k % 9) * 40 - 180.0},{(k // 9) * 30 - 150.0},0,"
                   f"{ZERO_MM + 1e-3 * (k % 7)},{flags}\n" for k in range(rows))
    path.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,flags\n" + body)
    return path


def test_a_single_row_gets_a_clear_message(tmp_path, cell_file, capsys):
    rec = _write(tmp_path / "one.csv", 1)
    code, err = _cli(["explain", "--robot", str(cell_file), str(rec)], capsys)
    assert code == 2
    assert "one.csv: 1 row; explain needs at least 8 fused rows" in err, err
    assert "Traceback" not in err and "internal error" not in err


def test_all_readings_rejected_gets_a_clear_message(tmp_path, cell_file, capsys):
    rec = _write(tmp_path / "rejected.csv", 40, flags="rejected")
    code, err = _cli(["explain", "--robot", str(cell_file), str(rec)], capsys)
    assert code == 2
    assert "rejected.csv: 40 rows, 0 of them fused" in err and "marks the others rejected" in err, err
    assert "ZeroDivision" not in err and "internal error" not in err


def test_a_million_rows_are_refused_with_the_limit(tmp_path, cell_file, capsys):
    """10**6 rows (about 45 MB, written in blocks): the reader stops at the limit with the line,
    in seconds and without holding the file; a recording built in memory past the limit gets
    the same limit from explain."""
    import time

    from adaptive_cal.analysis.explain import explain
    from adaptive_cal.formats.recording import MAX_ROWS, RecordingError

    path = tmp_path / "million.csv"
    with path.open("w") as f:
        f.write("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n")
        for s in range(0, 10**6, 100_000):
            f.write("".join(f"{k},,{(k % 1000) * 0.4 - 200.0:.1f},{(k // 1000) * 0.3 - 150.0:.1f},"
                            f"0,{ZERO_MM}\n" for k in range(s, s + 100_000)))
    t0 = time.monotonic()
    code, err = _cli(["explain", "--robot", str(cell_file), str(path), "--json",
                      str(tmp_path / "out.json")], capsys)
    assert code == 2
    assert f"million.csv:{MAX_ROWS + 3}: more than {MAX_ROWS} rows" in err, err
    assert time.monotonic() - t0 < 30  # about 2 s alone
    assert not (tmp_path / "out.json").exists()
    n = MAX_ROWS + 1
    x = np.resize(np.linspace(-200.0, 200.0, 9), n)
    y = np.linspace(-150.0, 150.0, n)
    rec = Recording(np.arange(n), 4.0 * np.arange(n), x, y, np.zeros(n), np.full(n, ZERO_MM))
    with pytest.raises(RecordingError, match=f"{n} rows in 1 recording.*at most {MAX_ROWS}"):
        explain([rec], generator_cell())


def test_tilt_blocks_equal_the_loop(contexts):
    """identify._tilt (one scatter) against the per-round loop it replaces: the same matrix."""
    from adaptive_cal.analysis.explain.identify import _tilt

    for name, ctx in contexts.items():
        d = ctx.design
        T = effects.tilt.regressor(d.features, d.geometry)
        ref = np.zeros((T.shape[0], 3 * d.rounds))
        for r in range(d.rounds):
            ref[d.round_index == r, 3 * r:3 * r + 3] = T[d.round_index == r]
        assert np.array_equal(_tilt(d.features, d.round_index, d.rounds, d.geometry), ref), name


# -- start-up: explain --json loads neither JAX, matplotlib, scipy.stats nor filterpy -------------

def test_explain_json_loads_nothing_it_does_not_use(tmp_path, cell_file):
    """40 rows through ``adaptive-cal explain --json`` in a fresh interpreter: JAX, matplotlib,
    scipy.stats and filterpy (about 1.5 s of the start-up before) stay unloaded, and JAX still
    comes up in float64 when a command does load it."""
    import json
    import subprocess
    import sys

    rec = _write(tmp_path / "rec.csv", 40)
    probe = (
        "import json, sys\nfrom adaptive_cal.cli import main\n"
        f"code = main(['explain', '--robot', {str(cell_file)!r}, {str(rec)!r}, '--json', "
        f"{str(tmp_path / 'out.json')!r}])\n"
        "heavy = sorted(m for m in ('jax', 'matplotlib', 'scipy.stats', 'filterpy') "
        "if m in sys.modules)\n"
        "import jax\n"
        "print(json.dumps([code, heavy, bool(jax.config.jax_enable_x64)]), file=sys.stderr)\n")
    p = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert json.loads(p.stderr.strip().splitlines()[-1]) == [0, [], True], p.stderr[-2000:]
    assert json.loads((tmp_path / "out.json").read_text())["readings"]["total"] == 40


def test_special_functions_equal_scipy_stats():
    """The densities and tail probabilities explain now takes from scipy.special are
    scipy.stats' own (exactly, on this scipy), edge cases included."""
    from scipy import special, stats

    from adaptive_cal.analysis.tails import LOG_SQRT_2PI, t_logpdf

    rng = np.random.default_rng(11)
    x, df = 10 * rng.standard_normal(5000), rng.uniform(1.0, 5000.0, 5000)
    assert np.allclose(t_logpdf(x, df), stats.t.logpdf(x, df), rtol=1e-13, atol=0)
    s = rng.uniform(1e-4, 1.0, 5000)
    assert np.allclose(-(x / s) ** 2 / 2.0 - LOG_SQRT_2PI - np.log(s),
                       stats.norm.logpdf(x, scale=s), rtol=1e-13, atol=0)
    for F, q, d in [(0.0, 3, 10), (2.5, 3, 10), (40.0, 7, 3993), (np.inf, 2, 5)]:
        assert special.fdtrc(q, d, F) == stats.f.sf(F, q, d)
    for v, m in [(0.0, 5), (3.0, 5), (1e5, 40), (37.5, 37)]:
        assert special.chdtrc(m, v) == stats.chi2.sf(v, m)


def test_a_plain_table_takes_as_many_rows_as_a_recording():
    """formats.table reads plain x,y,reading files as recordings: the same row limit."""
    from adaptive_cal.formats import recording, table

    assert table.MAX_ROWS == recording.MAX_ROWS


@pytest.mark.filterwarnings("error")
def test_direction_along_y_text_names_only_the_arrivals_the_design_has():
    """A raster never arrives moving -y: the text must not print the mean of nothing (nan)."""
    import types

    from adaptive_cal.analysis.explain.structure import _detail

    y = np.repeat(np.arange(4.0), 5)  # a raster: rows in +y order, touches along x
    d = types.SimpleNamespace(features=types.SimpleNamespace(y_mm=y), round_index=np.zeros(20, int))
    r = np.where(y > 0, 0.004, 0.0)  # the last move along y is +y from the second row on
    text = _detail("direction along y", {"structure_rms_mm": 0.002, "p_value_corrected": 1e-4},
                   r, types.SimpleNamespace(design=d))
    assert "nan" not in text and "moving -y" not in text
    assert "+4.0 um arriving moving +y" in text and "+0.0 um arriving without moving along y" in text, text
