"""The benchmark's table of cases (issue 15, item 7): families, sizes, designs, how many.

``table(n, seed)`` lists plain specs; ``build(spec)`` makes the case (seeded by the spec alone,
so any case can be re-made on its own). ``n`` recordings per cell of the single-effect table;
nulls get 3 n per family, out-of-library 2 n per cell. n = 10: 960 recordings.
"""
from __future__ import annotations

import numpy as np

from .generate import Case, generate

SINGLE = ("form", "arm_sag", "reversal", "thermal_drift", "local_defect")
SINGLE_DESIGNS = ("s_path", "raster", "random", "edge")
FORM_KINDS = ("bow", "twist", "mixed")
NULLS = {  # family: (noise, plate, rounds)
    "null_gauss": ("gauss", "standard", 1), "null_student_t": ("student_t", "standard", 1),
    "null_outliers": ("outliers", "standard", 1), "null_spike": ("spike", "standard", 1),
    "null_off_centre": ("gauss", "off_centre", 1), "null_small": ("gauss", "small", 1),
    "null_rounds": ("gauss", "standard", 0)}
# a linear drift on a raster is a plane in x, y (t = seq x 4 s, rows taken alike): the tilt
INVISIBLE = {("thermal_drift", "raster")}
PAIRS = (("form", "local_defect"), ("arm_sag", "reversal"), ("thermal_drift", "local_defect"),
         ("form", "reversal"))


def table(n: int) -> list[dict]:
    """Every case's spec: family, effects, sigma, design, plate, rounds, noise, index."""
    specs = []

    def add(count, **kw):
        for i in range(count):
            specs.append({**kw, "i": i})

    for fam, (noise, plate, rounds) in NULLS.items():
        add(3 * n, family=fam, effects=[], sigma=0.0, design="mixed", plate=plate,
            rounds=rounds, noise=noise)
    for eff in SINGLE:
        for sigma in (4.0, 6.0, 10.0):
            for design in SINGLE_DESIGNS:
                if (eff, design) in INVISIBLE:
                    continue
                add(n, family="single", effects=[eff], sigma=sigma, design=design,
                    plate="standard", rounds=1, noise="gauss")
    for sigma in (6.0, 10.0):
        for design in ("s_path", "random", "edge"):
            add(n, family="warmup", effects=["warmup"], sigma=sigma, design=design,
                plate="standard", rounds=1, noise="gauss")
    for pair in PAIRS:
        add(n, family="two_effects", effects=list(pair), sigma=10.0, design="mixed",
            plate="standard", rounds=1, noise="gauss")
    add(2 * n, family="out_of_library", effects=["backlash_y"], sigma=10.0, design="columns",
        plate="standard", rounds=1, noise="gauss")
    for design in ("s_path", "random"):
        add(2 * n, family="out_of_library", effects=["ripple"], sigma=10.0, design=design,
            plate="standard", rounds=1, noise="gauss")
    for sigma in (6.0, 10.0):
        add(n, family="rounds_shared_form", effects=["form"], sigma=sigma, design="s_path",
            plate="standard", rounds=3, noise="gauss")
    return specs


def spec_key(spec: dict) -> str:
    return (f"{spec['family']}/{'+'.join(spec['effects']) or 'none'}/{spec['sigma']:g}/"
            f"{spec['design']}/{spec['plate']}/{spec['noise']}/{spec['i']}")


def build(spec: dict, seed: int) -> Case:
    """The case of a spec: every random choice from (seed, the spec's key)."""
    key = spec_key(spec)
    rng = np.random.default_rng([seed, *key.encode()])
    design = spec["design"]
    if design == "mixed":  # a design on which every effect of the case is visible
        design = str(rng.choice([d for d in ("s_path", "raster", "random", "edge")
                                 if not any((e, d) in INVISIBLE for e in spec["effects"])]))
    rounds = spec["rounds"] or int(rng.integers(2, 4))
    effects = [f"form:{FORM_KINDS[spec['i'] % 3]}" if e == "form" else e for e in spec["effects"]]
    return generate(spec["family"], tuple(effects), spec["sigma"], design, rng,
                    plate=spec["plate"], n_rounds=rounds, noise=spec["noise"])
