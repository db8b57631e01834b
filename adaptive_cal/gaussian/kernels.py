"""The form prior's correlation between two knots, k(d) for an offset d along one axis (the 2-D
correlation is the product of the two axes'). Two families, weighed by their evidence at every
refit (``prior.learned_belief``):

* ``se``: squared exponential, exp(-d^2 / (2 l^2)) -- infinitely smooth: the family of the
  project's own prior and of milled, well-behaved plates;
* ``m52``: Matern-5/2, (1 + r + r^2 / 3) exp(-r), r = sqrt(5) |d| / l (Rasmussen & Williams
  2006, eq. 4.17) -- twice differentiable: a rough plate's form has power at short wavelengths
  that the squared exponential gives none, so fitted with it alone the bands narrowed to
  what the smooth family allows and covered 0.76-0.83 of the benchmark's gentler rough plates.

Both are written for numpy and for JAX (``xp``); the Matern's |d| is a constant of the data,
never differentiated, so its gradient in l is finite at d = 0.
"""
from __future__ import annotations

import numpy as np

#: the kernels a learned belief weighs, the first the default (a configured prior's own)
KERNELS = ("se", "m52")
#: their names in words
KERNEL_NAMES = {"se": "squared exponential", "m52": "Matern-5/2"}


def correlation(d, length_mm, kernel: str = "se", xp=np):
    """k(d) for offsets ``d`` (mm, any shape) at length scale ``length_mm``."""
    if kernel == "se":
        return xp.exp(-0.5 * (d / length_mm) ** 2)
    if kernel == "m52":
        r = np.sqrt(5.0) * xp.abs(d) / length_mm
        return (1.0 + r + r * r / 3.0) * xp.exp(-r)
    raise ValueError(f"kernel {kernel!r} is not one of {', '.join(KERNELS)}")


def knot_correlation(knots, length_mm, kernel: str = "se", xp=np):
    """The correlation matrix of the form's coefficients along one axis's knots."""
    return correlation(knots[:, None] - knots[None, :], length_mm, kernel, xp)
