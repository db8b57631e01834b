"""The effect library as values: registry, composition with +, the warm-up drift forward in the
simulator, the docs table, and that a new effect needs nothing but its value to be scored."""
import re

import numpy as np
import pytest

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import Context, score_effect
from adaptive_cal.analysis.explain.design import build_design
from adaptive_cal.formats.recording import Recording
from adaptive_cal.simulation.concealed import generator_cell, serpentine
from conftest import ROOT
from helpers import sim_cell

GEOM = effects.Geometry((-225.0, 225.0), (-185.0, 185.0), (0.0, -650.0))


def _features(n=30, seed=0):
    rng = np.random.default_rng(seed)
    return effects.Features(rng.uniform(-200, 200, n), rng.uniform(-160, 160, n),
                            np.arange(n) * 4.0, np.sign(rng.standard_normal(n)),
                            5.0 + rng.uniform(-2, 2, n))


def test_registry_holds_the_stable_names_in_the_design_order():
    assert effects.EFFECT_NAMES == ("tilt", "form", "thermal_drift", "reversal", "arm_sag",
                                    "probe_gain", "local_defect")
    for e in effects.LIBRARY:
        assert e.axis in effects.AXES
        assert set(e.linear) | set(e.nonlinear) | set(e.derived) == set(e.param_names)
        assert set(e.searched) <= set(e.linear)
        if e.nonlinear:
            assert e.grid is not None, e.name
    with pytest.raises(KeyError, match="unknown effect 'wobble'; known: tilt"):
        effects.get("wobble")


def test_sum_of_effects_is_the_sum_of_forward_models_and_prints_as_physics():
    f = _features()
    s = effects.tilt + effects.form + effects.thermal_drift
    assert s.names == ("tilt", "form", "thermal_drift")
    params = {"tilt": {"a": 0.01, "b": -0.002, "c": 0.3}, "form": {"pv_mm": 0.2, "twist": 1.0},
              "thermal_drift": {"amplitude_mm": 0.02, "tau_s": 40.0}}
    parts = sum(effects.reading_change(k, v, f, GEOM) for k, v in params.items())
    np.testing.assert_allclose(s.reading_change(f, params, GEOM), parts, atol=1e-15)
    assert str(s) == ("tilt [a x + b y + c] + form [pv_mm x centred shape (bow_x u^2 + bow_y v^2 "
                      "+ twist u v + warp u^2 v^2)] + thermal_drift [rate_mm_per_s t + "
                      "amplitude_mm (1 - exp(-t / tau_s))]")
    with pytest.raises(ValueError, match="tilt"):
        s + effects.tilt


def test_warm_up_drift_against_the_hand_formula():
    f = _features()
    change = effects.reading_change("thermal_drift", {"amplitude_mm": 0.02, "tau_s": 30.0,
                                                      "rate_mm_per_s": 1e-5}, f, GEOM)
    np.testing.assert_allclose(change, 1e-5 * f.t_s + 0.02 * (1 - np.exp(-f.t_s / 30.0)),
                               rtol=1e-13, atol=1e-16)


def test_simulated_cell_carries_the_warm_up_exactly():
    """simulation.effects: {thermal_drift: {amplitude_mm: 0.02, tau_s: 300}} in a cell file:
    every noise-free reading is zero - z + 0.02 (1 - exp(-t / 300)), to the probe's resolution."""
    from adaptive_cal.simulation.cell import SimulatedCell

    cell = sim_cell(simulation={"effects": {"thermal_drift": {"amplitude_mm": 0.02, "tau_s": 300}},
                                "noise_std_mm": 0.0, "repeatability_mm": 0.0,
                                "xy_repeatability_mm": 0.0},
                    probe={"resolution_mm": 1e-9})
    sim = SimulatedCell.from_cell(cell)
    t, change = [], []
    for k in range(12):
        x, y, z = -200.0 + 35.0 * k, 40.0 * (-1) ** k, 0.5
        sim.move_to(x, y, z)
        sample = sim.read()
        t.append(sample.t_s)
        change.append(sample.reading_mm - (cell.probe.zero_mm - z))
    t = np.asarray(t)
    assert t.max() > 40.0
    np.testing.assert_allclose(change, 0.02 * (1 - np.exp(-t / 300.0)), rtol=0, atol=1e-9)


def test_cell_schema_reads_the_library():
    cell = sim_cell(simulation={"effects": {"thermal_drift": {"amplitude_mm": 0.02, "tau_s": 300}}})
    assert cell.simulation.effects["thermal_drift"]["tau_s"] == 300
    from adaptive_cal.cell.schema import ConfigError

    with pytest.raises(ConfigError, match="tau"):
        sim_cell(simulation={"effects": {"thermal_drift": {"tau": 300}}})


def test_docs_effect_table_is_the_library():
    text = (ROOT / "docs" / "explain.md").read_text(encoding="utf-8")
    assert effects.markdown_table() in text, "paste effects.markdown_table() into docs/explain.md"
    rows = re.findall(r"^\| (\w+) \| (position|time|direction|reach|indication) \|", text, re.M)
    assert [r[0] for r in rows] == [e.name for e in effects.LIBRARY if e.candidate]


def test_a_new_effect_is_scored_by_explain_from_its_value_alone():
    """An effect the library does not have (a ripple along x with a searched wavelength) is
    scored by the generic machinery: nothing but the value is written."""
    ripple = effects.Effect(
        "ripple", "waviness along x", "amplitude_mm sin(2 pi x / wavelength_mm)",
        (effects.Param("amplitude_mm", "mm", "half the peak-to-valley", 0.0, prior=(1e-4, 0.1)),
         effects.Param("wavelength_mm", "mm", "period along x", 100.0, linear=False)),
        lambda f, p, g: p["amplitude_mm"] * np.sin(2 * np.pi * f.x_mm / p["wavelength_mm"]),
        axis="position", main="amplitude_mm", searched=("amplitude_mm",),
        grid=lambda f, g: {"wavelength_mm": np.array([60.0, 90.0, 135.0])})
    x, y = serpentine(20, 6)
    n = x.size
    rng = np.random.default_rng(3)
    f = effects.Features(x, y, 4.0 * np.arange(n), np.zeros(n), np.zeros(n))
    truth = ripple.reading_change(f, {"amplitude_mm": 0.02, "wavelength_mm": 90.0}, GEOM)
    reading = 5.0 + 0.003 * x + truth + 0.002 * rng.standard_normal(n)
    rec = Recording(np.arange(n), 4.0 * np.arange(n), x, y, np.zeros(n), reading)
    ctx = Context.of(build_design([rec], generator_cell()))
    cand = score_effect(ctx, ripple)
    assert cand.log_bf > 20 and cand.fixed == {"wavelength_mm": 90.0}
    assert cand.mean[0] == pytest.approx(0.02, rel=0.1)
