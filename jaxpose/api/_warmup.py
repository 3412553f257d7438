"""Build the standard compiled programs ahead of time (`jaxpose warmup`).

`warm_up` compiles (or finds already on disk) the programs that `solve_pnp`,
`solve_pnp_batch`, a plain `solve` and a plain `jax.grad` of it (float64, default
options) run for each point bucket, and stores them in the program cache
(`jaxpose.api._programs`), so that the first call of a new process only loads them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..strategy import Options, escalation, split_values
from ._pnp import (
    CHUNK,
    _batched_opencv,
    _pack,
    _pad_points,
    _solve_opencv,
    _stages,
    _values,
)
from ._programs import POINT_BUCKETS, Program, bucket_points, program
from ._stored import _derivative_program, _stored_program, values_only

__all__ = ["DEFAULT_BATCHES", "DEFAULT_POINTS", "Built", "warm_up", "warm_up_plan"]

#: The point buckets `warm_up` builds by default: every `n` from 4 to 64.
DEFAULT_POINTS = POINT_BUCKETS[:4]
#: The batch chunks `warm_up` builds by default for `solve_pnp_batch`: none (a batch
#: compiles its chunk sizes on first use; name them, e.g. `(16, 2048)`, to build them).
DEFAULT_BATCHES: tuple[int, ...] = ()


class Built(NamedTuple):
    """One program `warm_up` built: `what` (its description), `compiled` (True: compiled
    now; False: already on disk, or in this process)."""

    what: str
    compiled: bool


def _problem(n: int, batch: int | None):
    """A problem of `n` points in the bucket's shapes (the values do not matter to the
    program, only the shapes)."""
    K = np.asarray([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]], np.float64)
    rng = np.random.default_rng(n)
    obj = rng.uniform(-1, 1, (n, 3))
    img = rng.uniform(0, 640, (n, 2))
    values = _values(Options())
    if batch is None:  # `solve_pnp`'s program takes the problem packed in one vector
        return (jnp.asarray(np.concatenate([values, _pack(K, *_pad_points(obj, img))])),)
    obj, img = np.broadcast_to(obj, (batch, n, 3)), np.broadcast_to(img, (batch, n, 2))
    obj, img, mask = _pad_points(obj, img)
    return tuple(jnp.asarray(a) for a in (K, values, obj, img, mask))


def warm_up_plan(
    points: Iterable[int] = DEFAULT_POINTS,
    batches: Iterable[int] = DEFAULT_BATCHES,
    options: Options | None = None,
    gradients: bool = True,
) -> list[tuple[str, Callable[[], bool]]]:
    """The programs `warm_up` builds, as `(description, build)` pairs: `build()` compiles
    the program (or loads it) and returns whether it compiled. `gradients`: the program
    of a plain `jax.grad` (`jax.jacrev`, `jax.jacfwd`, `jax.jvp`) of `solve` too, the
    answer and its Jacobian (`jaxpose.api._stored._derivative_program`; its first rung's,
    which a problem accepted there runs)."""
    options = Options() if options is None else options
    plan: list[tuple[str, Callable[[], bool]]] = []
    stages = list(_stages(options))
    names = ["solve_pnp"] + [f"solve_pnp, rung {k}" for k in range(2, len(stages) + 1)]
    for n in sorted({bucket_points(int(p)) for p in points}):
        for stage, name in zip(stages, names, strict=False):

            def build(n=n, stage=stage) -> bool:
                prog = program(_solve_opencv, stage)
                before = prog.compiled
                with jax.enable_x64(True):
                    prog.executable(*_problem(n, None))
                return prog.compiled > before

            plan.append((f"{name}, {n} points", build))

        key, values = split_values(options)
        keys = escalation(values_only(key))  # a program a rung, as a plain `solve` runs
        for k, solve_key in enumerate(keys):

            def build_solve(n=n, solve_key=solve_key) -> bool:
                prog = program(_stored_program, solve_key, True)
                before = prog.compiled
                K = np.asarray([[800.0, 0, 320, 0], [0, 800, 240, 0], [0, 0, 1, 0]])
                shapes = (np.zeros((1, n, 3)), np.zeros((1, n, 2)), np.ones((1, n), bool))
                with jax.enable_x64(True):
                    prog.executable(values, K, *shapes)
                return prog.compiled > before

            what = "solve" if k == 0 else f"solve, rung {k + 1}"
            plan.append((f"{what}, {n} points", build_solve))
        if gradients:  # the first rung's: the later rungs' compile on first use

            def build_gradient(n=n, solve_key=keys[0]) -> bool:
                prog = program(_derivative_program, solve_key)
                before = prog.compiled
                K = np.asarray([[800.0, 0, 320, 0], [0, 800, 240, 0], [0, 0, 1, 0]])
                shapes = (np.zeros((1, n, 3)), np.zeros((1, n, 2)), np.ones((1, n), bool))
                with jax.enable_x64(True):
                    prog.executable(values, K, *shapes, None)
                return prog.compiled > before

            plan.append((f"jax.grad(solve), {n} points", build_gradient))
        for B in sorted({min(int(b), CHUNK) for b in batches}):

            def build_batch(n=n, B=B) -> bool:
                from ._batch import _compiled

                prog = _compiled(_batched_opencv, (stages[0],), (), None, 2, 3)
                assert isinstance(prog, Program)
                before = prog.compiled
                with jax.enable_x64(True):
                    prog.executable(*_problem(n, B))
                return prog.compiled > before

            plan.append((f"solve_pnp_batch, {n} points, {B} problems", build_batch))
    return plan


def warm_up(
    points: Iterable[int] = DEFAULT_POINTS,
    batches: Iterable[int] = DEFAULT_BATCHES,
    options: Options | None = None,
    progress: Callable[[str], None] | None = None,
    gradients: bool = True,
) -> list[Built]:
    """Build the programs of `solve_pnp` (one per rung of the escalation), of a plain
    `solve` (float64, one problem) and, with `gradients`, of a plain `jax.grad` of it for
    the buckets of `points`, and of `solve_pnp_batch` for the chunk sizes `batches`, with
    `options` (default `Options()`). Programs already on disk are only loaded.
    `progress(description)` is called before each. Returns what was built."""
    built = []
    for what, build in warm_up_plan(points, batches, options, gradients):
        if progress is not None:
            progress(what)
        built.append(Built(what, build()))
    return built
