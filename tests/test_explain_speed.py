"""explain's speed (issue 15, item 8): the vectorised searches give the answers of the plain loops
they replace (kept here as slow references), and bad input of any size gets a clear message.

The figures against the targets are printed by benchmarks/bench_explain_speed.py.
"""
import numpy as np
import pytest

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import Context
from adaptive_cal.analysis.explain.design import build_design
from adaptive_cal.analysis.explain.identify import _gap_touches
from adaptive_cal.formats.recording import Recording
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
    """The loop before issue 15 item 8 (the reference): distances to every touch, every time."""
    d = ctx.design
    gx, gy = effects.defect_centres(d.geometry, 10.0)
    px, py = list(d.features.x_mm), list(d.features.y_mm)
    touches, fill0 = [], None
    for k in range(count):
        dist = np.min(np.hypot(gx[:, None] - np.asarray(px), gy[:, None] - np.asarray(py)), 1)
        i = int(np.argmax(dist))
        fill0 = float(dist[i]) if fill0 is None else fill0
        touches.append({"x_mm": float(gx[i]), "y_mm": float(gy[i]),
                        "z_mm": float(np.median(d.z_mm)),
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
