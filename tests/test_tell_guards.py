"""What ``tell`` must refuse or catch, found by an outside audit of the library (2026-11-29):
a stop on self-checks that have not seen the newest readings, a keep-out lying in the edge
margin, an approach height outside the workspace box (its retake would be sent there), a
frozen readout told as numpy or JAX scalars, a Decimal."""
import copy
import decimal
import warnings

import numpy as np
import pytest
import yaml

import adaptive_cal
from adaptive_cal.planning import survey as sv
from adaptive_cal.planning.robust import InvalidReading

CELL = "configs/sim-cell.yaml"


def _cell(**workplane):
    d = yaml.safe_load(open(CELL))
    d["workplane"].update(workplane)
    return d


def _truth(x, y):
    return 0.014 * x + 0.0019 * y + 0.2 + 0.14 * (y / 185) ** 2


def _tell(s, rng, x, y, extra=0.0, noise=0.002):
    h = _truth(x, y) + extra + rng.normal(0, noise)
    z = round(float(s.plan.approach_height(h)), 1)
    told = s.tell(x, y, z, h - z + 5.0)
    if told.retake_next:
        h = _truth(x, y) + extra + rng.normal(0, noise)
        told = s.tell(x, y, z, h - z + 5.0)
    return told


def test_a_stop_rests_on_checks_of_every_fused_reading():
    """28 touches on a 7 x 4 grid meet the bound; then an 80 um bump 25 mm wide: its first
    reading is gated, its retake confirms it. The stop fired there on the checks of the refit at
    28 readings (RMS std 1.1 um, where the next refit says 11 um)."""
    adaptive_cal.use_float64()
    warnings.simplefilter("ignore")
    s = adaptive_cal.start_survey(_cell(keep_outs=[]))
    rng = np.random.default_rng(5)
    for x in np.linspace(-210, 210, 7):
        for y in np.linspace(-170, 170, 4):
            _tell(s, rng, x, y)
    for x, y in [(100, 60), (115, 45), (85, 75), (100, 40)]:
        bump = 0.08 * np.exp(-((x - 100) ** 2 + (y - 60) ** 2) / (2 * 25.0 ** 2))
        _tell(s, rng, x, y, bump)
        if s.stop_reason() is not None:
            assert s.state.fitted_at == s.state.fused  # the checks have seen every reading
            assert s.status().adequate == sv.check(s.plan, s.state).adequate
    assert s.stop_reason() is None and s.status().mean_std_mm > 0.004


def test_a_keep_out_in_the_edge_margin_is_refused():
    clamp = {"x_mm": [218, 225], "y_mm": [0, 50]}  # a clamp at the edge, inside the 10 mm margin
    s = adaptive_cal.start_survey(_cell(keep_outs=[clamp]))
    before = (s.state.belief.mean.copy(), s.touches)
    for x, y in [(220.0, 25.0), (224.0, 10.0)]:
        with pytest.raises(InvalidReading, match=f"x_mm = {x:g}, y_mm = {y:g} is inside a keep-out"):
            s.tell(x, y, 0.0, 5.0)
        with pytest.raises(InvalidReading, match="keep-out"):
            s.skip(x, y)
    assert np.array_equal(s.state.belief.mean, before[0]) and s.touches == before[1]
    s.tell(220.0, 80.0, 0.0, 5.0)  # beside the clamp, in the margin: on the plate, accepted
    assert s.touches == 1


def test_an_approach_height_outside_the_workspace_is_refused_and_never_retaken_there():
    s = adaptive_cal.start_survey(_cell())
    t = s.ask(1)[0]
    with pytest.raises(InvalidReading, match=r"z_mm = -1.*workspace box's z range \[-20, 60\]"):
        s.tell(t.x_mm, t.y_mm, t.z_mm * 1000 - 100.0, t.expected_reading_mm)  # z in um
    assert s.touches == 0 and s.state.retake is None
    assert all(s.plan.z_allowed(a.z_mm) for a in s.ask(3))


@pytest.mark.parametrize("kind", ["numpy", "jax"])
def test_a_frozen_readout_is_caught_whatever_scalar_type_tells_it(kind):
    import jax.numpy as jnp
    adaptive_cal.use_float64()
    wrap = {"numpy": np.asarray, "jax": jnp.asarray}[kind]
    s = adaptive_cal.start_survey(_cell())
    n = s.plan.frozen_after
    assert n is not None
    warnings.simplefilter("ignore")
    flags = []
    for t in (s.ask(1)[0] for _ in range(n + 1)):
        flags.append(s.tell(t.x_mm, t.y_mm, t.z_mm, wrap(5.0603)).flags)
    assert flags[n - 1] == ("rejected", "frozen")


def test_a_decimal_is_told_as_its_float():
    a, b = adaptive_cal.start_survey(_cell()), adaptive_cal.start_survey(_cell())
    t = a.ask(1)[0]
    a.tell(t.x_mm, t.y_mm, t.z_mm, 5.0603)
    b.tell(decimal.Decimal(repr(t.x_mm)), t.y_mm, decimal.Decimal(repr(t.z_mm)),
           decimal.Decimal("5.0603"))
    assert np.array_equal(a.state.belief.mean, b.state.belief.mean)
