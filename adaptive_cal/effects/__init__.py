"""The effect library: one value per physical effect, read by the simulator, explain, the cell
schema and the docs alike (DESIGN.md, "Names of physics effects": the names are stable).

    >>> from adaptive_cal import effects
    >>> print(effects.tilt + effects.thermal_drift)
    tilt [a x + b y + c] + thermal_drift [rate_mm_per_s t + amplitude_mm (1 - exp(-t / tau_s))]

Adding an effect: write its ``Effect`` value (name, parameters with units and sign conventions,
forward model, residual axis, prior range, search grid) beside the others, list it in
``LIBRARY`` below, and test its forward model; explain, the simulator and the schema pick it up.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from adaptive_cal.effects.base import AXES, Effect, EffectSet, Features, Geometry, Param
from adaptive_cal.effects.machine import arm_sag, probe_gain, reversal, thermal_drift
from adaptive_cal.effects.plate import (DEFECT_PROFILES, defect_centres, defect_profile,
                                        defect_regressor_grid, form, form_basis,
                                        form_height, form_params, form_pv_gradient,
                                        local_defect, tilt)

LIBRARY = EffectSet((tilt, form, thermal_drift, reversal, arm_sag, probe_gain, local_defect))
EFFECTS: dict[str, Effect] = {e.name: e for e in LIBRARY}
EFFECT_NAMES = LIBRARY.names


def get(name: str) -> Effect:
    """The effect called ``name``; an unknown name raises with the known ones."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise KeyError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}") from None


def effect_set(names) -> EffectSet:
    """The sum of the named effects (in the order given)."""
    return EffectSet(tuple(get(n) for n in names))


def complete_params(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """Defaults filled in; unknown effect or parameter names raise with the name."""
    return get(name).complete(params)


def reading_change(name: str, params: Mapping[str, float], features: Features,
                   geometry: Geometry) -> np.ndarray:
    """Change of the reading in mm caused by one effect at each touch."""
    return get(name).reading_change(features, params, geometry)


def total_change(effects: Mapping[str, Mapping[str, float]], features: Features,
                 geometry: Geometry) -> np.ndarray:
    """Sum of the reading changes of the effects given as {name: params}."""
    return effect_set(effects).reading_change(features, effects, geometry)


def split(effects: Mapping[str, Mapping[str, float]]) -> tuple[dict, dict]:
    """{name: params} split into the plate's (surface) effects and the others."""
    surface = {k: v for k, v in effects.items() if get(k).surface}
    return surface, {k: v for k, v in effects.items() if k not in surface}


def markdown_table() -> str:
    """The effect table of docs/explain.md, from the library (tested to agree)."""
    rows = ["| effect | shows along | linear parameters: prior sd range | nonlinear parameters: grid |",
            "|---|---|---|---|"]
    for e in LIBRARY:
        if not e.candidate:
            continue
        lin = "; ".join(f"{p.name}: {p.prior[0]:g} .. {p.prior[1]:g}"
                        + (f" {p.unit}" if p.unit != "-" else "")
                        for p in e.params if p.prior is not None)
        rows.append(f"| {e.name} | {e.axis} | {lin} | {e.grid_text} |")
    return "\n".join(rows)


__all__ = ["AXES", "Effect", "EffectSet", "Features", "Geometry", "Param", "LIBRARY", "EFFECTS",
           "EFFECT_NAMES", "get", "effect_set", "complete_params", "reading_change",
           "total_change", "split", "markdown_table", "tilt", "form", "thermal_drift", "reversal",
           "arm_sag", "probe_gain", "local_defect", "form_basis", "form_height", "form_params",
           "form_pv_gradient", "defect_centres", "defect_regressor_grid", "DEFECT_PROFILES",
           "defect_profile"]
