"""What an effect is: one immutable value per physical effect, and sums of effects.

An effect maps per-touch features to a change of the reading in mm (larger reading = surface
higher):

    reading_change(features, params, geometry) = forward(features, params, geometry).

Every effect is linear in some of its parameters once the others (the *nonlinear* ones) are
fixed; its regressor R has one column per linear parameter, the forward model evaluated at unit
values of that parameter and zero for the other linear ones, so

    reading_change(params) = R(features, nonlinear params) @ theta(linear params)

holds by construction: explain fits exactly the code the simulator runs. Effects add like
pysindy's candidate terms: ``tilt + form + thermal_drift`` is an ``EffectSet`` whose forward
model is the sum and which prints as readable physics.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, NamedTuple

import numpy as np

AXES = ("position", "time", "direction", "reach", "indication")


@dataclass(frozen=True)
class Geometry:
    """What the effects need to know about the cell (mm, workplane frame)."""

    x_range_mm: tuple[float, float]
    y_range_mm: tuple[float, float]
    base_xy_mm: tuple[float, float] | None = None  # robot base; needed by effects along reach


@dataclass(frozen=True)
class Features:
    """Per-touch inputs of the forward models; arrays of one length, NaN where unknown."""

    x_mm: np.ndarray
    y_mm: np.ndarray
    t_s: np.ndarray
    direction: np.ndarray  # +1 arriving moving +x, -1 moving -x, 0 unknown
    ideal_reading_mm: np.ndarray  # the noise-free reading: surface - z + probe zero

    def reach_mm(self, geometry: Geometry) -> np.ndarray:
        """Horizontal distance r from the robot base (mm)."""
        if geometry.base_xy_mm is None:
            raise ValueError("arm_sag needs robot.base_xy_mm (the robot base position in the "
                             "workplane frame) in the cell file")
        bx, by = geometry.base_xy_mm
        return np.hypot(self.x_mm - bx, self.y_mm - by)

    def with_ideal_reading(self, ideal_reading_mm) -> "Features":
        return Features(self.x_mm, self.y_mm, self.t_s, self.direction,
                        np.asarray(ideal_reading_mm, float))


class Param(NamedTuple):
    """One parameter of an effect: its stable name, unit, sign convention and default."""

    name: str
    unit: str
    meaning: str
    default: float
    linear: bool = True  # the reading change is linear in it (others fixed)
    prior: tuple[float, float] | None = None  # explain: log-uniform range of its prior sd


Forward = Callable[[Features, Mapping[str, float], Geometry], np.ndarray]
Grid = Callable[[Features, Geometry], Mapping[str, np.ndarray]]


@dataclass(frozen=True)
class Effect:
    """One physical effect (DESIGN.md, "Names of physics effects").

    ``axis`` is the residual axis it shows on (explain looks for it there); the linear
    parameters' ``Param.prior`` ranges make it a candidate of explain (none: a nuisance); ``grid`` the search grid of the nonlinear parameters; ``searched`` the linear parameters whose
    column depends on them (the others can be fitted without a search); ``main`` the parameter a
    one-line summary leads with; ``columns`` replaces the unit-value regressor where a parameter
    is a derived scale (``derived``: form's pv_mm).
    """

    name: str
    what: str
    formula: str
    params: tuple[Param, ...]
    forward: Forward
    axis: str
    main: str | None = None
    grid: Grid | None = None
    grid_text: str = "--"  # the search grid in words (docs/explain.md's table)
    searched: tuple[str, ...] = ()
    surface: bool = False
    columns: Callable[[Features, Geometry], np.ndarray] | None = None
    derived: tuple[str, ...] = ()  # parameters computed from the linear ones (form's pv_mm)
    # fitted linear values -> (all parameters incl. the derived, d derived / d linear values)
    derive: Callable[[np.ndarray, Geometry], tuple[dict, dict]] | None = None

    def __post_init__(self):
        if self.axis not in AXES:
            raise ValueError(f"effect {self.name!r}: axis {self.axis!r} is not one of {AXES}")

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    @property
    def linear(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params if p.linear)

    @property
    def nonlinear(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params if not p.linear and p.name not in self.derived)

    @property
    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.params}

    @property
    def candidate(self) -> bool:
        """Explain scores it (its linear parameters have a prior range)."""
        return any(p.prior is not None for p in self.params)

    def prior_range(self, names: tuple[str, ...] | None = None) -> tuple[float, float]:
        """The prior range shared by the linear parameters ``names`` (default: all)."""
        ranges = {p.prior for p in self.params if p.name in (names or self.linear)}
        if len(ranges) != 1 or None in ranges:
            raise ValueError(f"effect {self.name!r}: parameters {names or self.linear} need one "
                             f"common prior range, got {ranges}")
        return ranges.pop()

    @property
    def plain(self) -> tuple[str, ...]:
        """Linear parameters whose regressor column needs no nonlinear parameter."""
        return tuple(k for k in self.linear if k not in self.searched)

    def complete(self, params: Mapping[str, float]) -> dict[str, float]:
        """Defaults filled in; unknown parameter names raise with the name."""
        unknown = set(params) - set(self.param_names)
        if unknown:
            raise KeyError(f"effect {self.name!r} has no parameter(s) {sorted(unknown)}; "
                           f"it takes {', '.join(self.param_names)}")
        return {**self.defaults, **{k: float(v) for k, v in params.items()}}

    def reading_change(self, features: Features, params: Mapping[str, float],
                       geometry: Geometry) -> np.ndarray:
        """Change of the reading in mm at each touch."""
        return np.asarray(self.forward(features, self.complete(params), geometry), float)

    def regressor(self, features: Features, geometry: Geometry,
                  fixed: Mapping[str, float] | None = None,
                  names: tuple[str, ...] | None = None) -> np.ndarray:
        """R (touches x linear parameters ``names``, default all): reading_change = R @ theta.

        Nonlinear parameters come from ``fixed`` or the defaults; each column is the forward
        model at a unit value of one linear parameter, zero for the others.
        """
        names = self.linear if names is None else names
        if self.columns is not None:
            R = self.columns(features, geometry)
            return R[:, [self.linear.index(k) for k in names]]
        base = {k: v for k, v in self.complete(dict(fixed or {})).items() if k not in self.linear}
        cols = [self.reading_change(features, {**base, **{n: float(n == k) for n in self.linear}},
                                    geometry) for k in names]
        return np.stack(cols, axis=-1)

    def jacobian(self, features: Features, params: Mapping[str, float], geometry: Geometry,
                 rel_step: float = 1e-6) -> np.ndarray:
        """d reading_change / d parameter (touches x params) by central differences.

        Linearises the effect around ``params`` so its parameters can become states of a belief.
        """
        p0 = self.complete(params)
        cols = []
        for k in self.param_names:
            h = rel_step * max(1.0, abs(p0[k]))
            up = self.reading_change(features, {**p0, k: p0[k] + h}, geometry)
            dn = self.reading_change(features, {**p0, k: p0[k] - h}, geometry)
            cols.append((up - dn) / (2.0 * h))
        return np.stack(cols, axis=-1)

    def summary(self, params: Mapping, stds: Mapping) -> str:
        """One line: ``name: main = value +- sd``; per round ``name: main per round 0: value
        +- sd, 1: value +- sd`` (each round's value beside its own sd)."""
        main = self.main if self.main in params else next(k for k in self.linear if k in params)
        values, sds = np.atleast_1d(params[main]), np.atleast_1d(stds[main])
        if values.size == 1:
            return f"{self.name}: {main} = {values[0]:.4g} +- {sds[0]:.4g}"
        return f"{self.name}: {main} per round " + ", ".join(
            f"{r}: {v:.4g} +- {e:.4g}" for r, (v, e) in enumerate(zip(values, sds)))

    def __add__(self, other: "Effect | EffectSet") -> "EffectSet":
        return EffectSet((self,)) + other

    def __str__(self) -> str:
        return f"{self.name} [{self.formula}]"


@dataclass(frozen=True)
class EffectSet:
    """A sum of distinct effects; its forward model is the sum of theirs."""

    effects: tuple[Effect, ...] = ()

    def __add__(self, other: "Effect | EffectSet") -> "EffectSet":
        more = other.effects if isinstance(other, EffectSet) else (other,)
        names = [e.name for e in self.effects + more]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"effect(s) {twice} added twice")
        return EffectSet(self.effects + more)

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def select(self, keep: Callable[[Effect], bool]) -> "EffectSet":
        return EffectSet(tuple(e for e in self.effects if keep(e)))

    def reading_change(self, features: Features, params: Mapping[str, Mapping[str, float]],
                       geometry: Geometry) -> np.ndarray:
        """Sum of the members' reading changes; ``params`` by effect name (missing: defaults)."""
        out = np.zeros(np.shape(features.x_mm))
        for e in self.effects:
            out = out + e.reading_change(features, params.get(e.name, {}), geometry)
        return out

    def __str__(self) -> str:
        return " + ".join(str(e) for e in self.effects) or "(no effect)"
