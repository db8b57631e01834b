"""The greedy search of ``identify.suggest_touches``, scored in batches.

Each greedy step scores every menu item (a few extra touches) by the smallest canonical
correlation of the effect with the tilt and its partners on the design plus the chosen touches
plus the item (``identify._alias_cc_of``). That number depends on the columns W = [design rows;
extra rows] only through W^T W, so the design's thousands of rows enter as R of their QR (K x
K), and the chosen touches are folded into it as they are chosen. A step then stacks [R; item
rows], one K-column matrix per item (items of unequal length padded with zero rows, which leave
W^T W as it is), and ``min_cc`` scores them all in one pass of batched SVDs: 12 steps of
30-40 items cost about 12 vectorised passes instead of about 400 scorings of 0.5-0.9 ms each
(measured on 4,000 Student-t rows, where ``probe_gain`` is aliased with the tilt).

``min_cc`` is ``_alias_cc_of`` on a stack: the same projections, the same rank rules (a
singular value counts above 1e-9 of the largest, the rounds' offsets above 1e-10; SVD in place
of the pivoted QR ``Projector.of`` uses: the same subspace where the rank is clear), the same
zeroing of centred columns that were constant. It agrees with the loop to round-off
(tests/test_explain.py).
"""
from __future__ import annotations

import numpy as np

ORTH_RTOL = 1e-9  # identify._orth
OFFSET_RTOL = 1e-10  # evidence.Projector.of
CONSTANT_RTOL = 1e-9  # identify._centred
TIE = 1e-12  # canonical correlations this close are equal


def _basis(X: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of each X's column span, stacked: U (b, n, k) with the columns beyond
    each one's rank zeroed, and the ranks (b,)."""
    if X.shape[-1] == 0:
        return np.zeros(X.shape[:-1] + (0,)), np.zeros(X.shape[0], int)
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    keep = s > rtol * np.maximum(s.max(axis=-1, keepdims=True, initial=0.0), 1e-300)
    return U * keep[:, None, :], keep.sum(axis=-1)


def min_cc(W: np.ndarray, widths: tuple) -> np.ndarray:
    """``identify._alias_cc_of`` of each W[i] (b, rows, K): [tilt per round (3 a round) | the
    effect | partners], the smallest canonical correlation of the effect with the rest, each
    about each round's mean."""
    T, E, *P = np.split(W, np.cumsum(widths)[:-1], axis=-1)
    Q, _ = _basis(T[..., 2::3], OFFSET_RTOL)
    off = lambda A: A - Q @ (np.swapaxes(Q, -1, -2) @ A)

    def centred(A):
        C = off(A)
        small = (np.linalg.norm(C, axis=-2)
                 <= CONSTANT_RTOL * np.maximum(np.linalg.norm(A, axis=-2), 1e-300))
        return np.where(small[:, None, :], 0.0, C)

    QE, rE = _basis(centred(E), ORTH_RTOL)
    QF, rF = _basis(np.concatenate([off(T)] + [centred(B) for B in P], axis=-1), ORTH_RTOL)
    s = np.clip(np.linalg.svd(np.swapaxes(QF, -1, -2) @ QE, compute_uv=False), 0.0, 1.0)
    r = np.minimum(rE, rF)  # the loop's SVD has min(rank F, rank E) values; the rest are 0 here
    out = s[np.arange(len(s)), np.maximum(r - 1, 0)]
    out = np.where(rF == 0, 0.0, out)
    return np.where(rE == 0, 1.0, out)  # an all-zero regressor is invisible: fully aliased


def first_best(scores) -> int:
    """The first try whose score is the least to round-off (1e-12): mirror-image places tie,
    and the pick then follows the menu's order, not the last bits of an SVD."""
    scores = np.asarray(scores, float)
    return int(np.flatnonzero(scores <= scores.min() + TIE)[0])


def search(W0: np.ndarray, widths: tuple, blocks: list[np.ndarray], menu: list[list[dict]],
           cc: float, target: float, max_extra: int) -> tuple[list[dict], float]:
    """Greedy: add the menu item that lowers the canonical correlation most, until it is at most
    ``target``, the menu is spent or ``max_extra`` touches are chosen. ``W0``: the design's
    columns; ``blocks[i]``: the columns' rows of ``menu[i]``'s touches, a function of each
    touch's own features (the caller has checked this). Returns the chosen touches and the
    canonical correlation after them (``cc`` where none is chosen)."""
    menu, blocks = list(menu), list(blocks)
    R = np.linalg.qr(W0, mode="r")
    chosen: list[dict] = []
    while cc > target and menu and len(chosen) < max_extra:
        L = max(len(b) for b in blocks)
        stack = np.zeros((len(menu), R.shape[0] + L, R.shape[1]))
        stack[:, :R.shape[0]] = R
        for i, b in enumerate(blocks):
            stack[i, R.shape[0]:R.shape[0] + len(b)] = b
        scores = min_cc(stack, widths)
        best = first_best(scores)
        chosen += menu.pop(best)
        R = np.linalg.qr(np.vstack([R, blocks.pop(best)]), mode="r")
        cc = float(scores[best])
    return chosen, cc
