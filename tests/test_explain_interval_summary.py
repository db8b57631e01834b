"""How a searched effect's grid posterior is summarised (issue 15, item 2): the refined grid's end
cells, and the equivalent-normal sd of a tailed mixture (the warm-up's amplitude over tau_s).
Recordings come from the independent generator tests/open_world_generator.py (numpy only)."""
from __future__ import annotations

import numpy as np
import pytest

import open_world_generator as gen
from adaptive_cal.analysis.explain import explain, intervals
from adaptive_cal.cell.schema import load_cell
from adaptive_cal.formats.recording import read_recording

TWO_SD = 0.9544997361036416  # P(|Z| <= 2)


def test_an_end_point_stands_for_a_cell_as_wide_as_the_others():
    """The search gives every grid point the same prior mass, so each stands for a cell of the
    same width in the space the grid is uniform in: the end points' children mirror their one
    neighbour's spacing (a radius of 60 mm stands for 42-85 mm, p = 3 for 2.75-3.25)."""
    radii = np.array([15.0, 30.0, 60.0])
    parent, kid, cell = intervals.refine(radii, radii)
    split = 2.0 ** np.array([-0.375, -0.125, 0.125, 0.375])
    for j, r in enumerate(radii):
        assert kid[parent == j] == pytest.approx(r * split)
    assert kid.max() > 60.0 and kid.min() < 15.0
    # each child's cell: a quarter of an octave about it, the same share of every parent's cell
    width = np.sqrt(12.0 * cell)
    assert width / kid == pytest.approx(np.full(kid.size, 2 ** (1 / 8) - 2 ** (-1 / 8)))
    p = np.array([1.0, 1.5, 2.0, 2.5, 3.0])
    parent, kid, cell = intervals.refine(p, np.array([3.0]))
    assert kid == pytest.approx([2.8125, 2.9375, 3.0625, 3.1875])
    assert cell == pytest.approx(np.full(4, 0.125 ** 2 / 12))
    parent, kid, cell = intervals.refine(np.array([7.0]), np.array([7.0]))  # one point: itself
    assert kid == pytest.approx([7.0]) and cell == pytest.approx([0.0])


def test_equivalent_normal_sd_of_a_tailed_mixture_against_monte_carlo():
    """A warm-up's amplitude mixed over tau_s: a core and a tail toward the long time constants
    (the amplitude grows with tau_s there). value +- 2 sd holds 95.45 % of 400,000 draws of the
    mixture (binomial sd 3.3e-4: bound 2e-3), and the 95 % interval is the draws' 2.5 and
    97.5 % quantiles."""
    rng = np.random.default_rng(5)
    w = np.array([0.30, 0.40, 0.18, 0.08, 0.04])
    m = np.array([0.040, 0.041, 0.045, 0.055, 0.080])
    s = np.array([0.004, 0.004, 0.005, 0.007, 0.012])
    value = 0.041
    sd = intervals.two_sd_normal(w, m, s, value)
    comp = rng.choice(w.size, size=400_000, p=w)
    draws = m[comp] + s[comp] * rng.standard_normal(comp.size)
    held = np.mean(np.abs(draws - value) <= 2 * sd)
    assert held == pytest.approx(TWO_SD, abs=2e-3)
    lo, hi = intervals.mixture_quantiles(w, m, s)  # the 95 % interval: the draws' quantiles
    assert [lo, hi] == pytest.approx(np.quantile(draws, [0.025, 0.975]), abs=5e-4)


def _bell_case(rng, radius: float, sigma: float) -> dict:
    """DESIGN.md's local_defect (a cosine bell) of a radius beyond the search's largest (60 mm),
    centred between touches of the S-path grid."""
    case = gen.recording("null", rng)
    i = int(rng.integers(case["x"].size - 1))
    f = rng.uniform(0.3, 0.7)
    cx = case["x"][i] + f * (case["x"][i + 1] - case["x"][i])
    row = (gen.Y_RANGE[1] - gen.Y_RANGE[0] - 20.0) / (gen.NY - 1)  # toward the middle row
    cy = case["y"][i] - np.sign(case["y"][i]) * rng.uniform(0.2, 0.8) * row
    d = np.hypot(case["x"] - cx, case["y"] - cy) / radius
    shape = np.where(d < 1, 0.5 * (1 + np.cos(np.pi * np.minimum(d, 1))), 0.0)
    A = np.stack([case["x"], case["y"], np.ones_like(d)], 1)
    left = shape - A @ np.linalg.lstsq(A, shape, rcond=None)[0]
    h = sigma * gen.NOISE_MM / np.linalg.norm(left) * rng.choice([-1.0, 1.0])
    case["reading"] = case["reading"] + h * shape
    case["truth"] = {"height_mm": float(h), "radius_mm": radius, "x_mm": cx, "y_mm": cy}
    return case


def test_a_bump_wider_than_the_largest_radius_is_reached(tmp_path):
    """A bell of radius 75 mm lies in the cell the 60 mm grid point stands for (42-85 mm): the
    refined posterior reaches it (reported radius above 60 mm) and the height's 2-sd interval
    covers the truth. Before, the end cell was cut at 60 mm: the radius held at <= 55 mm."""
    covered, wide, n = 0, 0, 0
    for seed in range(6):
        case = _bell_case(np.random.default_rng([41, seed]), 75.0, 10.0)
        cell, rec = gen.write(tmp_path, case)
        f = explain([read_recording(rec)], load_cell(cell)).findings
        if f["verdict"] != "local_defect":
            continue
        n += 1
        e = next(e for e in f["left_out"] if e["effect"] == "local_defect")
        wide += e["params"]["radius_mm"] > 60.0
        err = e["params"]["height_mm"] - case["truth"]["height_mm"]
        covered += abs(err) <= 2 * e["params_std"]["height_mm"]
    assert n >= 5, n
    assert wide >= n - 1 and covered >= n - 1, (wide, covered, n)
