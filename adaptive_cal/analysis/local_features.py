"""Local features a retake confirmed and the map does not follow.

The gate retakes a reading far from the map (``planning.gate``). When the retake, an unselected
second reading at the same point, departs from the map in the same direction, the plate really
is there -- a dent, a burr, a chip narrower than the spline's knots -- and the spline cannot
follow it: its bands and the self-checks (mean squares over many readings) do not show it, and
the whole plate's flatness from the map would leave it out. Measured (docs/flatness.md): a run
that touched a 30 um dent (radius 20 mm) and confirmed it by the retake, -18 um against the
map, reported the whole plate's minimum zone as 2.1 um (95 % 1.2 .. 4.8) with the touched
points' at 32.8 um.

The test is on the retake alone (the gated reading was selected for being far off, so it is
not evidence): its leave-one-out residual against the map, e = (y - b m) r_w / (r_w - s) with
s = b C b^T and r_w = sigma^2 / w its fusion noise (the exact removal of one fused reading),
standardized by sqrt(sigma^2 + s r_w / (r_w - s)), beyond the two-sided normal bound at
``ALPHA`` shared over the run's retakes (Bonferroni), and of the gated reading's sign -- and
the map as it ends still more than ``FOLLOWS`` reading sds away from the retake (a map that
bent to it, near the edge where the retake carries much of the posterior, follows it). The
departure is the retake's height less the map's there, known to one reading's sd.

The plate families' gross errors are independent from reading to reading (benchmarks/plates),
so there a retake that agrees with its gated reading is the plate: the two runs of 20 on the
noisy family that named a feature named a place where the readings were right to 2 um and the
map was 17-25 um off (the plate's edge, y = 175 mm), and one of them was dropped by the
``FOLLOWS`` test (the map ended 5 um from the retake). On a real cell a chip under the tip that stays for
the retake is a feature of the plate too.
"""
from __future__ import annotations

import numpy as np
from scipy import special  # -ndtri(a): scipy.stats's norm.isf(a), without loading scipy.stats

from adaptive_cal.formats.recording import Recording, surface_height_mm
from adaptive_cal.gaussian import belief as bl
from adaptive_cal.planning.gate import SAME_POINT_MM, flagged_weight

ALPHA = 0.01  # false-alarm level over all of a run's retakes
MIN_RADIUS_MM = 5.0  # the bands widen at least this far around a confirmed feature
FOLLOWS = 2.0  # the map follows a retake it ends within this many reading sds of


def retake_pairs(rec: Recording) -> list[tuple[int, int]]:
    """(gated row, retake row) indices: a ``gated`` row followed by a fused ``retake`` at the
    same point."""
    if not rec.flags:
        return []
    fused = rec.fused
    out = []
    for i in range(len(rec.flags) - 1):
        j = i + 1
        if ("gated" in rec.flags[i] and "retake" in rec.flags[j] and fused[j]
                and abs(rec.x_mm[i] - rec.x_mm[j]) <= SAME_POINT_MM
                and abs(rec.y_mm[i] - rec.y_mm[j]) <= SAME_POINT_MM
                and np.isfinite(rec.reading_mm[i]) and np.isfinite(rec.reading_mm[j])):
            out.append((i, j))
    return out


def confirmed(surface, belief: bl.Belief, noise_std_mm: float, rec: Recording,
              zero_mm: float) -> list[dict]:
    """Local features the retakes confirmed (module docstring), JSON-ready: {x_mm, y_mm,
    departure_mm (the retake's height less the map's), sd_mm (the reading noise), z (the
    retake's standardized leave-one-out residual), seq [gated, retake], nearest_touch_mm (the
    distance to the nearest other fused touch)}."""
    pairs = retake_pairs(rec)
    if not pairs or not noise_std_mm > 0:
        return []
    zc = float(-special.ndtri(ALPHA / (2 * len(pairs))))
    sigma2 = float(noise_std_mm) ** 2
    fused = np.flatnonzero(rec.fused)
    out = []
    for i, j in pairs:
        x, y = float(rec.x_mm[j]), float(rec.y_mm[j])
        b = surface.basis(np.array([x]), np.array([y]))[0]
        mean = float(b @ belief.mean)
        s = float(b @ belief.cov @ b)
        rw = sigma2 / flagged_weight(rec.flags[j])
        if rw <= s:  # the reading carries nearly all the posterior there: nothing to leave out
            continue
        g = rw / (rw - s)
        h_r = surface_height_mm(rec.reading_mm[j], rec.z_mm[j], zero_mm)
        h_g = surface_height_mm(rec.reading_mm[i], rec.z_mm[i], zero_mm)
        e = (h_r - mean) * g
        z = e / float(np.sqrt(sigma2 + s * g))
        mean_without = h_r - e  # the map's height there without the retake
        if (abs(z) <= zc or np.sign(h_g - mean_without) != np.sign(e)
                or abs(h_r - mean) <= FOLLOWS * np.sqrt(sigma2)):
            continue
        others = [k for k in fused if k not in (i, j)]
        near = (float(np.min(np.hypot(rec.x_mm[others] - x, rec.y_mm[others] - y)))
                if others else None)
        out.append({"x_mm": x, "y_mm": y, "departure_mm": float(h_r - mean),
                    "sd_mm": float(np.sqrt(sigma2)), "z": float(z),
                    "seq": [int(rec.seq[i]), int(rec.seq[j])],
                    "nearest_touch_mm": near})
    return out


def feature_line(f: dict) -> str:
    where = "below" if f["departure_mm"] < 0 else "above"
    near = (f"; no other touch within {f['nearest_touch_mm']:.0f} mm"
            if f.get("nearest_touch_mm") is not None else "")
    return (f"local feature at ({f['x_mm']:.0f}, {f['y_mm']:.0f}) mm: the retake (seq "
            f"{f['seq'][1]}) confirmed the gated reading, {abs(f['departure_mm']) * 1e3:.1f} um "
            f"{where} the map (sd {f['sd_mm'] * 1e3:.1f} um); the map does not follow it, the "
            f"whole plate's flatness includes it{near}")


def feature_var_mm2(features, x_mm, y_mm) -> np.ndarray:
    """The variance the confirmed features add to the bands at points (x, y): departure^2 +
    sd^2 within the nearest other touch's distance of each (where no touch says the plate
    follows the map again; at least ``MIN_RADIUS_MM``), 0 elsewhere. In belief.npz's grid of
    unresolved variance, so the report's bands and ``compensate``'s refusals see them, and in
    the run's surface.png."""
    x, y = np.broadcast_arrays(np.asarray(x_mm, float), np.asarray(y_mm, float))
    out = np.zeros(x.shape)
    for f in features:
        r = max(f.get("nearest_touch_mm") or 0.0, MIN_RADIUS_MM)
        inside = np.hypot(x - f["x_mm"], y - f["y_mm"]) <= r
        out = out + np.where(inside, f["departure_mm"] ** 2 + f["sd_mm"] ** 2, 0.0)
    return out


def weighted_out(seqs, weights) -> list[dict]:
    """The fused readings the map weighted out as gross errors (weight <= 0.5, an outlier
    probability p = 1 - weight >= 0.5): [{seq, outlier_probability}]. Readings the map does not
    follow either, so the run, the flatness command and the page name them alike."""
    return [{"seq": int(q), "outlier_probability": round(1.0 - float(w), 4)}
            for q, w in zip(seqs, weights) if w <= 0.5]


def weighted_out_line(out: list[dict]) -> str | None:
    """The line naming ``weighted_out``'s readings (None for none)."""
    if not out:
        return None
    n = len(out)
    shown = ", ".join(f"seq {w['seq']} (p {w['outlier_probability']:.2f})" for w in out[:5])
    return (f"{n} reading{'s' * (n != 1)} weighted out of the map as gross error"
            f"{'s' * (n != 1)} (outlier probability >= 0.5): {shown}{' ...' if n > 5 else ''}; "
            f"the touched points' figures include {'them' if n != 1 else 'it'}, their intervals "
            "(repeats of the map) do not")
