"""Effects of the robot and the probe (not part of the plate): thermal_drift, reversal, arm_sag,
probe_gain.

======================  =====================================================================
thermal_drift           rate_mm_per_s t + amplitude_mm (1 - exp(-t / tau_s)): a linear drift and
                        a warm-up that approaches amplitude_mm with time constant tau_s
reversal                span_mm / 2 x direction of arrival along x (+1 / -1)
arm_sag                 sag_mm_at_1m (r / 1 m)^p, r = horizontal distance from the robot base
probe_gain              gain x ideal reading (reading = (1 + gain) ideal reading)
======================  =====================================================================
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.effects.base import Effect, Features, Geometry, Param

SAG_EXPONENTS = (1.0, 1.5, 2.0, 2.5, 3.0)
# tau_s searched on 15 values from 1/32 to 4 times the run's duration (factor sqrt 2 apart)
TAU_PER_RUN = tuple(float(v) for v in np.geomspace(1.0 / 32.0, 4.0, 15))


def _drift(f, p, g):
    t = np.nan_to_num(f.t_s, nan=0.0)
    out = p["rate_mm_per_s"] * t
    if p["amplitude_mm"] != 0.0:
        out = out + p["amplitude_mm"] * -np.expm1(-t / p["tau_s"])
    return out


def _tau_grid(features: Features, geometry: Geometry) -> dict[str, np.ndarray]:
    t = np.nan_to_num(np.asarray(features.t_s, float), nan=0.0)
    run_s = max(float(t.max(initial=0.0)), 1.0)
    return {"tau_s": run_s * np.asarray(TAU_PER_RUN)}


thermal_drift = Effect(
    "thermal_drift", "robot and plate warm up: grows with time",
    "rate_mm_per_s t + amplitude_mm (1 - exp(-t / tau_s))",
    (Param("rate_mm_per_s", "mm/s", "reading gain per second", 0.0, prior=(1e-6, 1e-3)),
     Param("amplitude_mm", "mm", "reading gain the warm-up approaches", 0.0, prior=(1e-4, 1.0)),
     Param("tau_s", "s", "time constant of the warm-up", 300.0, linear=False)),
    _drift, axis="time", main="rate_mm_per_s", grid=_tau_grid, searched=("amplitude_mm",),
    grid_text="tau_s on 15 values from 1/32 to 4 x the run's duration (with amplitude_mm; "
    "rate_mm_per_s alone needs none)")


def _reversal(f, p, g):
    return 0.5 * p["span_mm"] * f.direction


reversal = Effect(
    "reversal", "backlash, hysteresis: offset by direction of arrival along x",
    "span_mm / 2 x direction of arrival along x (+1, -1)",
    (Param("span_mm", "mm", "reading arriving moving +x minus arriving moving -x", 0.0,
           prior=(1e-4, 0.1)),),
    _reversal, axis="direction", main="span_mm")


def _sag(f, p, g):
    return p["sag_mm_at_1m"] * (f.reach_mm(g) / 1000.0) ** p["p"]


arm_sag = Effect(
    "arm_sag", "arm droops with reach: grows with horizontal distance r from the robot base",
    "sag_mm_at_1m (r / 1 m)^p",
    (Param("sag_mm_at_1m", "mm", "reading change at r = 1 m", 0.0, prior=(1e-3, 1.0)),
     Param("p", "-", "exponent of the reach", 2.0, linear=False)),
    _sag, axis="reach", main="sag_mm_at_1m",
    grid=lambda features, geometry: {"p": np.asarray(SAG_EXPONENTS)},
    searched=("sag_mm_at_1m",), grid_text="p uniform on {1, 1.5, 2, 2.5, 3}")


def _gain(f, p, g):
    return p["gain"] * f.ideal_reading_mm


probe_gain = Effect(
    "probe_gain", "gauge scale / cosine error: proportional to the indication",
    "gain x ideal reading",
    (Param("gain", "-", "reading = (1 + gain) x ideal reading", 0.0, prior=(1e-5, 1e-2)),),
    _gain, axis="indication", main="gain")
