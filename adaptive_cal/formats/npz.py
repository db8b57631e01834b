"""Arrays a run saved (belief.npz), read back with the file named in any error: a file cut
short, overwritten or from another program says which file and what is wrong with it."""
from __future__ import annotations

import os
import zipfile

import numpy as np

BELIEF_KEYS = ("mean", "cov", "hyper", "knots_x", "knots_y")
# the variance of structure finer than the knots on a grid over the workplane (saved since
# 2026-11-24; an older belief.npz lacks them: its bands are the spline's alone)
UNRESOLVED_KEYS = ("unresolved_x_mm", "unresolved_y_mm", "unresolved_var_mm2")
# the form kernel of the hyper-parameters (saved since 2026-12-01; older: squared exponential)
KERNEL_KEY = "kernel"


def read_npz(path: str | os.PathLike, keys=BELIEF_KEYS,
             optional=UNRESOLVED_KEYS + (KERNEL_KEY,)) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the .npz file at ``path`` (no pickled objects), and those of
    ``optional`` it holds; ValueError naming the file when it is not an .npz numpy wrote or
    lacks one of ``keys``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            held = list(data.files)
            arrays = {k: data[k] for k in (*keys, *optional) if k in held}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise ValueError(f"{path}: not an .npz file adaptive-cal wrote ({e}); was it cut "
                         "short or overwritten?") from None
    except ValueError:  # not an archive numpy reads, or an array of pickled objects
        raise ValueError(f"{path}: not an .npz file adaptive-cal wrote (not a zip archive of plain "
                         "arrays); was it cut short or overwritten?") from None
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise ValueError(f"{path}: no array {missing[0]!r} (it holds "
                         f"{', '.join(held) or 'nothing'}): not a file adaptive-cal wrote")
    return arrays


def unresolved_at(data, x_mm, y_mm) -> np.ndarray:
    """s_u^2 (mm^2) at points from a saved belief's grid (``run.results.unresolved_grid``;
    bilinear, the nearest edge value outside it); 0 for a belief saved without one."""
    x, y = np.broadcast_arrays(np.asarray(x_mm, float), np.asarray(y_mm, float))
    if "unresolved_var_mm2" not in data:
        return np.zeros(x.shape)
    from scipy.interpolate import RegularGridInterpolator

    gx, gy = np.asarray(data["unresolved_x_mm"]), np.asarray(data["unresolved_y_mm"])
    f = RegularGridInterpolator((gx, gy), np.asarray(data["unresolved_var_mm2"]))
    pts = np.c_[np.clip(x.ravel(), gx[0], gx[-1]), np.clip(y.ravel(), gy[0], gy[-1])]
    return np.maximum(f(pts), 0.0).reshape(x.shape)


def broken_belief(data) -> str | None:
    """Which of a saved belief's arrays (``data``: read_npz's) is not a posterior's -- NaN or
    infinite values, or a covariance with negative variances or asymmetric -- or None. An
    outside audit (2026-11-29): a NaN mean wrote Znan, a NaN or negated covariance switched
    compensate's band check off."""
    mean, cov = np.asarray(data["mean"], float), np.asarray(data["cov"], float)
    bad = next((k for k, a in (("mean", mean), ("cov", cov)) if not np.all(np.isfinite(a))), None)
    if bad is None and (np.any(np.diag(cov) < 0) or not np.allclose(
            cov, cov.T, rtol=0, atol=1e-9 * np.abs(cov).max(initial=0.0))):
        bad = "cov"  # negative variances or asymmetric: no covariance (a band would be wrong)
    return bad


def broken_text(path, bad: str) -> str:
    """The message naming ``broken_belief``'s array ``bad`` of the file at ``path``."""
    return (f"{path}: array {bad!r} is not a map's (NaN or infinite values, or a covariance "
            "with negative variances): was it edited or cut short?")


def saved_hyper(data: dict):
    """The hyper-parameters a belief.npz holds (``read_npz``'s arrays): its three numbers and
    its form kernel (squared exponential where an older file names none)."""
    from adaptive_cal.gaussian.prior import Hyper

    kernel = str(data[KERNEL_KEY]) if KERNEL_KEY in data else "se"
    return Hyper(*np.asarray(data["hyper"], float).tolist()[:3], kernel=kernel)
