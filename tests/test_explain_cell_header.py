"""The explained cell file's header and the one-line summary of an effect fitted per round: each
round's value stood beside another round's sd ("pv_mm = 0.03338, 0.08521 +- 0.003904,
0.005079"); now each round's value with its own sd."""
import numpy as np
import yaml

from adaptive_cal.analysis.explain import explain
from adaptive_cal.analysis.explain.summary import write_cell
from adaptive_cal.cell.schema import load_cell

CELL = """name: two rounds
workplane: {x_mm: [-225, 225], y_mm: [-185, 185], edge_margin_mm: 10}
robot: {adapter: sim, touch_time_s: 4}
probe: {adapter: sim, stroke_mm: 10, usable_mm: [0.5, 9.5], zero_mm: 5.0, noise_std_mm: 0.005}
simulation:
  seed: 0
  effects: {tilt: {a: 0.0, b: 0.0, c: 0.0}}
  unknown: [tilt]
  noise_std_mm: 0.005
"""


def _round(path, bow_mm, slope, seed):
    xs, ys = np.linspace(-200, 200, 10), np.linspace(-160, 160, 8)
    pts = np.array([(x, y) for j, y in enumerate(ys) for x in (xs if j % 2 == 0 else xs[::-1])])
    rng = np.random.default_rng(seed)
    read = 5.0 + slope * pts[:, 0] + bow_mm * (pts[:, 1] / 185) ** 2 + rng.normal(0, 0.005, len(pts))
    rows = [f"{i},{4.0 * i:.1f},{x:.3f},{y:.3f},0,{r:.6f}" for i, ((x, y), r) in
            enumerate(zip(pts, read))]
    path.write_text("# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm\n"
                    + "\n".join(rows) + "\n")
    return path


def test_a_form_fitted_per_round_is_said_round_by_round(tmp_path):
    (tmp_path / "cell.yaml").write_text(CELL)
    cell = load_cell(tmp_path / "cell.yaml")
    recs = [_round(tmp_path / "r0.csv", 0.03, 3e-4, 1), _round(tmp_path / "r1.csv", 0.08, 6e-4, 2)]
    result = explain([str(p) for p in recs], cell, rng=np.random.default_rng(0))
    f = result.findings
    assert f["verdict"] == "form"
    entry = next(e for e in f["left_out"] if e["effect"] == "form")
    assert entry["sharing"] == "per_round"
    pv, sd = entry["params"]["pv_mm"], entry["params_std"]["pv_mm"]
    said = (f"form: pv_mm per round 0: {pv[0]:.4g} +- {sd[0]:.4g}, "
            f"1: {pv[1]:.4g} +- {sd[1]:.4g}")
    assert entry["summary"].startswith(said), entry["summary"]
    path = write_cell(result, yaml.safe_load(CELL), tmp_path / "cell.yaml", tmp_path / "out")
    head = path.read_text().splitlines()[:4]
    assert head[1].startswith("# " + said), head
    # the file itself holds the last round's values, and says so
    assert "the last round's values are written" in head[3]
    written = yaml.safe_load(path.read_text())["simulation"]["effects"]["form"]
    assert written["pv_mm"] == pv[1]
