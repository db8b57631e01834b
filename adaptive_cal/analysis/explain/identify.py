"""Identifiability for this design, and the smallest change of plan that separates effects.

An effect E is aliased with a set F (the tilt of each round, possibly another effect) when every
direction of span(E) lies nearly in span(F): the smallest canonical correlation between the two
spans exceeds ``ALIAS_CC`` (0.99: the tilt absorbs more than 99 % of the regressor's norm, less
than 14 % is left to see). For one-column effects the canonical correlation is |P_F x| / |x|.
Between two effects this is directional (``spans``): A inside B's span is not B inside A's.

``suggest_touches`` adds touches from a menu that fits the residual axis the effect shows on
(time: repeats of reference points at a later time; direction: a reversed pass; indication: a
second approach height; position, for a bump: touches in the largest gaps) greedily, one at a
time, until the canonical correlation falls to ``TARGET_CC`` (0.9), as (x_mm, y_mm, z_mm, order).
"""
from __future__ import annotations

import numpy as np

from adaptive_cal import effects
from adaptive_cal.analysis.explain.candidates import CANDIDATES, Context, prior_scale
from adaptive_cal.analysis.explain import greedy, spans
from adaptive_cal.analysis.explain.evidence import Projector

ALIAS_CC = spans.ALIAS_CC
TARGET_CC = 0.9
MAX_EXTRA = 12


def _orth(X: np.ndarray) -> np.ndarray:
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > 1e-9 * max(s.max(initial=0.0), 1e-300)]


def canonical_correlations(E: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Cosines of the principal angles between span(E) and span(F), largest first."""
    QE, QF = _orth(E), _orth(F)
    if QE.shape[1] == 0:
        return np.ones(1)  # an all-zero regressor is invisible: fully aliased
    if QF.shape[1] == 0:
        return np.zeros(QE.shape[1])
    return np.clip(np.linalg.svd(QF.T @ QE, compute_uv=False), 0.0, 1.0)


def _centred(off: Projector, E: np.ndarray) -> np.ndarray:
    """E about each round's mean; columns that were (nearly) constant become exactly zero."""
    C = off(E)
    small = np.linalg.norm(C, axis=0) <= 1e-9 * np.maximum(np.linalg.norm(E, axis=0), 1e-300)
    C[:, small] = 0.0
    return C


def _shown(effect: effects.Effect) -> tuple[str, ...]:
    """The linear parameters whose regressor stands for the effect (its plain part if any)."""
    return effect.plain or effect.linear


def _is_bump(effect: effects.Effect) -> bool:
    """Confined to a searched place on the plate (local_defect): checked by coverage instead."""
    return effect.axis == "position" and bool(effect.searched)


def representative(ctx: Context, name: str, features=None, round_index=None) -> np.ndarray:
    """The effect's regressor (shared parameters, nonlinear ones at their defaults: sag p = 2;
    thermal_drift: the linear rate)."""
    d = ctx.design
    f = features if features is not None else d.features
    effect = effects.get(name)
    return effect.regressor(f, d.geometry, names=_shown(effect))


def _tilt(features, round_index, rounds, geometry) -> np.ndarray:
    T = effects.tilt.regressor(features, geometry)
    if rounds == 1:
        return np.array(T, float)
    out = np.zeros((T.shape[0], 3 * rounds))
    out[np.arange(T.shape[0])[:, None], 3 * np.asarray(round_index)[:, None] + np.arange(3)] = T
    return out


def _touch_features(extra: list[dict]) -> tuple[effects.Features, np.ndarray]:
    """Features and rounds of extra touches (dicts with x, y, z, t, direction, ideal, round)."""
    col = lambda k: np.array([e[k] for e in extra], float)
    feats = effects.Features(col("x_mm"), col("y_mm"), col("t_s"), col("direction"), col("ideal"))
    return feats, col("round").astype(int)


def _augment(ctx: Context, extra: list[dict]) -> tuple[effects.Features, np.ndarray]:
    """Features and rounds of the design plus extra touches (``_touch_features``)."""
    f, (g, s) = ctx.design.features, _touch_features(extra)
    cat = lambda k: np.concatenate([getattr(f, k), getattr(g, k)])
    return (effects.Features(*map(cat, ("x_mm", "y_mm", "t_s", "direction", "ideal_reading_mm"))),
            np.concatenate([ctx.design.round_index, s]).astype(int))


def _alias_columns(ctx, name, partners, feats, ridx) -> tuple[np.ndarray, tuple]:
    """[tilt per round | the effect | each partner] on these touches, and the blocks' widths."""
    d = ctx.design
    blocks = [_tilt(feats, ridx, d.rounds, d.geometry), representative(ctx, name, feats)]
    blocks += [representative(ctx, p, feats) for p in partners if p != "tilt"]
    return np.hstack(blocks), tuple(b.shape[1] for b in blocks)


def _alias_cc_of(W: np.ndarray, widths: tuple) -> float:
    """The smallest canonical correlation of the effect with the tilt and the partners, each
    about each round's mean, from ``_alias_columns``. It depends on W only through W^T W
    (norms and angles of its columns), so any rows with the same Gram matrix give it."""
    T, E, *P = np.split(W, np.cumsum(widths)[:-1], axis=1)
    off = Projector.of(T[:, 2::3])
    F = [off(T)] + [_centred(off, B) for B in P]
    return float(canonical_correlations(_centred(off, E), np.hstack(F)).min())


def _alias_cc(ctx, name, partners, feats, ridx) -> float:
    return _alias_cc_of(*_alias_columns(ctx, name, partners, feats, ridx))


def _greedy(ctx, name, partners, menu, cc) -> tuple[list[dict], float]:
    """The greedy search over ``menu`` (``greedy.search``, batched). It scores from R of the
    design's columns and each item's own rows, so it first checks that every column is a function
    of each touch's own features (the design's rows unchanged by extra touches, the extra rows
    those of the touches alone); where not, each try is the whole matrix, one at a time."""
    every = [t for item in menu for t in item]
    W0, widths = _alias_columns(ctx, name, partners, *_augment(ctx, []))
    W, _ = _alias_columns(ctx, name, partners, *_augment(ctx, every))
    own = _alias_columns(ctx, name, partners, *_touch_features(every))[0]
    n0 = W0.shape[0]
    if np.array_equal(W[:n0], W0) and np.array_equal(W[n0:], own):
        blocks = np.split(own, np.cumsum([len(item) for item in menu])[:-1])
        return greedy.search(W0, widths, blocks, menu, cc, TARGET_CC, MAX_EXTRA)
    menu, chosen = list(menu), []
    while cc > TARGET_CC and menu and len(chosen) < MAX_EXTRA:
        scores = [_alias_cc(ctx, name, partners, *_augment(ctx, chosen + i)) for i in menu]
        best = greedy.first_best(scores)
        chosen, cc = chosen + menu.pop(best), scores[best]
    return chosen, cc


def _menu(ctx: Context, name: str, dz_mm: float) -> list[list[dict]]:
    """Candidate additions (each a short list of touches, in order) along the effect's axis."""
    d = ctx.design
    f = d.features
    idx = _last_round_of(d)
    t_end = float(f.t_s[idx].max())
    dt = float(np.median(np.diff(f.t_s[idx]))) if idx.size > 1 else 1.0
    pick = idx[np.linspace(0, idx.size - 1, min(idx.size, 40)).astype(int)]
    r = d.rounds - 1
    touch = lambda i, **k: {"x_mm": f.x_mm[i], "y_mm": f.y_mm[i], "z_mm": d.z_mm[i],
                            "t_s": t_end + dt, "direction": f.direction[i],
                            "ideal": f.ideal_reading_mm[i], "round": r, **k}
    axis = effects.get(name).axis
    if axis == "time":
        return [[touch(i)] for i in pick]
    if axis == "indication":
        return [[touch(i, z_mm=d.z_mm[i] + dz_mm, ideal=f.ideal_reading_mm[i] - dz_mm)]
                for i in pick]
    if axis == "direction":
        rows = {}
        for i in idx:
            rows.setdefault(round(float(f.y_mm[i]), 3), []).append(i)
        out = []
        for members in rows.values():
            members = sorted(members, key=lambda i: f.x_mm[i])
            if len(members) < 2:
                continue
            mean_dir = np.mean(f.direction[members])
            order = members[::-1] if mean_dir >= 0 else members  # against the usual direction
            step = -1.0 if mean_dir >= 0 else 1.0
            out.append([touch(i, direction=step) for i in order])
        return out
    return []


def suggest_touches(ctx: Context, name: str, partners: list[str], dz_mm: float = 2.0) -> dict:
    """Smallest set of extra touches (greedy) that separates ``name`` from ``partners``."""
    d = ctx.design
    effect = effects.get(name)
    along_reach = [p for p in partners if p != "tilt" and effects.get(p).axis == "reach"]
    if _is_bump(effect):  # touch where none reached
        return _gap_touches(ctx)
    if effect.axis == "reach" or (along_reach and effect.axis == "position"):
        sag = name if effect.axis == "reach" else along_reach[0]
        return {"description": f"no touch on this plate separates {sag} (reach) from the plate's "
                "form (reach is a function of x, y): measure a reference flat of known form, or "
                "the same plate with the robot base moved", "touches": [], "canonical_correlation_after": None}
    menu = _menu(ctx, name, dz_mm)
    chosen: list[dict] = []
    cc = _alias_cc(ctx, name, partners, *_augment(ctx, []))
    if menu and cc > TARGET_CC:
        chosen, cc = _greedy(ctx, name, partners, menu, cc)
    what = {"time": "repeat reference point(s) at the end of the run",
            "direction": "a reversed pass (same points, arriving from the other side)",
            "indication": f"second approach height (z + {dz_mm:g} mm) at some points"}.get(
        effect.axis, "extra touches")
    n0 = int((d.round_index == d.rounds - 1).sum())
    touches = [{"x_mm": float(e["x_mm"]), "y_mm": float(e["y_mm"]), "z_mm": float(e["z_mm"]),
                "order": n0 + k} for k, e in enumerate(chosen)]
    return {"description": f"{what}: {len(touches)} touch(es) appended to the last round",
            "touches": touches, "canonical_correlation_after": round(cc, 4)}


def nearest_distance(gx, gy, px, py, neighbours: int = 8, others: bool = False) -> np.ndarray:
    """min over the points (px, py) of hypot(g - p) for every g, as the plain broadcast computes
    it, without the len(g) x len(p) matrix: a k-d tree proposes the ``neighbours`` nearest
    distinct points and the exact hypot of those is taken (the same minimum unless more than
    ``neighbours`` distinct points lie within rounding of one distance). ``others``: a point at
    the query itself does not count (the nearest *other* point; inf where there is none)."""
    from scipy.spatial import cKDTree

    pts = np.unique(np.stack([np.asarray(px, float), np.asarray(py, float)], 1), axis=0)
    k = min(neighbours + others, len(pts))
    _, j = cKDTree(pts).query(np.stack([gx, gy], 1), k=k)
    j = j.reshape(len(gx), k)
    dist = np.hypot(gx[:, None] - pts[j, 0], gy[:, None] - pts[j, 1])
    if others:
        dist[dist == 0.0] = np.inf
    return np.min(dist, 1)


def _approach_plane(d) -> tuple[np.ndarray, float]:
    """Plane (a, b, c) through the last round's surface heights as the probe saw them
    (z_mm + reading_mm: the commanded height plus the indication, up to the probe zero), and that
    round's median indication: an approach at plane(x, y) - indication expects that indication."""
    idx = _last_round_of(d)
    x, y = d.features.x_mm[idx], d.features.y_mm[idx]
    seen = d.z_mm[idx] + d.reading_mm[idx]
    xm, ym, sm = x.mean(), y.mean(), seen.mean()
    # a slope across touches on (or near) one line is not determined: it is taken as level
    # (singular values below a tenth of the largest dropped), not a plane at z = +-362,428 mm
    a, b = np.linalg.lstsq(np.stack([x - xm, y - ym], 1), seen - sm, rcond=0.1)[0]
    return np.array([a, b, sm - a * xm - b * ym]), float(np.median(d.reading_mm[idx]))


def _last_round_of(d) -> np.ndarray:
    return np.flatnonzero(d.round_index == d.rounds - 1)


def _gap_touches(ctx: Context, count: int = 4) -> dict:
    """Touches at the centres of the largest empty circles of the design (greedy maximin), among
    the places a run could touch: the cell's own rule (``Design.allows``, the workplane's edge
    margin and keep-outs, as the planner's candidate grid), at an approach height from a plane
    fitted to the last round (``_approach_plane``)."""
    d = ctx.design
    gx, gy = effects.defect_centres(d.geometry, 10.0)
    dist = nearest_distance(gx, gy, d.features.x_mm, d.features.y_mm)
    fill0 = float(dist.max())  # over the whole workplane: where a defect may sit
    if d.allows is not None:
        ok = d.allows(gx, gy)
        gx, gy, dist = gx[ok], gy[ok], dist[ok]
    n0 = int((d.round_index == d.rounds - 1).sum())
    (a, b, c), indication = _approach_plane(d)
    touches = []
    for k in range(min(count, gx.size)):
        i = int(np.argmax(dist))
        z_mm = float(a * gx[i] + b * gy[i] + c - indication)
        touches.append({"x_mm": float(gx[i]), "y_mm": float(gy[i]), "z_mm": round(z_mm, 4),
                        "order": n0 + k})
        dist = np.minimum(dist, np.hypot(gx - gx[i], gy - gy[i]))  # the new touch is a point too
    return {"description": f"fill distance {fill0:.0f} mm over the whole workplane (its edge "
            "margin and keep-outs included: where a defect may sit; run's 'largest gap' is of "
            "the reachable plate alone): a defect of smaller radius between "
            "touches reaches no touch; touches at the centres of the largest gaps a run could "
            "touch (inside the edge margin, outside the keep-outs), each approached at the "
            "height of a plane fitted to the last round's touches (z_mm + reading_mm), where "
            f"the indication is expected near that round's median {indication:.3f} mm",
            "touches": touches, "fill_distance_mm": fill0}


def not_identifiable(ctx: Context, sigma_mm: float | None, dz_mm: float = 2.0, *,
                     verdict: str | None = None, ambiguous: tuple[str, ...] = ()) -> list[dict]:
    """The ``not_identifiable`` block: effects the design cannot show (not testable), effects
    the tilt absorbs, and effects whose signature lies inside another's span (directional:
    ``spans``; ``inside_span_of``, with ``share_explained_by`` and ``explains_share_of`` per
    partner). The verdict is left out where the data separated it (no partner of it is in
    ``ambiguous``). ``sigma_mm``: the noise, None below the readout step (no sizes in sigma)."""
    d = ctx.design
    out = []
    names = [n for n in CANDIDATES if n not in d.unknown]
    why_not = d.untestable_why()
    for name in [n for n in names if n in why_not]:
        names.remove(name)
        fix = ("add robot.base_xy_mm: [x, y] (mm, workplane frame) to the cell file"
               if effects.get(name).axis == "reach" else
               "a pass that arrives at the same points moving -x as well as +x (a reversed row)")
        out.append({"effect": name, "aliased_with": [], "not_testable": True, "why": why_not[name],
                    "suggested_design": {"description": fix, "touches": []}})
    T = _tilt(d.features, d.round_index, d.rounds, d.geometry)
    offsets = Projector.of(T[:, 2::3])  # the variation about each round's mean
    bumps = [n for n in names if _is_bump(effects.get(n))]
    regs = {n: representative(ctx, n) for n in names if n not in bumps}
    projected = {n: ctx.project(E) for n, E in regs.items()}
    for name, E in regs.items():
        effect = effects.get(name)
        # its size in noise sds; not said below the readout step (sigma_mm None: the noise is
        # rounding, or 0 where every reading is the nominal)
        size = float(np.linalg.norm(projected[name], axis=0).max()) * prior_scale(
            effect, _shown(effect))
        left = (f"; an effect of typical prior size leaves {size / sigma_mm:.2f} reading-noise "
                "sd after the tilt" if sigma_mm else "")
        cc_t = canonical_correlations(_centred(offsets, E), offsets(T))
        if cc_t.min() > ALIAS_CC and name != verdict:  # a verdict passed the tilt: shown
            why = (f"the tilt absorbs {100 * cc_t.min() ** 2:.2f} % of the regressor's variation "
                   f"(canonical correlation {cc_t.min():.4f}){left}")
            if effect.axis == "time":
                why += ("; time is then a linear function of position on this design, so any "
                        "drift -- linear or a warm-up -- is a function of position too and "
                        "cannot be told from a plate shape: a warm-up named here rests on the "
                        "library's form being the plate's whole shape")
            out.append({"effect": name, "aliased_with": ["tilt"], "why": why,
                        "suggested_design": suggest_touches(ctx, name, ["tilt"], dz_mm)})
            continue
        if name == verdict and not ambiguous:
            continue  # the data separated the verdict from everything else
        partners = [o for o in regs if o != name and spans.inside(projected[name], projected[o])]
        if name == verdict:
            partners = [o for o in partners if o in ambiguous]
        if partners:
            shares = {o: spans.share(projected[name], projected[o]) for o in partners}
            back = {o: spans.share(projected[o], projected[name]) for o in partners}
            why = "after the tilt, its signature lies inside the span of " + ", ".join(
                f"{o} ({o} explains {100 * shares[o]:.1f} % of it; it explains {100 * back[o]:.1f} "
                f"% of {o}'s)" for o in partners)
            out.append({"effect": name, "aliased_with": partners, "inside_span_of": partners,
                        "share_explained_by": shares, "explains_share_of": back,
                        "mutual": [o for o in partners if spans.inside(projected[o], projected[name])],
                        "why": why,
                        "suggested_design": suggest_touches(ctx, name, ["tilt"] + partners, dz_mm)})
        elif cc_t.max() > ALIAS_CC and E.shape[1] > 1 and name != verdict:
            out.append({"effect": name, "aliased_with": ["tilt"], "why": (
                f"partly: one combination of its shapes is absorbed by the tilt (canonical "
                f"correlation {cc_t.max():.4f}); the others are identifiable"),
                "suggested_design": {"description": "touches at more distinct x and y values",
                                     "touches": []}})
    gap = _gap_touches(ctx) if bumps else None
    for name in bumps:
        if gap["fill_distance_mm"] > min(40.0, 0.5 * max(np.ptp(d.geometry.x_range_mm), 1.0)):
            out.append({"effect": name, "aliased_with": [],
                        "why": f"coverage: a defect of radius below {gap['fill_distance_mm']:.0f} "
                        "mm can sit between touches, anywhere on the workplane, and reach none "
                        "of them",
                        "suggested_design": gap})
    return out
