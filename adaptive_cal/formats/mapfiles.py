"""Height-map files as a cell or a study names them: paths beside the file that names them, and
the checks that a map lies within the probe's reach (``formats.heightmap`` reads the files)."""
from __future__ import annotations

import glob
from pathlib import Path

import numpy as np

from adaptive_cal.formats.heightmap import HeightMap, HeightMapError, load_heightmap


def beside(name: str, file: str | Path) -> str:
    """``name`` (a path) taken relative to the folder of ``file``, unless absolute."""
    p = Path(name)
    return str(p if p.is_absolute() else Path(file).resolve().parent / p)


def beside_glob(pattern: str, file: str | Path) -> str:
    """The glob ``pattern`` taken relative to the folder of ``file``, unless absolute; the
    folder's own name is escaped (a study in ``plates[1]/`` once globbed ``plates1/``'s maps)."""
    if Path(pattern).is_absolute():
        return pattern
    return str(Path(glob.escape(str(Path(file).resolve().parent))) / pattern)


SAMPLES = 101  # per axis: the uniform sample of the workplane a map's plane is fitted to


def plane_of(hm: HeightMap, x_mm, y_mm) -> tuple[float, float, float, float]:
    """a, b, c, form: the plane z = a (x - xc) + b (y - yc) + c of least squares through the map
    as the simulated cell reads it (bilinear) on x_mm x y_mm (centre xc, yc), fitted to a
    uniform SAMPLES x SAMPLES sample of it, and the largest departure from that plane (mm) --
    exact: a bilinear cell less a plane peaks at a corner, so the departure is taken where the
    map's node lines and the workplane's edges cross. The map's nodes alone missed a coarse
    map whose nodes lie outside the workplane (none left to fit) or only at its middle."""
    def lines(nodes, lo, hi):
        return np.unique(np.r_[lo, hi, nodes[(nodes > lo) & (nodes < hi)]])

    xc, yc = 0.5 * sum(x_mm), 0.5 * sum(y_mm)
    X, Y = np.meshgrid(np.linspace(*x_mm, SAMPLES), np.linspace(*y_mm, SAMPLES), indexing="ij")
    A = np.c_[X.ravel() - xc, Y.ravel() - yc, np.ones(X.size)]
    abc = np.linalg.lstsq(A, hm(X.ravel(), Y.ravel()), rcond=None)[0]
    X, Y = np.meshgrid(lines(hm.x_mm, *x_mm), lines(hm.y_mm, *y_mm), indexing="ij")
    x, y = X.ravel(), Y.ravel()
    form = np.abs(hm(x, y) - (abc[0] * (x - xc) + abc[1] * (y - yc) + abc[2])).max()
    return float(abc[0]), float(abc[1]), float(abc[2]), float(form)


def check_map(path: str | Path, workplane, key: str, usable_mm=None, offset_mm: float = 0.0
              ) -> HeightMap:
    """The map at ``path`` if it loads and covers ``workplane``, else HeightMapError opening with
    ``key``; with the probe's ``usable_mm`` also refused: a plane at the plate centre (plus
    ``offset_mm``, the tilt effect's c) beyond half the usable stroke from the prior's 0, or a
    form 20 times that (a map in um read as mm: a 999 mm spike ran to a 34 mm 'true error')."""
    try:
        hm = load_heightmap(path).check_covers(workplane.x_mm, workplane.y_mm)
    except HeightMapError as e:
        raise HeightMapError(f"{key}: {e}") from None
    if usable_mm is None:  # a study's map: study.config.map_in_reach holds it to its prior
        return hm
    c, form = np.array(plane_of(hm, workplane.x_mm, workplane.y_mm)[2:]) + (offset_mm, 0)
    half, tilt = 0.5 * (usable_mm[1] - usable_mm[0]), " (with the tilt effect's c)"
    if abs(c) > half or form > 20 * half:
        raise HeightMapError(
            f"{key}: {path}: its plane stands {c:+.3f} mm at the plate centre"
            f"{tilt * bool(offset_mm)}, its form {form:.3f} mm: past the +-{half:g} mm of the "
            "probe's usable stroke about the prior's 0 (heights in um? a map's are mm)")
    return hm
