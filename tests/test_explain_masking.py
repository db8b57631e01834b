"""Two gross errors that hide each other (explain.masking): an outside audit's 12 readings of
2 um noise with two +0.5 mm misreads came out "unexplained structure along noise" at p 1.00,
neither set aside -- each inflated the noise the other was judged against."""
import numpy as np

from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.masking import log_joint, robust_start
from adaptive_cal.analysis.explain.suspects import RATE, SCALE, _gross_logpdf
from adaptive_cal.cell.schema import load_cell

CELL = """name: audit mid_off
workplane: {x_mm: [-50.0, 350.0], y_mm: [20.0, 320.0], edge_margin_mm: 8.0,
            keep_outs: [{x_mm: [120.0, 170.0], y_mm: [140.0, 200.0]}]}
robot: {adapter: sim, base_xy_mm: [900.0, 150.0], touch_time_s: 3.0}
probe: {adapter: sim, stroke_mm: 10, usable_mm: [0.5, 9.5], zero_mm: 3.0, resolution_mm: 0.0001,
        noise_std_mm: 0.002}
simulation: {seed: 0, effects: {tilt: {a: 0.0, b: 0.0, c: 0.0}}, unknown: [tilt],
             noise_std_mm: 0.002}
"""


def _grid(rng, spikes=(3, 6), size=0.5):
    x, y = (g.ravel() for g in np.meshgrid([0.0, 100.0, 200.0, 300.0], [40.0, 170.0, 300.0]))
    z = 3.0 + 1e-5 * x - 2e-6 * y + rng.normal(0, 0.002, x.size)
    z[list(spikes)] += size
    return x, y, z


def test_the_robust_start_flags_the_misreads_and_nothing_on_clean_readings():
    rng = np.random.default_rng(7)
    x, y, z = _grid(rng)
    D = np.c_[x, y, np.ones_like(x)]
    assert list(np.flatnonzero(robust_start(D, z, 0.002, 3))) == [3, 6]
    assert np.flatnonzero(robust_start(D, z, 0.002, 1)).tolist() in ([3], [6])  # at most 1
    # Gaussian readings: 300 recordings of 40, none flagged more than rarely (6 robust sds)
    flagged = 0
    for s in range(300):
        r = np.random.default_rng([11, s])
        xx, yy = r.uniform(0, 400, 40), r.uniform(0, 300, 40)
        zz = 1e-4 * xx + r.normal(0, 0.005, 40)
        flagged += robust_start(np.c_[xx, yy, np.ones(40)], zz, 0.0, 8).any()
    assert flagged <= 3, flagged


def test_the_joint_posterior_prefers_the_misreads_set_aside_and_no_suspect_on_clean_data():
    rng = np.random.default_rng(7)
    x, y, z = _grid(rng)
    models = [(np.c_[x, y, np.ones_like(x)], np.zeros((3, 3)))]
    logw = np.zeros((1, 1))
    none, two = np.zeros(12, bool), np.isin(np.arange(12), [3, 6])
    joint = lambda s, zz: log_joint(models, zz, logw, s, 0.002, RATE, _gross_logpdf, SCALE)  # noqa: E731
    assert joint(two, z) > joint(none, z) + 20.0
    _, _, clean = _grid(rng, spikes=())
    assert joint(none, clean) > joint(two, clean) + 5.0


def test_two_misreads_on_twelve_readings_are_both_suspects_and_no_physics(tmp_path):
    rng = np.random.default_rng(7)
    x, y, z = _grid(rng)
    rows = [f"{i},{3.0 * i:.3f},{a:.4f},{b:.4f},0.0000,{c:.6f}"
            for i, (a, b, c) in enumerate(zip(x, y, z))]
    rec = tmp_path / "r.csv"
    rec.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n"
                   + "\n".join(rows) + "\n")
    (tmp_path / "cell.yaml").write_text(CELL)
    f = explain([rec], load_cell(tmp_path / "cell.yaml"), identifiability=False).findings
    assert sorted(s["seq"] for s in f["suspect_readings"]) == [3, 6]
    assert all(s["probability"] >= 0.99 for s in f["suspect_readings"])
    assert f["verdict"] == "none"
