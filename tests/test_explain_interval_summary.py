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


PROFILES = {  # unit-height bump profiles at d = distance / radius, written here from their shapes
    "cosine_bell": lambda d: 0.5 * (1 + np.cos(np.pi * np.minimum(d, 1))),  # DESIGN.md's
    "dome": lambda d: 1 - np.minimum(d, 1) ** 2,  # a shallow spherical cap (paraboloid)
    "cone": lambda d: 1 - np.minimum(d, 1),
}


def _bell_case(rng, radius: float, sigma: float, profile: str = "cosine_bell") -> dict:
    """DESIGN.md's local_defect (a cosine bell, or another ``PROFILES``) of a radius beyond the
    search's largest (60 mm), centred between touches of the S-path grid."""
    case = gen.recording("null", rng)
    i = int(rng.integers(case["x"].size - 1))
    f = rng.uniform(0.3, 0.7)
    cx = case["x"][i] + f * (case["x"][i + 1] - case["x"][i])
    row = (gen.Y_RANGE[1] - gen.Y_RANGE[0] - 20.0) / (gen.NY - 1)  # toward the middle row
    cy = case["y"][i] - np.sign(case["y"][i]) * rng.uniform(0.2, 0.8) * row
    d = np.hypot(case["x"] - cx, case["y"] - cy) / radius
    shape = np.where(d < 1, PROFILES[profile](d), 0.0)
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


def test_profiles_match_their_shapes_and_the_library_forward_model():
    """effects.defect_profile against the shapes written above; the bell is local_defect's own
    forward model (``reading_change``); an unknown profile is refused by name."""
    from adaptive_cal import effects
    from adaptive_cal.effects.base import Features

    d = np.linspace(0.0, 1.5, 31)
    for name, shape in PROFILES.items():
        assert effects.defect_profile(d, name) == pytest.approx(shape(d), abs=1e-15)
    x = np.linspace(-60.0, 60.0, 25)
    zero = np.zeros(x.size)
    f = Features(x, np.full(x.size, 3.0), zero, zero, zero)
    p = {"x_mm": 1.0, "y_mm": 3.0, "height_mm": 1.0, "radius_mm": 40.0}
    bell = effects.local_defect.reading_change(f, p, None)
    for name in PROFILES:
        col = effects.defect_regressor_grid(f, [1.0], [3.0], 40.0, name)[:, 0]
        assert col == pytest.approx(PROFILES[name](np.abs(x - 1.0) / 40.0) * (np.abs(x - 1) < 40))
    assert effects.defect_regressor_grid(f, [1.0], [3.0], 40.0)[:, 0] == pytest.approx(bell)
    with pytest.raises(ValueError, match="'wedge'"):
        effects.defect_profile(d, "wedge")


def test_profile_variants_split_each_childs_prior_mass_evenly(tmp_path):
    """Oracle: the refined posterior with the profile as a variant equals, block by block, the
    refined posterior run once per profile alone, each child's weight lowered by log 3 (its
    prior mass split over the three profiles); the parents' prior part is the search's."""
    from adaptive_cal import effects
    from adaptive_cal.analysis.explain.candidates import Context
    from adaptive_cal.analysis.explain.design import build_design

    case = _bell_case(np.random.default_rng([43, 0]), 40.0, 10.0, "dome")
    cell, rec = gen.write(tmp_path, case)
    d = build_design([read_recording(rec)], load_cell(cell))
    ctx = Context.of(d)
    t = case["truth"]
    values = {"x_mm": np.array([t["x_mm"], t["x_mm"] + 5.0]), "y_mm": np.full(2, t["y_mm"]),
              "radius_mm": np.array([30.0, 60.0])}
    log_w, tau = np.array([-1.0, -2.0]), np.array([0.05, 0.05])
    steps = {"x_mm": np.full(2, 7.5), "y_mm": np.full(2, 7.5)}

    def columns(forced=None):
        def column_of(v, sl):
            names = v["profile"][sl] if "profile" in v else [forced or "cosine_bell"] * len(
                v["x_mm"][sl])
            return np.column_stack([effects.defect_regressor_grid(
                d.features, [x], [y], float(r), str(n))[:, 0] for x, y, r, n in zip(
                v["x_mm"][sl], v["y_mm"][sl], v["radius_mm"][sl], names)])
        return column_of

    grid = {"radius_mm": np.array([15.0, 30.0, 60.0])}
    vals, logw, mean, var, _ = intervals.refined_posterior(
        ctx, columns(), grid, values, log_w, tau, "radius_mm", None, steps,
        {"profile": effects.DEFECT_PROFILES})
    n = logw.size // 3
    for i, name in enumerate(effects.DEFECT_PROFILES):
        block = slice(i * n, (i + 1) * n)
        assert set(vals["profile"][block]) == {name}
        # alone: the parents' prior part from the bell (the search's), the children under name
        base = columns()

        def alone(v, sl, name=name):
            return base({**v, "profile": np.full(v["x_mm"].size, name, object)}, sl) \
                if v["x_mm"].size == n else base(v, sl)
        v1, lw1, m1, s1, _ = intervals.refined_posterior(ctx, alone, grid, values, log_w, tau,
                                                         "radius_mm", None, steps)
        assert logw[block] == pytest.approx(lw1 - np.log(3.0), abs=1e-9)
        assert mean[block] == pytest.approx(m1, rel=1e-12) and var[block] == pytest.approx(s1)
        assert vals["radius_mm"][block] == pytest.approx(v1["radius_mm"])


@pytest.mark.parametrize("profile,radius", [("dome", 70.0), ("cone", 55.0)])
def test_a_bump_of_another_profile_has_its_height_covered(tmp_path, monkeypatch, profile, radius):
    """A dome or a cone at 10 sigma: explain reports the bell's height, biased on these profiles
    (the flank touches fix the width; a dome's peak is lower, a cone's higher). Its 2-sd
    interval, averaged over the profiles, covers the truth in all but 2 of 12 cases, at least as
    often as with the bell alone, and the errors in sds are smaller (median |z|): measured with
    the bell alone, dome 11/12 covered, median |z| 1.11 (0.80 averaged); cone 8/12 (10/12)."""
    from adaptive_cal import effects

    def errors():
        z = []
        for seed in range(12):
            case = _bell_case(np.random.default_rng([47, seed]), radius, 10.0, profile)
            cell, rec = gen.write(tmp_path, case)
            f = explain([read_recording(rec)], load_cell(cell)).findings
            if f["verdict"] != "local_defect":
                continue
            e = next(e for e in f["left_out"] if e["effect"] == "local_defect")
            err = e["params"]["height_mm"] - case["truth"]["height_mm"]
            z.append(abs(err) / e["params_std"]["height_mm"])
        return np.array(z)

    z = errors()
    monkeypatch.setattr(effects, "DEFECT_PROFILES", ("cosine_bell",))
    z_bell = errors()
    assert z.size >= 11 and np.sum(z <= 2) >= z.size - 2, z
    assert np.sum(z <= 2) >= np.sum(z_bell <= 2) and np.median(z) < np.median(z_bell), (z, z_bell)
