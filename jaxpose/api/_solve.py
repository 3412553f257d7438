"""The JAX-native entry points: `solve` (one problem, differentiable), `solve_many` (a
batch, batch-first) and `solve_batch` (a large batch from numpy, chunked and sharded over
devices). The OpenCV-convention ones are in `jaxpose.api._pnp`."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._errors import pose_error
from ..geometry._pose import Observations, Pose, observations, transform
from ..geometry._validate import as_batched, check_problem, no_type_check
from ..solvers._residuals import pixel_residuals, rms
from ..solvers._status import Status
from ..strategy._best import Answer, answer, answer_batch, settle_batch
from ..strategy._implicit import polish
from ..strategy._jobs import CHUNK
from ..strategy._methods import per_triplet
from ..strategy._mixed import mixed_from_initial, mixed_from_initial_batch
from ..strategy._options import METHODS as METHODS
from ..strategy._options import Options, resolve
from ..strategy._triplets import best_triplet, initial_poses, select_triplets, triplet_count
from ._batch import run_batched

__all__ = ["METHODS", "Solution", "solve", "solve_batch", "solve_many"]


class Solution(NamedTuple):
    """The answer to one pose problem.

    **Fields:**
    - `pose`: `Pose(R, t)` mapping model to world, `p = R m + t` (a finite placeholder,
      the identity, when nothing was found at all).
    - `error`: Eq. 8 reprojection error (px).
    - `pose_error`: the paper's pose error (model units, e.g. mm).
    - `status`: `Status` code of the answer (`Status(int(status)).message`).
    - `accepted`: whether a pose was accepted (`ok` of `solve_pnp`).
    - `triplet`: the three matches (indices into `model`) of the triplet whose
      three-point root led to the answer, `(3,)` int32.
    """

    pose: Pose
    error: Float[Array, ""]
    pose_error: Float[Array, ""]
    status: Int[Array, ""]
    accepted: Bool[Array, ""]
    triplet: Int[Array, " 3"]


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
    **changes,
) -> Solution:
    """Recover the pose of a known object from one calibrated image (JAX-native).

    Pure, for ONE problem: composes with `jax.jit`, `jax.vmap` (batch the arrays) and
    `jax.grad`. All triplets of matches are solved at once; the answer is the accepted
    triplet pose of lowest Eq. 8 error (see `jaxpose.mixed` for the algorithm).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points `m_i`, `n >= 3`.
    - `image`: `(n, 2)` pixels matched to them.
    - `mask`: optional `(n,)` bool, which matches to use (fixed shapes with padding).
    - `options`: a `jaxpose.Options` (default `Options()`): the method (`"mixed"`,
      `"three_point"`, `"linear"` or `"nonlinear"`, the last two started from every
      triplet's three-point pose, as in the paper's experiment), the acceptance
      threshold, the triplets used (`max_triplets`, `triplet_budget`: the fast path for
      large batches of easy problems), the mixed algorithm's budgets. A static argument
      under `jax.jit` (hashable).
    - `**changes`: keyword shorthands for fields of `options`, e.g.
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
    camera, model, image, finite = _finite_inputs(camera, model, image)
    obs = observations(camera, model, image, mask)
    sobs = jax.lax.stop_gradient(obs)
    if options.method == "mixed" and options.refine is not None:
        found = answer(sobs, options)
        if not options.derivative:
            one = jax.tree.map(lambda a: a[None], (sobs, found))
            found = jax.tree.map(lambda a: a[0], settle_batch(*one))
        return _not_finite(_finish_answer(obs, found, options.derivative), finite)
    initial = _initial(obs, options)
    if options.method == "mixed":
        res = mixed_from_initial(sobs, initial, options=options)
        found = (res.pose, res.error, res.status)
    else:
        one = jax.tree.map(lambda a: a[None], (sobs, initial))
        found = jax.tree.map(lambda a: a[0], per_triplet(*one, options))
    finish = functools.partial(_finish, options.method, derivative=options.derivative)
    return _not_finite(finish(obs, initial.triplets, *found), finite)


@no_type_check
def solve_many(
    camera: Real[ArrayLike, "3 4"] | Real[ArrayLike, "B 3 4"],
    model: Real[ArrayLike, "B n 3"],
    image: Real[ArrayLike, "B n 2"],
    mask: Bool[ArrayLike, "B n"] | None = None,
    *,
    options: Options | None = None,
    **changes,
) -> Solution:
    """`solve` for a batch of `B` problems of equal `n`: the same answers as
    `jax.vmap(solve)`, computed batch-first. `camera` is `(3, 4)`, one camera for every
    problem (`jax.vmap(solve, in_axes=(None, 0, 0, 0))`), or `(B, 3, 4)`, one per problem.

    The difference is the cost: under a plain `vmap`, every problem pays for the mixed
    algorithm's full Levenberg-Marquardt buffer (`vmap` turns its "only when needed" into
    "always"); here the triplets of the whole batch that need it share one buffer
    (`jaxpose.strategy.mixed_from_initial_batch`), and the cheap steps run in cache-sized passes.
    Arguments as `solve` (`model`, `image`, `mask` with a leading batch axis); pure, for
    `jit` and `grad`.
    """
    options = resolve(options, changes)
    _check_many(camera, model, image, mask)
    B = jnp.shape(model)[0]
    shared = None if jnp.ndim(camera) == 2 else 0
    camera, model, image, finite = jax.vmap(_finite_inputs, in_axes=(shared, 0, 0))(
        camera, model, image
    )
    if mask is None:
        # (The barrier keeps XLA from constant-folding the all-true mask through the
        # triplet gathers, which costs seconds of compile time for nothing.)
        mask = jax.lax.optimization_barrier(jnp.ones(model.shape[:2], dtype=bool))
    obs = jax.vmap(observations)(camera, model, image, mask)
    if options.method == "mixed" and options.refine is not None:
        found = answer_batch(jax.lax.stop_gradient(obs), options)
        if not options.derivative:
            found = settle_batch(jax.lax.stop_gradient(obs), found)
        finish = functools.partial(_finish_answer, derivative=options.derivative)
        return jax.vmap(_not_finite)(jax.vmap(finish)(obs, found), finite)
    T = triplet_count(model.shape[1], options)
    initial = jax.lax.map(
        lambda o: _initial(o, options), obs, batch_size=max(1, min(B, CHUNK // T))
    )
    sobs = jax.lax.stop_gradient(obs)
    if options.method == "mixed":
        res = mixed_from_initial_batch(sobs, initial, options=options)
        found = (res.pose, res.error, res.status)
    else:
        found = per_triplet(sobs, initial, options)
    return jax.vmap(_not_finite)(
        jax.vmap(functools.partial(_finish, options.method, derivative=options.derivative))(
            obs, initial.triplets, *found
        ),
        finite,
    )


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


def _finite_inputs(camera, model, image):
    """The problem with its non-finite values replaced by harmless finite ones (the
    camera by `[I | 0]`, points by zeros), and whether it had none: the solvers then run
    on finite numbers, and `_not_finite` reports the problem. (Non-finite values of
    masked-out matches count too: padding should be finite.)"""
    camera = jnp.asarray(camera)
    if not jnp.issubdtype(camera.dtype, jnp.floating):
        camera = camera.astype(jnp.result_type(float))
    model = jnp.asarray(model, camera.dtype)
    image = jnp.asarray(image, camera.dtype)
    finite_camera = jnp.all(jnp.isfinite(camera))
    finite = finite_camera & jnp.all(jnp.isfinite(model)) & jnp.all(jnp.isfinite(image))
    camera = jnp.where(finite_camera, camera, jnp.eye(3, 4, dtype=camera.dtype))
    model = jnp.where(jnp.isfinite(model), model, 0)
    image = jnp.where(jnp.isfinite(image), image, 0)
    return camera, model, image, finite


def _not_finite(sol: Solution, finite) -> Solution:
    """`sol`, or when the input held non-finite values, the placeholder answer: identity
    pose, zero errors, not accepted, status `NOT_FINITE` (and a zero gradient)."""
    dtype = sol.error.dtype

    def pick(a, b):
        return jnp.where(finite, a, jnp.asarray(b, a.dtype))

    return Solution(
        pose=Pose(pick(sol.pose.R, jnp.eye(3, dtype=dtype)), pick(sol.pose.t, 0)),
        error=pick(sol.error, 0),
        pose_error=pick(sol.pose_error, 0),
        status=pick(sol.status, Status.NOT_FINITE),
        accepted=sol.accepted & finite,
        triplet=jnp.where(finite, sol.triplet, jnp.arange(3, dtype=sol.triplet.dtype)),
    )


def _initial(obs: Observations, options: Options):
    """Step 1: the triplets of `select_triplets` and their best three-point roots (no
    gradient)."""
    sobs = jax.lax.stop_gradient(obs)
    _, triplets = select_triplets(sobs, options)
    return initial_poses(sobs, options=options, triplets=triplets)


def _finish(
    method,
    obs: Observations,
    triplets,
    poses: Pose,
    error,
    status,
    derivative: bool = True,
    polished: bool = False,
) -> Solution:
    """The answer from every triplet's outcome: the best accepted, polished (with the
    implicit derivative attached) for the optimising methods unless `polished` (values
    only, finished by `settle_batch`)."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    index, accepted = best_triplet(error, status)
    pose = Pose(poses.R[index], poses.t[index])
    pose = jax.tree.map(lambda a, b: jnp.where(accepted, a, b), pose, Pose.identity(dtype))
    error = jnp.where(accepted, error[index], jnp.where(error[index] < big, error[index], 0))
    if method != "three_point":
        if not polished:
            pose = polish(obs, pose, accepted, derivative)
        final = rms(pixel_residuals(transform(pose, obs.model), obs), obs.mask)
        error = jnp.where(accepted, final, error)
    return Solution(
        pose=pose,
        error=error,
        pose_error=pose_error(obs.camera, pose.R, pose.t, obs.model, obs.image, obs.mask),
        status=status[index].astype(jnp.int32),
        accepted=accepted,
        triplet=triplets[index].astype(jnp.int32),
    )


def _finish_answer(obs: Observations, found: Answer, derivative: bool = True) -> Solution:
    """`_finish` for a problem whose answer is already chosen (`jaxpose.strategy.answer`);
    `derivative=False`: the answer is already settled (`settle_batch`), not polished
    again."""
    pose = Pose(found.pose.R[None], found.pose.t[None])
    return _finish(
        "mixed",
        obs,
        found.triplet[None],
        pose,
        found.error[None],
        found.status[None],
        derivative,
        polished=not derivative,
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
