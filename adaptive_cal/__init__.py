"""adaptive-cal: plans and runs probe measurements on robot cells.

A Bayesian bicubic spline of the workplane height (Brunn & Hanebeck), Kalman fusion of each probe
reading, the next touch chosen by the largest drop of integrated posterior variance, and a loop
that drives a robot cell until a variance bound is met.
"""
__version__ = "0.1.0"


def use_float64() -> None:
    """Turn on JAX float64 (x64). The library never does this by itself; call it once at the
    start of a notebook or script (the CLI and the tests do)."""
    import jax

    jax.config.update("jax_enable_x64", True)
