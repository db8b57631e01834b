"""explain's evidence of many one-column models at once (the bump search's thousands of centres
and prior scales): ``evidence.log_evidence_spectral``'s numbers to round-off
(tests/test_explain_speed_exact.py), several times as fast."""
from __future__ import annotations

import numpy as np

from adaptive_cal.analysis.explain.quadrature import (LOG2PI, NEWTON_TOL, TIGHT, _log_integral,
                                                      coarse_grid, rules)


def _spectral1(lam, c2, rest, m, w, v):
    """``_spectral`` of one-column models, the same operations in the same order, without the k
    axis: lam, c2, rest (...); w and v = e^w broadcast against them on a trailing grid axis."""
    a = np.add(v, lam[..., None])
    g = np.log(a)
    g *= 0.5
    np.subtract(-0.5 * m * LOG2PI - 0.5 * (m - 1) * w, g, out=g)
    np.divide(c2[..., None], a, out=a)
    out = np.divide(rest[..., None], v)
    out += a
    out *= 0.5
    g -= out
    return g


def _derivs1(lam, c2, rest, m, w):
    """``_derivs`` of one-column models: the same operations in the same order."""
    v = np.exp(w)
    a = v + lam
    a2 = a ** 2
    r = 0.5 * rest / v
    cv = c2 * v
    d1 = (-0.5 * (m - 1) - 0.5 * (v / a) + r + 0.5 * (cv / a2))
    d2 = (-0.5 * (v * lam / a2) - r + 0.5 * (cv * (lam - v) / a ** 3))
    return d1, d2


def _newton1(lam, c2, rest, m, w):
    """``log_evidence_spectral``'s Newton steps from w, and the sd of w at the mode: a model
    whose step was within ``NEWTON_TOL`` takes no more (most: after 4 of the 12)."""
    w, idx, on = np.array(w, float), np.arange(w.size), (lam, c2, rest, np.array(w, float))
    for _ in range(12):  # Newton, steps clipped to the coarse spacing
        if not idx.size:
            break
        d1, d2 = _derivs1(*on[:3], m, on[3])
        step = np.clip(np.where(d2 < 0, -d1 / np.where(d2 < 0, d2, -1.0), np.sign(d1) * 0.3),
                       -0.3, 0.3)
        new = on[3] + step
        w[idx], moved = new, np.abs(step) > NEWTON_TOL
        idx, on = idx[moved], tuple(a[moved] for a in on[:3]) + (new[moved],)
    _, d2 = _derivs1(lam, c2, rest, m, w)
    return w, 1.0 / np.sqrt(np.maximum(-d2, 1e-2))


CHUNK = 512  # one-column models per pass: their grids of 61-110 coarse values stay in L2 cache
WINDOW = 8  # coarse grid points evaluated where the bounds below confine the argmax


def _start1(lam, c2, rest, m, coarse, v_coarse) -> np.ndarray:
    """Newton's start for one-column models: the coarse grid's best w (as in
    ``log_evidence_spectral``), evaluating the grid only where its argmax can be. With
    h = (m - 1) / 2 and v = e^w,

        d/dw log p(z | v) = -h - v / 2(v + lam) + rest / 2v + c2 v / 2(v + lam)^2

    lies between -h - 1/2 + rest / 2v and -h + (rest + c2) / 2v (lam, c2 >= 0): the integrand
    rises below v = rest / m, falls above v = (rest + c2) / (m - 1). 0.9 (3 grid steps) beyond
    either bound its slope exceeds 0.26 h: each grid step there changes it by over 0.08 h (0.04
    at m = 2), far above round-off, so no grid point out there can tie the window's edge. Where
    the window spans at most ``WINDOW`` points (c2 << rest: nearly every bump centre) only those
    are evaluated, at the grid's own values: the whole grid's argmax, first occurrence too.

    Where the bounds themselves are less than ``TIGHT`` apart in w (c2 below about a tenth of
    rest: most bump centres), the mode is within TIGHT / 2 of their midpoint, where the
    integrand is concave (its curvature there is about -m / 2, the c2 term's at most a tenth of
    that): Newton starts at the midpoint instead of the grid's best point, and reaches the same
    mode (to ``NEWTON_TOL``) in two or three steps."""
    w, narrow = np.empty(lam.size), np.zeros(lam.size, bool)
    step, last = (coarse[-1] - coarse[0]) / (coarse.size - 1), coarse.size - 1
    if m > 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            w_lo, w_hi = np.log(rest / m), np.log((rest + c2) / (m - 1))
            lo = (w_lo - 0.9 - coarse[0]) / step
            hi = (w_hi + 0.9 - coarse[0]) / step
        narrow = ~np.isnan(lo) & ~np.isnan(hi)
        tight = narrow & (w_hi - w_lo < TIGHT)
        w[tight] = 0.5 * (w_lo[tight] + w_hi[tight])
        j_lo = np.clip(np.floor(np.where(narrow, lo, 0.0)), 0, last).astype(int)
        narrow &= np.clip(np.ceil(np.where(narrow, hi, 0.0)), 0, last) - j_lo < WINDOW
        narrow &= ~tight
        if tight.all():
            return w
    else:
        tight = narrow
    idx = np.flatnonzero(narrow)
    for j in range(0, idx.size, 8 * CHUNK):  # grids of 8 points: as many values as 512 x 61
        c = idx[j:j + 8 * CHUNK]
        J = np.minimum(j_lo[c, None] + np.arange(WINDOW), last)
        g = _spectral1(lam[c], c2[c], rest[c], m, coarse[J], v_coarse[J])
        w[c] = coarse[np.minimum(j_lo[c] + np.argmax(g, axis=-1), last)]
    idx = np.flatnonzero(~narrow & ~tight)
    for j in range(0, idx.size, CHUNK):
        c = idx[j:j + CHUNK]
        w[c] = coarse[np.argmax(_spectral1(lam[c], c2[c], rest[c], m, coarse, v_coarse), axis=-1)]
    return w


def log_evidence_spectral1(lam, c2, yy, m) -> tuple[np.ndarray, np.ndarray]:
    """``log_evidence_spectral`` of one-column models, lam and c2 (...) not (..., 1): the same
    numbers to round-off (tests/test_explain_speed_exact.py), several times as fast: ``_start1``,
    no k axis, e^w of the coarse grid once, grids ``CHUNK`` models at a time (L2 cache)."""
    lam, c2 = np.broadcast_arrays(np.asarray(lam, float), np.asarray(c2, float))
    shape, lam, c2, yy = lam.shape, lam.reshape(-1), c2.reshape(-1), float(yy)
    rest = np.maximum(yy - c2, 1e-12 * np.asarray(yy, float))
    coarse = coarse_grid(yy, m, float(np.min(rest, initial=yy)))
    w, sd = _start1(lam, c2, rest, m, coarse, np.exp(coarse)), np.empty(lam.size)
    for j in range(0, lam.size, 8 * CHUNK):  # 8 x as many: vectors of 32 kB, not a grid each
        c = slice(j, j + 8 * CHUNK)
        w[c], sd[c] = _newton1(lam[c], c2[c], rest[c], m, w[c])
    log_z = np.empty(lam.size)
    for on, t, log_weight in rules(m - 1, rest, c2):
        idx = np.flatnonzero(on)
        for c in [idx[j:j + CHUNK] for j in range(0, idx.size, CHUNK)]:
            grid = w[c, None] + sd[c, None] * t
            log_z[c] = _log_integral(_spectral1(lam[c], c2[c], rest[c], m, grid, np.exp(grid)),
                                     log_weight)
    log_z = log_z + np.log(sd) + np.log(0.5)  # dsigma/sigma = dw / 2
    return log_z.reshape(shape), w.reshape(shape)
