"""The pipeline: the observations of `B` problems in, one `Solution` of `B` out.

Every entry point is an adapter over `solve_problems`: `jaxpose.solve` runs it on a batch
of one, `jaxpose.solve_many` is it, `solve_batch` and the OpenCV-convention functions
chunk, shard and convert around it, recognition and the paper's experiment call it or
its parts. It owns, in this order:

1. the inputs' sanitation: a problem with a non-finite value runs on harmless finite
   placeholders and is reported `NOT_FINITE` (`finite_inputs`, `not_finite`);
2. the answer of every problem, values only, by the method of `Options.method`
   (`jaxpose.strategy._best.answer_batch`): for the mixed method the rungs of
   `escalation` (the best roots of the spread triplets, of more triplets, the whole
   mixed algorithm of the paper's Section 3), each run only for the problems the rungs
   before it left; for the paper's single methods, every triplet's run
   (`jaxpose.strategy._methods`) and the best accepted one;
3. the finish (`finish`): the answer polished to the Eq. 8 optimum, its implicit
   derivative attached (`jaxpose.strategy._implicit.polish`), its errors and status.

The acceptance rule is `jaxpose.strategy._accept`'s throughout.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry._errors import pose_error
from ..geometry._pose import Observations, Pose, observations, transform
from ..solvers._residuals import pixel_residuals, rms
from ..solvers._status import Status
from ._answer import Answer, finish_linear_batch
from ._best import answer_batch
from ._implicit import polish
from ._options import Options
from ._start import answer_from_start

__all__ = ["Solution", "finish", "finite_inputs", "not_finite", "solve_problems"]


class Solution(NamedTuple):
    """The answer to one pose problem (a leading batch axis for a batch).

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
    error: Float[Array, "*B"]
    pose_error: Float[Array, "*B"]
    status: Int[Array, "*B"]
    accepted: Bool[Array, "*B"]
    triplet: Int[Array, "*B 3"]


def finite_inputs(camera, model, image):
    """One problem with its non-finite values replaced by harmless finite ones (the
    camera by `[I | 0]`, points by zeros), and whether it had none: the solvers then run
    on finite numbers, and `not_finite` reports the problem. (Non-finite values of
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


def not_finite(sol: Solution, finite) -> Solution:
    """`sol` (one problem), or when the input held non-finite values, the placeholder
    answer: identity pose, zero errors, not accepted, status `NOT_FINITE` (and a zero
    gradient)."""
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


def finish(
    obs: Observations, found: Answer, method: str, derivative: bool, settled: bool
) -> Solution:
    """One problem's `Solution` from its chosen answer: a pose not accepted is the
    identity placeholder (its error kept where finite); for the optimising methods the
    accepted pose is polished to the Eq. 8 optimum by Newton steps, with the implicit
    derivative when `derivative` (unless `settled`: values only, already finished by
    `finish_linear_batch`), and its error measured again."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    accepted = Status.is_success(found.status)
    pose = jax.tree.map(lambda a, b: jnp.where(accepted, a, b), found.pose, Pose.identity(dtype))
    error = jnp.where(accepted | (found.error < big), found.error, 0)
    if method != "three_point":
        if not settled:
            pose = polish(obs, pose, accepted, derivative)
        final = rms(pixel_residuals(transform(pose, obs.model), obs), obs.mask)
        error = jnp.where(accepted, final, error)
    return Solution(
        pose=pose,
        error=error,
        pose_error=pose_error(obs.camera, pose.R, pose.t, obs.model, obs.image, obs.mask),
        status=found.status.astype(jnp.int32),
        accepted=accepted,
        triplet=found.triplet.astype(jnp.int32),
    )


def solve_problems(camera, model, image, mask, options: Options, start=None) -> Solution:
    """The pipeline (module docstring) on `B` problems of equal `n`: `camera` `(3, 4)`
    (shared) or `(B, 3, 4)`, `model` `(B, n, 3)`, `image` `(B, n, 2)`, `mask` `(B, n)`
    bool or `None` (every match). `start`: `None`, or a `Pose` of `B` given poses, from
    which step 2 of the answer runs instead of the three-point roots
    (`jaxpose.strategy._start.answer_from_start`). Arguments already checked
    (`jaxpose.solve_many` checks them); pure, for `jit`, `vmap` and `grad` (the
    derivative flows through the finish only)."""
    shared = None if jnp.ndim(camera) == 2 else 0
    camera, model, image, finite = jax.vmap(finite_inputs, in_axes=(shared, 0, 0))(
        camera, model, image
    )
    if mask is None:
        # (The barrier keeps XLA from constant-folding the all-true mask through the
        # triplet gathers, which costs seconds of compile time for nothing.)
        mask = jax.lax.optimization_barrier(jnp.ones(model.shape[:2], dtype=bool))
    obs = jax.vmap(observations)(camera, model, image, mask)
    sobs = jax.lax.stop_gradient(obs)
    if start is not None:
        found = answer_from_start(sobs, jax.lax.stop_gradient(start), options)
        settled = False
    else:
        found = answer_batch(sobs, options)
        # values only: an answer from the best roots is finished by two linear steps
        settled = not options.derivative and options.method == "mixed"
        settled = settled and options.refine is not None
    if settled:
        found = finish_linear_batch(sobs, found)

    def one(o, f):
        return finish(o, f, options.method, options.derivative, settled)

    return jax.vmap(not_finite)(jax.vmap(one)(obs, found), finite)
