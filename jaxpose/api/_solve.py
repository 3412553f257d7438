"""The JAX-native entry points: `solve` (one problem, differentiable), `solve_many` (a
batch, batch-first) and `solve_batch` (a large batch from numpy, chunked and sharded over
devices). The OpenCV-convention ones are in `jaxpose.api._pnp`."""

from __future__ import annotations

import functools
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer
from jaxtyping import ArrayLike, Bool, Real

from ..geometry import Pose, as_batched, check_problem, no_type_check
from ..strategy import METHODS as METHODS
from ..strategy import (
    TRACED,
    Options,
    Solution,
    resolve,
    solve_problems,
    split_values,
)
from ._batch import run_batched
from ._stored import (
    _derivative_fits,
    _differentiated,
    _jitted,
    _stored,
    _stored_derivative,
)

__all__ = ["METHODS", "Solution", "solve", "solve_batch", "solve_many"]


# The entry points check their arguments themselves (`check_problem`, `as_batched`: a
# `ValueError` naming the argument), so no run-time type check comes before theirs.
@no_type_check
def solve(
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "n 3"],
    image: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    options: Options | None = None,
    initial: Pose | None = None,
    **changes,
) -> Solution:
    """Recover the pose of a known object from one calibrated image (JAX-native).

    Pure, for ONE problem: composes with `jax.jit`, `jax.vmap` (batch the arrays) and
    `jax.grad`; the pipeline (`jaxpose.strategy.solve_problems`) on a batch of one.
    By default (the mixed method with `refine=1`): the three-point roots of the triplets
    of the 4 matches farthest apart in the image are scored by their Eq. 8 error over all
    matches, the linear method runs from the best one (and, for a coplanar model, from
    its planar partner too), and the accepted pose is polished to the Eq. 8 optimum.
    Where none is accepted the problem escalates (`jaxpose.strategy.escalation`): the
    best roots of the triplets of 12 spread matches, then the paper's whole mixed
    algorithm over every triplet (`jaxpose.mixed`).
    `refine=None` runs the whole mixed algorithm from the start; `method=` one of the
    paper's single methods, from every triplet.

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points `m_i`, `n >= 3`.
    - `image`: `(n, 2)` pixels matched to them.
    - `mask`: optional `(n,)` bool, which matches to use (fixed shapes with padding).
    - `options`: a `jaxpose.Options` (default `Options()`), by concern: `search` (the
      method, `"mixed"`, `"three_point"`, `"linear"` or `"nonlinear"`, the last two
      started from every triplet's three-point pose, as in the paper's experiment; the
      mixed algorithm's budgets), `acceptance` (the threshold), `selection` (the
      triplets used: `max_triplets`, `triplet_budget`, the fast path for large batches
      of easy problems), `execution` (the derivative, the buffer). A static argument
      under `jax.jit` (hashable); its thresholds and tolerances are values.
    - `initial`: `None`, or a `Pose` `(R (3, 3), t (3,))` (model to world) to start
      from instead of the three-point roots: the paper's small-movement linear method
      (Section 2.2) from it, then, with the mixed method, Levenberg-Marquardt where it
      does not reach an accepted pose, and the usual acceptance and finish (the local
      answer near it: no other roots or planar partner are tried;
      `jaxpose.strategy._start`). Its `triplet` is then `(0, 1, 2)`. A value, not
      structure: another initial pose compiles nothing.
    - `**changes`: keyword shorthands for settings (or groups) of `options`, e.g.
      `solve(C, M, I, method="linear", threshold=2.0)`; an unknown one raises
      `ValueError`.

    **Returns:** a `Solution`.

    **Gradients** (`jax.grad`, `jax.jacfwd`, `jax.jacrev`, under `jit` and `vmap`): for
    the three optimising methods, `pose` (and `error`, `pose_error`) are differentiable
    with respect to `camera`, `model` and `image` through the optimality conditions of
    Eq. 8 at the answer (implicit function theorem, the full Hessian: exact first
    derivatives, not an unrolled iteration; see `jaxpose.strategy._implicit.polish`). The
    discrete choices (triplet, root, branch, acceptance) carry none. A problem with no
    accepted pose returns its placeholder with a zero gradient; `method="three_point"`
    gives no gradient to the pose.
    """
    options = resolve(options, changes)
    check_problem(camera, model, image, mask)
    start = _check_initial(initial, ())

    def one(x):  # a batch of one (numpy for a plain call: no dispatch)
        if x is None:
            return None
        return x[None] if isinstance(x, Tracer) else np.asarray(x)[None]

    start = None if start is None else Pose(*(cast(Any, one(x)) for x in start))
    return _pipeline(camera, one(model), one(image), one(mask), options, True, start)


def _check_initial(initial, batch: tuple[int, ...]) -> Pose | None:
    """`initial` checked: `None` or a `Pose` of shapes `(*batch, 3, 3)`, `(*batch, 3)`,
    real and (when concrete) finite; `ValueError` naming `initial` otherwise."""
    if initial is None:
        return None
    if not isinstance(initial, Pose):
        raise ValueError(f"initial must be a jaxpose.Pose or None, got {type(initial).__name__}")
    for name, x, tail in (("R", initial.R, (3, 3)), ("t", initial.t, (3,))):
        shape = tuple(getattr(x, "shape", np.shape(x)))
        if shape != (*batch, *tail):
            raise ValueError(f"initial.{name} must have shape {(*batch, *tail)}, got {shape}")
        if not isinstance(x, Tracer) and not np.all(np.isfinite(np.asarray(x, np.float64))):
            raise ValueError(f"initial.{name} must be finite")
    return initial


@no_type_check
def solve_many(
    camera: Real[ArrayLike, "3 4"] | Real[ArrayLike, "B 3 4"],
    model: Real[ArrayLike, "B n 3"],
    image: Real[ArrayLike, "B n 2"],
    mask: Bool[ArrayLike, "B n"] | None = None,
    *,
    options: Options | None = None,
    initial: Pose | None = None,
    **changes,
) -> Solution:
    """`solve` for a batch of `B` problems of equal `n`: the same answers as
    `jax.vmap(solve)`, computed batch-first. `camera` is `(3, 4)`, one camera for every
    problem (`jax.vmap(solve, in_axes=(None, 0, 0, 0))`), or `(B, 3, 4)`, one per problem.

    It is the pipeline itself (`jaxpose.strategy.solve_problems`). The difference from
    a plain `vmap` is the cost: under `vmap`, every problem pays for every rung of the
    escalation and the mixed algorithm's full Levenberg-Marquardt buffer (`vmap` turns
    "only when needed" into "always"); here each rung runs only for the problems that
    need it, gathered a few at a time, the triplets that need Levenberg-Marquardt share
    one buffer, and the cheap steps run in cache-sized passes. Arguments as `solve`
    (`model`, `image`, `mask` with a leading batch axis, `initial` a `Pose` of `B`
    poses); pure, for `jit` and `grad`.
    """
    options = resolve(options, changes)
    _check_many(camera, model, image, mask)
    start = _check_initial(initial, np.shape(model)[:1])
    return _pipeline(camera, model, image, mask, options, False, start)


# ------------------------------------------------------------------ compiled programs


def _pipeline(
    camera, model, image, mask, options: Options, single: bool = False, start=None
) -> Solution:
    """`solve_problems`, compiled. Concrete inputs (a plain call) run a stored program
    (`jaxpose.api._programs`: compiled once per bucket of points and of problems, kept
    on disk, loaded by a new process, built ahead by `jaxpose warmup`), and so do the
    inputs of a plain `jax.grad`, `jax.jacrev`, `jax.jacfwd` or `jax.jvp` (no `jit`
    around it: `_stored_derivative`); other traced ones (under the caller's `jit` or
    `vmap`) run `jax.jit` of the pipeline, whose program JAX keeps for the life of the
    process. Either way a call is as fast from its second call as a jitted one. The
    thresholds and tolerances are the programs' values (`jaxpose.strategy.split_values`):
    changing them compiles nothing.
    `single`: one problem (`B = 1`), returned without its batch axis. `start`: the
    given poses (`Pose`, batched) or `None`: an argument of the programs too."""
    arrays = (camera, model, image, mask, *(() if start is None else start))
    traced = any(isinstance(x, Tracer) for x in arrays)
    values_traced = any(isinstance(getattr(options, f), Tracer) for f in TRACED)
    if values_traced:  # the options' values are the caller's tracers: trace it all
        out = solve_problems(camera, model, image, mask, options, start)
    else:
        key, values = split_values(options)
        if not traced:
            return _stored(camera, model, image, mask, key, values, single, start)
        if _differentiated(arrays) and _derivative_fits(model):
            return _stored_derivative(camera, model, image, mask, key, values, single, start)
        out = _jitted(values, camera, model, image, mask, start, options=key)
    return jax.tree.map(lambda a: a[0], out) if single else out


def _check_many(camera, model, image, mask) -> None:
    """`check_problem` for a batch: `camera (3, 4)` or `(B, 3, 4)`, `model (B, n, 3)`,
    `image (B, n, 2)`, `mask (B, n)`."""
    for name, x, tail in (("model", model, 3), ("image", image, 2)):
        shape = getattr(x, "shape", None)
        if shape is None or len(shape) != 3 or shape[-1] != tail:
            raise ValueError(f"{name} must have shape (B, n, {tail}), got {shape}")
    if image.shape[0] != model.shape[0]:
        raise ValueError(
            f"model and image must hold the same number of problems, got {model.shape[0]} "
            f"and {image.shape[0]}"
        )
    if mask is not None and (getattr(mask, "ndim", None) != 2 or mask.shape[0] != model.shape[0]):
        raise ValueError(f"mask must have shape (B, n), got {getattr(mask, 'shape', None)}")
    if getattr(camera, "ndim", None) == 3 and camera.shape[0] != model.shape[0]:
        raise ValueError(
            f"camera must be (3, 4) or one per problem, (B, 3, 4) with B = {model.shape[0]}, "
            f"got {camera.shape}"
        )

    def item(x):
        return None if x is None else jax.ShapeDtypeStruct(x.shape[1:], x.dtype)

    check_problem(
        item(camera) if getattr(camera, "ndim", None) == 3 else camera,
        item(model),
        item(image),
        item(mask),
    )


def _solve_rows(camera, model, image, mask, *, camera_batched, model_batched, options):
    """`solve` over the rows of a chunk: `solve_many` (batch-first, one shared
    Levenberg-Marquardt buffer) when the camera is shared, else `jax.vmap(solve)`."""
    if not camera_batched:
        if not model_batched:
            model = jnp.broadcast_to(model, (image.shape[0], *model.shape))
        return solve_many(camera, model, image, mask, options=options)
    one = functools.partial(solve, options=options)
    axes = (0, 0 if model_batched else None, 0, 0)
    return jax.vmap(one, in_axes=axes)(camera, model, image, mask)


@no_type_check
def solve_batch(
    camera: Real[ArrayLike, "3 4"] | Real[ArrayLike, "B 3 4"],
    models: Real[ArrayLike, "B n 3"] | Real[ArrayLike, "n 3"],
    images: Real[ArrayLike, "B n 2"],
    masks: Bool[ArrayLike, "B n"] | None = None,
    *,
    options: Options | None = None,
    chunk_size: int | None = None,
    devices=None,
    **changes,
) -> Solution:
    """`jaxpose.solve` over a batch of problems, sharded over devices and chunked.

    Equivalent to `jax.jit(jax.vmap(jaxpose.solve))` on the whole batch (same results,
    row by row; with one shared camera it runs `jaxpose.solve_many`, the batch-first
    path, much faster than a plain `vmap` of the mixed method), but with the batch axis
    split over `devices` (a `"batch"` mesh) and streamed in chunks of `chunk_size`
    problems, so that a million problems fit in memory. Call it eagerly (its inputs are
    concrete arrays); under `jit` use `jax.vmap(jaxpose.solve)` itself. The dtype follows
    the inputs (float32 stays float32; float64 needs `jax_enable_x64`).

    **Arguments:**
    - `camera`: one camera `(3, 4)` for all problems, or one per problem `(B, 3, 4)`.
    - `models`: `(B, n, 3)` model points, or `(n, 3)` shared by all problems.
    - `images`: `(B, n, 2)` pixels.
    - `masks`: optional `(B, n)` bool, which matches each problem uses.
    - `options`, `**changes`: as `jaxpose.solve` (an `Options`, and keyword shorthands
      for its fields: `method`, `threshold`, `triplet_budget`, ...).
    - `chunk_size`, `devices`: see `jaxpose.api.run_batched`.

    **Returns:** a `Solution` whose fields have a leading `B` axis (jax arrays on the
    default device). Problems with non-finite values give `status` `NOT_FINITE` and finite
    placeholders, as `jaxpose.solve` does.

    **Raises:** `ValueError` naming the argument for wrong shapes, dtypes or options.
    """
    options = resolve(options, changes)
    images = as_batched(images, "images", 2, shared=False)
    B, n = images.shape[:2]
    models = as_batched(models, "models", 3, batch_size=B, count=n)
    camera = as_batched(camera, "camera", (3, 4), batch_size=B)
    dtype = jnp.result_type(camera.dtype, models.dtype, images.dtype)
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))
    if masks is None:
        masks = np.ones((B, n), dtype=bool)
    else:
        masks = np.asarray(masks)
        if masks.dtype != np.bool_ or masks.shape != (B, n):
            raise ValueError(
                f"masks must be a bool array of shape ({B}, {n}), got {masks.dtype} {masks.shape}"
            )
    camera_batched, model_batched = camera.ndim == 3, models.ndim == 3
    shared, batched = [], []
    (batched if camera_batched else shared).append(camera.astype(dtype))
    (batched if model_batched else shared).append(models.astype(dtype))
    batched += [images.astype(dtype), masks]
    order = _argument_order(camera_batched, model_batched)
    out = run_batched(
        _Reordered(order),
        shared,
        batched,
        static={
            "camera_batched": camera_batched,
            "model_batched": model_batched,
            "options": options,
        },
        chunk_size=chunk_size,
        devices=devices,
    )
    return Solution(*jax.tree.map(jnp.asarray, tuple(out)))


def _argument_order(camera_batched: bool, model_batched: bool) -> tuple[int, int, int, int]:
    """Positions of (camera, model, image, mask) in `shared + batched`."""
    shared = [i for i, b in ((0, camera_batched), (1, model_batched)) if not b]
    batched = [i for i, b in ((0, camera_batched), (1, model_batched)) if b] + [2, 3]
    position = {arg: pos for pos, arg in enumerate(shared + batched)}
    return position[0], position[1], position[2], position[3]


class _Reordered:
    """`_solve_rows` taking its arguments in `shared + batched` order (hashable)."""

    def __init__(self, order: tuple[int, ...]):
        self.order = order

    def __call__(self, *args, **static):
        return _solve_rows(*(args[i] for i in self.order), **static)

    def __hash__(self):
        return hash((_Reordered, self.order))

    def __eq__(self, other):
        return isinstance(other, _Reordered) and other.order == self.order
