"""Round to round: is a change of flatness between rounds larger than the measurement noise?

Flatness as the paper defines it (Cheng et al. eq. 5, ``analysis.flatness.ls_flatness_mm``):
least-squares plane through the surface heights of one round (reading + z: the height up to the
probe zero, which no flatness sees), then max - min of the residuals, measured normal to the
plane. Under the hypothesis that the plate did not change between rounds (only its tilt did),
the same touch points carry the same surface height h_i in every round:

    height_ri = plane_r(x_i, y_i) + h_i + e_ri,   e_ri ~ N(0, sigma^2).

sigma (the repeatability) follows from the difference of two rounds at the same points after a
plane is removed: var = 2 sigma^2 with n - 3 degrees of freedom. Whatever is the same in both
rounds (the form, however fine) cancels in it, so it is smaller than ``flatness``'s reading
noise, which is the scatter of one round about a smooth surface fitted to that round alone. A
parametric bootstrap of both rounds from the shared surface gives the distribution of the
flatness change the noise alone makes: its 95 % band and the two-sided p-value of the observed
change (on the points both rounds share) are a test of "unchanged", not an interval of the
change (``adaptive-cal flatness --compare`` gives that one).
"""
from __future__ import annotations

import numpy as np

from adaptive_cal.analysis.explain.design import Design
from adaptive_cal.analysis.flatness import ls_flatness_mm, ls_flatness_samples_mm


def _plane_residual(x, y, z) -> np.ndarray:
    A = np.stack([x, y, np.ones_like(x)], -1)
    P = A @ np.linalg.pinv(A)
    return z - z @ P.T if z.ndim > 1 else z - P @ z


def _matched(design: Design, a: int, b: int):
    """Indices of the touch points round a and round b share (same x, y to 0.01 mm)."""
    f = design.features
    ia = np.flatnonzero(design.round_index == a)
    ib = np.flatnonzero(design.round_index == b)
    key = lambda i: (round(float(f.x_mm[i]), 2), round(float(f.y_mm[i]), 2))
    lookup = {key(i): i for i in ib}
    pairs = [(i, lookup[key(i)]) for i in ia if key(i) in lookup]
    return np.array([p[0] for p in pairs], int), np.array([p[1] for p in pairs], int)


def flatness_change(design: Design, rng: np.random.Generator, a: int = 0, b: int = 1,
                    draws: int = 4000) -> dict:
    """Flatness of rounds a and b and whether their difference exceeds the noise."""
    f = design.features
    z = design.reading_mm + design.z_mm  # the height up to the probe zero (not the reading)
    ia, ib = _matched(design, a, b)
    out = {"rounds": [a, b]}
    flat = [ls_flatness_mm(f.x_mm[design.round_index == r], f.y_mm[design.round_index == r],
                           z[design.round_index == r]) for r in (a, b)]
    out["flatness_mm"] = flat
    out["change_mm"] = flat[1] - flat[0]
    if ia.size < 6:
        out["note"] = "rounds share fewer than 6 touch points: no paired noise estimate"
        return out
    x, y = f.x_mm[ia], f.y_mm[ia]
    ra, rb = _plane_residual(x, y, z[ia]), _plane_residual(x, y, z[ib])
    diff = rb - ra
    n = ia.size
    sigma = float(np.sqrt(diff @ diff / (n - 3) / 2.0))
    h = 0.5 * (ra + rb)
    sims = h + sigma * rng.standard_normal((draws, 2, n))
    fa = ls_flatness_samples_mm(x, y, sims[:, 0])
    fb = ls_flatness_samples_mm(x, y, sims[:, 1])
    null = fb - fa
    # the observed change on the points the bootstrap draws (all of them when the rounds share
    # every point), so the test compares like with like
    obs = ls_flatness_mm(x, y, z[ib]) - ls_flatness_mm(x, y, z[ia])
    lo, hi = np.quantile(null, [0.025, 0.975])
    out.update({
        "repeatability_mm": sigma,
        "repeatability_dof": n - 3,
        "matched_points": int(n),
        "matched_change_mm": float(obs),
        "null_change_std_mm": float(null.std()),
        "null_change_95_mm": [float(lo), float(hi)],
        "p_value": float((np.sum(np.abs(null) >= abs(obs)) + 1) / (draws + 1)),
        "flatness_noise_free_95_mm": [
            [float(v) for v in np.quantile(fa, [0.025, 0.975])],
            [float(v) for v in np.quantile(fb, [0.025, 0.975])]],
        "method": "paired rounds at the same touch points; parametric bootstrap under "
                  "'plate unchanged' with the repeatability from the round difference",
    })
    out["exceeds_noise"] = bool(out["p_value"] < 0.05)
    return out
