"""The solver's options, declared once.

`Options` holds every tunable of the mixed algorithm and of the entry points built on it
(`jaxpose.solve`, `solve_many`, `solve_batch`, `solve_pnp`, `solve_pnp_batch`,
`jaxpose.mixed`, `mixed_from_initial`, `mixed_from_initial_batch`, `initial_poses`), each
with its one default, in four groups by concern: `Selection` (which triplets and
matches), `Search` (the method and its budgets), `Acceptance` (when a pose is accepted)
and `Execution` (the work's layout, what is returned). `RobustOptions` holds those of
robust mode (`jaxpose.robust`, `solve_pnp_ransac`): its own, and the triplet and
refinement settings it shares with `Options` (same names, same defaults).

All are frozen, hashable dataclasses, so they can be static arguments of `jax.jit`:

    run = jax.jit(jaxpose.solve, static_argnames="options")
    run(C, M, I, options=jaxpose.Options(method="linear", threshold=2.0))

Only structure is static: the thresholds and tolerances (`TRACED`) are taken out as
values (`split_values`), so that changing them compiles nothing.

Every entry point takes `options=None` (the defaults) and keyword shorthands for single
settings or groups, `solve(C, M, I, method="linear")` meaning
`solve(C, M, I, options=dataclasses.replace(options or Options(), method="linear"))`
(`resolve`). Values are checked when an options object is made: a bad one raises
`ValueError` naming the setting.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from typing import Any, Generic, TypeGuard, TypeVar

import jax
import numpy as np
from jax.core import Tracer

from ..geometry._validate import no_type_check

__all__ = [
    "GROUP_OF",
    "METHODS",
    "REFINEMENTS",
    "TRACED",
    "Acceptance",
    "Execution",
    "Options",
    "RobustOptions",
    "Search",
    "Selection",
    "resolve",
    "split_values",
    "with_values",
]

#: The methods of `Options.method`: the paper's four.
METHODS = ("mixed", "three_point", "linear", "nonlinear")

_T = TypeVar("_T")

#: The refinements of `RobustOptions.refine`.
REFINEMENTS = ("linear", "nonlinear", "none")


def _is_int(value) -> TypeGuard[int | np.integer]:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _is_real(value) -> TypeGuard[int | float | np.integer | np.floating]:
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


def _check_int(name: str, value, low: int, *, optional: bool = False) -> None:
    """`value` an int `>= low` (or `None` when `optional`), else `ValueError` naming it."""
    if value is None and optional:
        return
    if not _is_int(value):
        kind = "a positive int" if low == 1 else f"an int >= {low}"
        none = " or None" if optional else ""
        raise ValueError(f"{name} must be {kind}{none}, got {value!r}")
    if value < low:
        raise ValueError(f"{name} must be >= {low}, got {value}")


def _check_real(name: str, value, *, positive: bool, optional: bool = False) -> None:
    """`value` a finite real number, `> 0` (`positive`) or `>= 0` (or `None` when
    `optional`), else `ValueError` naming it."""
    if value is None and optional:
        return
    if isinstance(value, Tracer):
        return  # a traced value (`TRACED`), checked where it was concrete
    bound = "> 0" if positive else ">= 0"
    none = " or None" if optional else ""
    if not _is_real(value) or (value <= 0 if positive else value < 0):
        raise ValueError(f"{name} must be a finite number {bound}{none}, got {value!r}")


def _check_bool(name: str, value) -> None:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a bool, got {value!r}")


def _check_choice(name: str, value, choices: tuple[str, ...]) -> None:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")


class _Forward(Generic[_T]):
    """`Options.<name>`: the field `name` of one of its groups, read through (`options.threshold`
    is `options.acceptance.threshold`)."""

    def __init__(self, group: str):
        self.group = group

    def __set_name__(self, owner, name: str):
        self.name = name
        self.default = getattr(_GROUPS[self.group](), name)  # read once, when `Options` is made

    def __get__(self, obj, owner=None) -> _T:
        if obj is None:  # the class itself: the default
            return self.default
        return getattr(getattr(obj, self.group), self.name)


# `__post_init__` checks every field, its type included, and raises `ValueError` naming
# it: the public contract. (`no_type_check`: no annotation check before it, such as the
# tests' run-time checks, which would raise a `TypeError` for a value of the wrong type.)
@no_type_check
@dataclasses.dataclass(frozen=True)
class Selection:
    """Which triplets and matches the algorithm works on (the paper's Section 2.1 and
    step 1 of Section 3): `Options.selection`.

    **Fields:**
    - `min_area`: the image-triangle area below which a triplet counts as aligned (the
      paper's Section 2.1), as a fraction of the spread of the problem's used image
      points, `sqrt(det S)` with `S` their 2x2 covariance (`jaxpose.strategy.area_threshold`;
      default `0.0138`). Scale-free: any affine map of the image multiplies both areas
      by one factor, so a problem gives the same triplets, hence the same answer, in
      pixels at any focal length (square pixels or not) and in normalised coordinates
      (`K = I`). The spread is of the problem itself, not of the camera (`K^-1`
      coordinates would make the test one of angle, which fails an object that is small
      in the view whatever its pixels): a small or far object is judged by its own
      shape. The default is the paper's 40 px^2 on its bench (f = 3000 px, a spread of
      about 2900 px^2): on the embedded bench it selects exactly the triplets the
      40 px^2 test selects, for seeds 0 to 9. A value (traced: changing it compiles
      nothing).
    - `collinear_tol`: model-triangle collinearity tolerance (scale-free; default `5e-3`;
      a value, as `min_area`).
    - `max_triplets`: above this many triplets (`C(n, 3)`; n = 24 gives 2024) a fixed
      seeded sample of this many is used instead of all (`jaxpose.strategy.triplet_indices`;
      default `2000`; `None`: all).
    - `triplet_budget`: use only this many triplets, the ones with the largest image
      triangles (`jaxpose.strategy.spread_triplets`): the fast path for large batches of easy
      problems (default `None`: all of them).
    - `spread_points`: the roots scored for `Search.refine` are those of the `C(k, 3)`
      triplets of the `k` matches farthest apart in the image
      (`jaxpose.strategy.spread_matches`; default `4`: 4 triplets); `None`: the triplets
      `max_triplets` and `triplet_budget` select (a `triplet_budget` takes precedence too).
    - `wider_spread`: the matches of the escalation's middle rung (default `12`: 220
      triplets, 8 roots refined); `None`: straight to the whole mixed algorithm.
    """

    min_area: float = 0.0138
    collinear_tol: float = 5e-3
    max_triplets: int | None = 2000
    triplet_budget: int | None = None
    spread_points: int | None = 4
    wider_spread: int | None = 12

    def __post_init__(self):
        _check_real("min_area", self.min_area, positive=False)
        _check_real("collinear_tol", self.collinear_tol, positive=False)
        _check_int("max_triplets", self.max_triplets, 1, optional=True)
        _check_int("triplet_budget", self.triplet_budget, 1, optional=True)
        _check_int("spread_points", self.spread_points, 3, optional=True)
        _check_int("wider_spread", self.wider_spread, 3, optional=True)


@no_type_check
@dataclasses.dataclass(frozen=True)
class Search:
    """The method and its budgets (the paper's Sections 2.2-2.3 and 3): `Options.search`.

    **Fields:**
    - `method`: `"mixed"` (the paper's mixed algorithm, `jaxpose.mixed`),
      `"three_point"`, `"linear"` or `"nonlinear"` (the last two started from every
      triplet's three-point pose, as in the paper's experiment). Default `"mixed"`. Read
      by the `solve*` entry points (the strategy functions are the mixed algorithm).
    - `refine`: how the `solve*` entry points find the answer with the mixed method: the
      linear method from this many of the best-scored roots of all triplets, the whole
      mixed algorithm only for a problem where none of them is accepted
      (`jaxpose.strategy.best_of_roots`; default `1`: the best-scored root alone; for a
      coplanar model the two best, and the planar partner of the answer, its two
      attitudes; a problem they leave escalates, see `fallback`); `None`: the whole
      mixed algorithm over every triplet for every problem.
    - `refine_with`: how those roots are refined: `"linear"` (default: the linear
      method, accepted as the mixed algorithm's step 2 accepts) or `"mixed"` (the mixed
      algorithm's steps 2-4: Levenberg-Marquardt where the linear method does not reach
      an accepted pose; the escalation's middle rung).
    - `fallback`: with `refine`, escalate a problem none of whose refined roots is
      accepted (default `True`): to the best roots of the triplets of
      `Selection.wider_spread` matches, then to the whole mixed algorithm
      (`jaxpose.strategy.escalation`); `False`: report it not accepted (status of its best
      candidate) and run nothing more.
    - `linear_iterations`: steps of each run of the linear method (default `5`).
    - `nonlinear_budget`: most triplets per problem sent to Levenberg-Marquardt, those of
      lowest error first (default `32`; `None`: every triplet that needs it, as in the
      paper's experiment).
    - `second_chance_budget`: most failed triplets per problem retried from their other
      three-point roots (default `8`; `0`: no second chance).
    - `planar_partner`: for a coplanar model, also start from the planar-ambiguity
      partner of the answer (default `True`).
    - `max_steps`: Levenberg-Marquardt's iteration budget (default `50`; the retries get
      a multiple of it, see `jaxpose.mixed`).
    """

    method: str = "mixed"
    refine: int | None = 1
    refine_with: str = "linear"
    fallback: bool = True
    linear_iterations: int = 5
    nonlinear_budget: int | None = 32
    second_chance_budget: int = 8
    planar_partner: bool = True
    max_steps: int = 50

    def __post_init__(self):
        _check_choice("method", self.method, METHODS)
        _check_int("refine", self.refine, 1, optional=True)
        _check_choice("refine_with", self.refine_with, ("linear", "mixed"))
        _check_bool("fallback", self.fallback)
        _check_int("linear_iterations", self.linear_iterations, 1)
        _check_int("nonlinear_budget", self.nonlinear_budget, 0, optional=True)
        _check_int("second_chance_budget", self.second_chance_budget, 0)
        _check_bool("planar_partner", self.planar_partner)
        _check_int("max_steps", self.max_steps, 1)


@no_type_check
@dataclasses.dataclass(frozen=True)
class Acceptance:
    """When a pose is accepted (the paper's Section 3, steps 2 and 4;
    `jaxpose.strategy.accepts`): `Options.acceptance`. Both fields are values (traced:
    changing them compiles nothing), except that `threshold` being `None` or a number is
    structure.

    **Fields:**
    - `threshold`: acceptance threshold on Eq. 8 (px), or `None` (default) for the
      adaptive one, within `rel_threshold` of the best converged error.
    - `rel_threshold`: the adaptive threshold's margin over the best error (a fraction;
      default `0.01`).
    """

    threshold: float | None = None
    rel_threshold: float = 0.01

    def __post_init__(self):
        _check_real("threshold", self.threshold, positive=True, optional=True)
        _check_real("rel_threshold", self.rel_threshold, positive=False)


@no_type_check
@dataclasses.dataclass(frozen=True)
class Execution:
    """How the work is laid out and what is returned: `Options.execution`.

    **Fields:**
    - `chunk`: slots of the Levenberg-Marquardt buffer of the mixed algorithm (default
      `None`: a size that grows with the batch, see `mixed_from_initial_batch`).
    - `derivative`: attach the implicit derivative to the answer (default `True`; see
      `jaxpose.strategy._implicit.polish`); `False`: values only, a smaller program
      without LAPACK calls (the OpenCV-convention entry points, whose numpy outputs carry
      no derivative, use it): an answer from the best roots is finished by two more
      steps of the linear method (`jaxpose.strategy._best.finish_linear_batch`), any other by
      the same Newton polish solved by Cholesky.
    """

    chunk: int | None = None
    derivative: bool = True

    def __post_init__(self):
        _check_int("chunk", self.chunk, 1, optional=True)
        _check_bool("derivative", self.derivative)


#: The groups of `Options`, by field name.
_GROUPS: dict[str, type] = {
    "selection": Selection,
    "search": Search,
    "acceptance": Acceptance,
    "execution": Execution,
}

#: Each setting's group (`Options(threshold=2.0)` sets `acceptance.threshold`).
GROUP_OF: dict[str, str] = {
    field.name: group for group, kind in _GROUPS.items() for field in dataclasses.fields(kind)
}


@no_type_check
@dataclasses.dataclass(frozen=True, init=False)
class Options:
    """The options of the mixed algorithm and of the entry points built on it, in four
    groups by concern: `selection` (`Selection`: which triplets and matches), `search`
    (`Search`: the method and its budgets), `acceptance` (`Acceptance`: when a pose is
    accepted) and `execution` (`Execution`: the work's layout and what is returned).

    Made from groups, from single settings, or both (a setting overrides its group):

        Options(acceptance=Acceptance(threshold=2.0), search=Search(method="linear"))
        Options(threshold=2.0, method="linear")  # the same options

    Every setting reads through as well (`options.threshold` is
    `options.acceptance.threshold`), and `dataclasses.replace(options, threshold=3.0)`
    changes one. Frozen and hashable (a static argument of `jax.jit`); checked when made
    (`ValueError` naming the setting). The entry points take the settings as keyword
    shorthands too (`jaxpose.solve(C, M, I, method="linear")`).

    Only what changes a program's shape or structure is structure: the thresholds and
    tolerances (`TRACED`: `threshold`, `rel_threshold`, `min_area`, `collinear_tol`) are
    values: the stored programs take them as arguments (changing them compiles nothing),
    and under your own `jax.jit` they may be traced arrays
    (`jax.jit(lambda thr: solve(C, M, I, threshold=thr))`).
    """

    selection: Selection
    search: Search
    acceptance: Acceptance
    execution: Execution

    def __init__(
        self,
        selection: Selection | None = None,
        search: Search | None = None,
        acceptance: Acceptance | None = None,
        execution: Execution | None = None,
        **settings,
    ):
        given = {"selection": selection, "search": search}
        given |= {"acceptance": acceptance, "execution": execution}
        changes: dict[str, dict[str, Any]] = {group: {} for group in _GROUPS}
        for name, value in settings.items():
            if name not in GROUP_OF:
                raise ValueError(f"unknown option {name!r}: the options are {', '.join(GROUP_OF)}")
            changes[GROUP_OF[name]][name] = value
        for group, kind in _GROUPS.items():
            value = given[group]
            if value is None:
                value = kind(**changes[group])
            elif not isinstance(value, kind):
                name = f"jaxpose.{kind.__name__}"
                raise ValueError(f"{group} must be a {name} or None, got {value!r}")
            elif changes[group]:
                value = dataclasses.replace(value, **changes[group])
            object.__setattr__(self, group, value)

    method = _Forward[str]("search")
    refine = _Forward[int | None]("search")
    refine_with = _Forward[str]("search")
    fallback = _Forward[bool]("search")
    linear_iterations = _Forward[int]("search")
    nonlinear_budget = _Forward[int | None]("search")
    second_chance_budget = _Forward[int]("search")
    planar_partner = _Forward[bool]("search")
    max_steps = _Forward[int]("search")
    threshold = _Forward[float | None]("acceptance")
    rel_threshold = _Forward[float]("acceptance")
    min_area = _Forward[float]("selection")
    collinear_tol = _Forward[float]("selection")
    max_triplets = _Forward[int | None]("selection")
    triplet_budget = _Forward[int | None]("selection")
    spread_points = _Forward[int | None]("selection")
    wider_spread = _Forward[int | None]("selection")
    chunk = _Forward[int | None]("execution")
    derivative = _Forward[bool]("execution")


#: The fields of `Options` that a compiled program takes as values, not as part of its
#: structure: changing them between calls compiles nothing (`split_values`). `threshold`
#: is structural only in being `None` (adaptive) or a number.
TRACED = ("threshold", "rel_threshold", "min_area", "collinear_tol")


def split_values(options: Options) -> tuple[Options, np.ndarray]:
    """`(key, values)`: `options` with its `TRACED` fields set to fixed stand-ins (the
    program's key: equal for options that differ only in those values) and the values
    themselves, a float64 vector of 4 (`threshold` `0` where it is `None`)."""
    given = options.threshold
    key = dataclasses.replace(
        options,
        threshold=None if given is None else 1.0,
        rel_threshold=Options.rel_threshold,
        min_area=Options.min_area,
        collinear_tol=Options.collinear_tol,
    )
    values = [0.0 if given is None else given, options.rel_threshold]
    values += [options.min_area, options.collinear_tol]
    return key, np.asarray(values, np.float64)


def with_values(key: Options, values) -> Options:
    """`key` (from `split_values`) with the `TRACED` values `values` (arrays, inside a
    compiled program; they were checked where they were concrete). A `None` threshold
    stays `None`."""
    changes = dict(zip(TRACED, values, strict=True))
    if key.threshold is None:
        del changes["threshold"]
    return dataclasses.replace(key, **changes)


@no_type_check
@dataclasses.dataclass(frozen=True)
class RobustOptions:
    r"""The options of robust mode (`jaxpose.robust`, `jaxpose.solve_pnp_ransac`).

    Its own (the consensus test and the refinement), and the triplet and refinement
    settings it shares with `Options`, under the same names and with the same defaults.
    Frozen and checked like `Options`; hashable when its values are (`inlier_threshold`
    and `min_inliers` may also be traced arrays inside `jaxpose.robust`, which are not).

    **Fields:**
    - `inlier_threshold`: the inlier test's pixel radius $\tau$ (px; default `8.0`,
      OpenCV's).
    - `min_inliers`: fewest inliers for the answer to count (`OK`; default `4`, at least
      `3`).
    - `refine`: `"linear"` (default: the small-movement method, `iterations` steps per
      round), `"nonlinear"` (Levenberg-Marquardt, `max_steps`) or `"none"`.
    - `rounds`: refine-then-recompute-inliers rounds (default `2`).
    - `iterations`: steps of each linear refinement (default: `Options.linear_iterations`).
    - `max_steps`: Levenberg-Marquardt's iteration budget (default: `Options.max_steps`).
    - `min_area`, `collinear_tol`, `max_triplets`: the triplet settings, as `Options`'s;
      the aligned test's area is at most $\tau^2$ here (`jaxpose.robust`'s step 1), since
      the spread it is relative to counts the wrong matches too.
    """

    inlier_threshold: float = 8.0
    min_inliers: int = 4
    refine: str = "linear"
    rounds: int = 2
    iterations: int = Options.linear_iterations
    max_steps: int = Options.max_steps
    min_area: float = Options.min_area
    collinear_tol: float = Options.collinear_tol
    max_triplets: int | None = Options.max_triplets

    def __post_init__(self):
        if not isinstance(self.inlier_threshold, jax.Array):
            _check_real("inlier_threshold", self.inlier_threshold, positive=True)
        if not isinstance(self.min_inliers, jax.Array):
            _check_int("min_inliers", self.min_inliers, 3)
        _check_choice("refine", self.refine, REFINEMENTS)
        _check_int("rounds", self.rounds, 0)
        _check_int("iterations", self.iterations, 1)
        _check_int("max_steps", self.max_steps, 1)
        _check_real("min_area", self.min_area, positive=False)
        _check_real("collinear_tol", self.collinear_tol, positive=False)
        _check_int("max_triplets", self.max_triplets, 1, optional=True)


_O = TypeVar("_O", Options, RobustOptions)


@functools.cache
def _defaults(kind: type[_O]) -> _O:
    """`kind()`, made once (the options are frozen: one instance serves every call)."""
    return kind()


@no_type_check  # it checks its arguments itself (`ValueError`), as `Options` does
def resolve(options: _O | None, changes: Mapping[str, Any], kind: type[_O] = Options) -> _O:
    """The options an entry point runs with: `options` (`None`: `kind()`, the defaults)
    with the keyword shorthands `changes` applied (`dataclasses.replace`).

    **Raises:** `ValueError` naming an unknown keyword, a wrong type of `options`, or the
    field of a bad value.
    """
    if options is None and not changes:
        return _defaults(kind)
    base = _defaults(kind) if options is None else options
    if not isinstance(base, kind):
        raise ValueError(
            f"options must be a jaxpose.{kind.__name__} or None, got {type(options).__name__}"
        )
    names = tuple(GROUP_OF) if kind is Options else ()
    names += tuple(field.name for field in dataclasses.fields(kind))
    for name in changes:
        if name not in names:
            raise ValueError(f"unknown option {name!r}: the options are {', '.join(names)}")
    return dataclasses.replace(base, **changes) if changes else base
