"""compensate evaluates the map on many check samples at once (a million-line program took
7 minutes and 1.2 GB one move at a time, 2026-11-29). Oracle: the same maths one move at a time,
written here plainly from the module's doc -- every output point, every refusal, every count,
on random programs with wide bands, cuts beyond reach, keep-outs, level and unknown rapids."""
import numpy as np
import pytest

from adaptive_cal.analysis import compensate as cp
from adaptive_cal.formats.toolpath import read_toolpath
from adaptive_cal.gaussian.belief import Z95

PLATE = ((-200.0, 200.0), (-150.0, 150.0))
REACH = ((-180.0, 180.0), (-130.0, 130.0))
KEEP_OUTS = (((-60.0, -20.0), (-40.0, 10.0)), ((50.0, 90.0), (30.0, 70.0)))


def height(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    mean = 0.05 * np.sin(x / 17.0) * np.cos(y / 23.0) + 2e-4 * x + 0.1
    std = 0.0015 + 0.004 * (x > 120.0) * (y > 60.0)  # a corner whose band passes 10 um
    return mean, std


def reference(path, tol, top, sample_mm=cp.SAMPLE_MM):
    """One move at a time: (pieces, wide, beyond, under, added, max deviation, dip)."""
    pieces, wide, beyond, under, added, dev_max, dip = {}, [], [], [], 0, 0.0, 0.0
    for mv in path.moves:
        if mv.cut:
            end = np.array(mv.end, float)
            start = end if mv.start is None else np.array(mv.start, float)
            t = cp.samples(float(np.hypot(*(end - start)[:2])), sample_mm)
            p = start + t[:, None] * (end - start)
            mean, std = height(p[:, 0], p[:, 1])
            band = Z95 * std
            w = int(np.argmax(band))
            if band[w] > tol:
                wide.append((mv.line, p[w, 0], p[w, 1], band[w]))
            far = cp.outside_mm(REACH, p[:, 0], p[:, 1])
            if far.max() > cp.EDGE_MM:
                k = int(np.argmax(far))
                beyond.append((mv.line, p[k, 0], p[k, 1], far[k]))
            for i, ((x0, x1), (y0, y1)) in enumerate(KEEP_OUTS):
                over = np.flatnonzero((p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0)
                                      & (p[:, 1] < y1))
                if over.size:
                    under.append((mv.line, p[over[0], 0], p[over[0], 1], i))
            limit = np.where(band <= tol, tol - band, tol)
            surf = p[:, 2] + mean
            kept = cp.bisect(surf, limit)
            dev_max = max(dev_max, cp.deviation(t, surf[kept], p[:, 2], mean, kept).max())
            pieces[mv.item] = [(p[k, 0], p[k, 1], surf[k]) for k in kept[1:]]
            added += len(kept) - 2
            continue
        x, y, z = mv.end
        if z is None:
            continue
        h = [top if q is None or None in q[:2] else float(height(q[0], q[1])[0])
             for q in (mv.start, mv.end)]
        pieces[mv.item] = [(x, y, z + h[1])]
        if mv.start is None or mv.start[2] is None or None in (x, y):
            continue
        if None in mv.start[:2]:
            if mv.start[2] == z and h[1] < h[0]:
                pieces[mv.item] = [(x, y, z + h[0]), (x, y, z + h[1])]
            continue
        a, b = np.array(mv.start[:2]), np.array([x, y])
        t = cp.samples(float(np.hypot(*(b - a))))
        along = height(*(a + t[:, None] * (b - a)).T)[0]
        if mv.start[2] == z and mv.start[:2] != (x, y) and h[0] != h[1]:
            pieces[mv.item] = ([(x, y, z + h[0]), (x, y, z + h[1])] if h[1] < h[0] else
                               [(a[0], a[1], z + h[1]), (x, y, z + h[1])])
            dip = max(dip, float(np.max(along - max(h))))
        else:
            dip = max(dip, float(np.max(along - (h[0] + t * (h[1] - h[0])))))
    return pieces, wide, beyond, under, added, dev_max, dip


def program(seed: int, n: int = 400) -> str:
    rng = np.random.default_rng(seed)
    lines = ["G21 G90", "G0 Z5", "G0 X-150 Y-100"]  # the first rapid: X, Y from nowhere
    for _ in range(n):
        x, y = rng.uniform(-195, 195), rng.uniform(-145, 145)
        r = rng.random()
        if r < 0.08:  # a level rapid
            lines.append(f"G0 X{x:.3f} Y{y:.3f}")
        elif r < 0.14:  # a plunge or retract alone
            lines.append(f"G0 Z{rng.choice([5, 2]):g}" if rng.random() < 0.5
                         else f"G1 Z{rng.uniform(-0.2, 0):.3f} F100")
        elif r < 0.5:  # a short cut
            lines.append(f"G1 X{x / 40:.3f} Y{y / 40:.3f}" if rng.random() < 0.3
                         else f"G1 X{x:.3f}")
        else:  # a long one, often split
            lines.append(f"G1 X{x:.3f} Y{y:.3f} Z{rng.uniform(-0.2, 0):.3f}")
    return "\n".join(lines + ["G0 Z5", "M2"]) + "\n"


@pytest.mark.parametrize("chunk", [7, 1_000, cp.CHUNK])
@pytest.mark.parametrize("seed", [0, 1])
def test_batched_compensation_equals_one_move_at_a_time(monkeypatch, seed, chunk):
    monkeypatch.setattr(cp, "CHUNK", chunk)  # chunks cut inside, between and around moves
    path = read_toolpath(program(seed), "p")
    tol, top = 0.01, 0.3
    done = []
    got = cp.compensate(path, height, PLATE, tol, top_mm=top, name="p", reach_mm=REACH,
                        keep_outs=KEEP_OUTS, progress=done.append)
    pieces, wide, beyond, under, added, dev_max, dip = reference(path, tol, top)
    assert sum(done) == len(path.moves)
    assert got.cuts == sum(m.cut for m in path.moves)
    assert got.rapids == len(path.moves) - got.cuts
    assert wide and beyond and under and added > 50 and dip > 0  # every branch was taken
    assert sorted(got.pieces) == sorted(pieces)
    for item, want in pieces.items():
        assert np.allclose(np.array(got.pieces[item], float), np.array(want, float), rtol=0,
                           atol=1e-12, equal_nan=True), item  # None (not known yet): NaN
    for mine, want in (([(w.line, w.x_mm, w.y_mm, w.band_mm) for w in got.wide], wide),
                       ([(b.line, b.x_mm, b.y_mm, b.outside_mm) for b in got.beyond], beyond)):
        assert np.shape(mine) == np.shape(want)
        assert np.allclose(mine, want, rtol=1e-13, atol=0)
    assert [(u.line, u.x_mm, u.y_mm, u.index) for u in got.under] == under
    assert got.added == added
    # the chord is summed in another order: a few ulp of 0.1 mm
    assert got.max_deviation_mm == pytest.approx(dev_max, abs=1e-12)
    assert got.rapid_dip_mm == pytest.approx(dip, abs=1e-12)


def test_the_first_refusal_in_the_file_is_the_one_raised():
    """All moves are checked before any is evaluated: the earliest bad line still speaks."""
    text = "G21 G90\nG1 X10 Y10 Z0\nG0 X500 Y0 Z5\n"  # line 2: a cut from nowhere; 3: outside
    with pytest.raises(cp.ToolpathError, match="line 2"):
        cp.compensate(read_toolpath(text, "p"), height, PLATE, 0.01, top_mm=0.0, name="p")


def test_height_is_asked_a_few_times_not_once_a_move(monkeypatch):
    calls = []

    def counted(x, y):
        calls.append(np.size(x))
        return height(x, y)

    path = read_toolpath(program(3, n=3_000), "p")
    cp.compensate(path, counted, PLATE, 0.01, top_mm=0.3, name="p")
    # cuts in CHUNK-sized calls (one more where a move crosses the chunk's end), the rapids'
    # ends in one call, their travel in one
    assert sum(calls) > 500_000
    assert len(calls) <= sum(calls) / cp.CHUNK + 4 and len(calls) < len(path.moves) / 100


def _words(line):
    from adaptive_cal.formats.toolpath import _words

    try:
        return _words(line, "p line 1")
    except cp.ToolpathError as e:
        return str(e)


def test_the_readers_quick_path_reads_and_refuses_as_the_full_one(monkeypatch):
    """Lines of words alone skip the comment and gap checks: on random lines of G-code's
    alphabet (exponents, stray dots, signs, comments, tape marks) every word read and every
    refusal is the full path's."""
    import re

    from adaptive_cal.formats import toolpath as tp

    rng = np.random.default_rng(5)
    pieces = ["G1", "G0", "X", "Y", "Z", "F", "M2", "1", "2.", ".5", "-", "+", "e", "E2", " ",
              "\t", "(c)", ";x", "%", ".", "N10", "x-3.25", "A1", "G21", "1e", "Y+.25"]
    lines = ["".join(rng.choice(pieces, rng.integers(1, 6))) for _ in range(20_000)]
    quick = [_words(t) for t in lines]
    taken = sum(bool(tp._PLAIN.fullmatch(t)) for t in lines)
    monkeypatch.setattr(tp, "_PLAIN", re.compile(r"(?!)"))  # never matches: the full path
    assert quick == [_words(t) for t in lines]
    assert taken > 2_000  # the quick path read many
    assert sum(isinstance(q, str) for q in quick) > 2_000  # and the full one refused many


def test_an_inserted_z_goes_after_the_last_axis_word_however_the_others_grew():
    from adaptive_cal.formats.toolpath import _replace_words

    assert _replace_words("G1 X1 Y2 F100 (c)", {"X": 1.0, "Y": 2.25, "Z": 0.5}) == \
        "G1 X1.0000 Y2.2500 Z0.5000 F100 (c)"
    assert _replace_words("G1 Y-3.123456X7 M3", {"X": 7.0, "Z": -1.0}) == \
        "G1 Y-3.123456X7.0000 Z-1.0000 M3"
    assert _replace_words("G1 F50 ; cut", {"Z": 0.1}) == "G1 F50 Z0.1000 ; cut"
