"""The tracker's compiled programs built ahead of time (`jaxpose warmup --track`, issue
#32): the per-frame solve (`jaxpose.apps._track_solve`, one program per bucket of
measurement units) and the offline refinement (`jaxpose.apps._track_refine`, one per
pair of buckets of frames and units), in float64 as `jaxpose track` runs them, stored in
the program cache (`jaxpose.api._programs`) so that a new `jaxpose track` process loads
them instead of compiling.

The default buckets are those `jaxpose track` uses on `box.mp4` (640 x 480, the box
at 40-160 cm, `TrackOptions()`): a frame has 100-340 measurement units (edge matches and
KLT points; the first frame's edges alone fewer), so the solve runs the programs of 128,
256 and 512 units; 64 is built too, for a frame that sees little of the object. The
whole video refined (`--smooth`: 455 frames, at most 333 units a frame) runs the
refinement's program of 512 frames by 512 units.

Only the shapes matter to a program, so each is built on placeholder arrays of the
shapes and dtypes the tracker passes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import jax
import numpy as np

from ..api._programs import bucket_points
from ..geometry._validate import no_type_check

__all__ = ["TRACK_REFINE_BUCKETS", "TRACK_SOLVE_BUCKETS", "track_warm_up_plan"]

#: The per-frame solve's buckets of measurement units built by default.
TRACK_SOLVE_BUCKETS = (64, 128, 256, 512)
#: The refinement's buckets `(frames, units)` built by default.
TRACK_REFINE_BUCKETS = ((512, 512),)


def _solve_args(units: int) -> tuple:
    from ._track_options import TrackOptions
    from ._track_solve import Measurements, _float, track_rows

    f = _float()
    K = np.array([[1578.5, 0.0, 320.0], [0.0, 1771.8, 240.0], [0.0, 0.0, 1.0]])
    empty = Measurements(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2)))
    rows = track_rows(K, empty, units, f)
    o = TrackOptions()
    return (np.eye(3, dtype=f), np.array([0.0, 0.0, 100.0], f), rows.model, rows.planes,
            rows.mask, rows.point, np.int32(o.iterations), np.int32(o.min_rows),
            f(o.min_scale), f(np.inf))  # fmt: skip


def _refine_args(frames: int, units: int) -> tuple:
    from ._track_solve import _float

    f = _float()
    F, U = frames, units
    return (np.tile(np.eye(3, dtype=f), (F, 1, 1)), np.zeros((F, 3), f), np.zeros((F, U, 3), f),
            np.zeros((F, U, 2, 3), f), np.zeros((F, U, 2), bool), np.zeros((F, U), f),
            np.zeros(F, bool), np.zeros(F, bool), np.zeros(3, f), np.ones(2, f),
            np.int32(8))  # fmt: skip


def _builder(which: str, shape: tuple) -> Callable[[], bool]:
    def build() -> bool:
        if which == "solve":
            from ._track_solve import _PROGRAM
        else:
            from ._track_refine import _PROGRAM
        before = _PROGRAM.compiled
        with jax.enable_x64(True):
            args = _solve_args(*shape) if which == "solve" else _refine_args(*shape)
            _PROGRAM.executable(*args)
        return _PROGRAM.compiled > before

    return build


@no_type_check  # (its arguments checked by itself, with a ValueError naming each)
def track_warm_up_plan(
    solve: Iterable[int] = TRACK_SOLVE_BUCKETS,
    refine: Iterable[tuple[int, int]] = TRACK_REFINE_BUCKETS,
) -> list[tuple[str, Callable[[], bool]]]:
    """The tracker's programs as `(description, build)` pairs (as
    `jaxpose.api._warmup.warm_up_plan`'s): the per-frame solve for the buckets holding each
    count of `solve`, the refinement for the buckets holding each `(frames, units)` of
    `refine`. `build()` compiles the program (or loads it) and returns whether it
    compiled.

    **Raises:** `ValueError` naming the argument when a count is below 1."""
    solve = sorted({bucket_points(_count("solve", n)) for n in solve})
    pairs = set()
    for pair in refine:
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise ValueError(f"refine must hold pairs (frames, units), got {pair!r}")
        F, U = (_count("refine", v) for v in pair)
        pairs.add((bucket_points(max(F, 2)), bucket_points(U)))
    plan = [(f"track: per-frame solve, {n} units", _builder("solve", (n,))) for n in solve]
    plan += [(f"track: refinement, {F} frames x {U} units", _builder("refine", (F, U)))
             for F, U in sorted(pairs)]  # fmt: skip
    return plan


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must hold ints >= 1, got {value!r}")
    return int(value)
