"""The other local minima of Eq. 8 that the algorithm's starts lead to (one problem):
what `cv2.solvePnPGeneric` returns beside the answer (`jaxpose.solve_pnp_generic`).

Eq. 8 can have several local minima: a coplanar model seen from afar has two attitudes
that image it nearly alike (the planar ambiguity), and four matches may fit a few poses
of a general model. Given the answer, `local_minima` refines, each to its own local
minimum, the starts that lead to the others:

- for a coplanar model (`FLAT_TOL`), the answer's planar partner (`planar_partner`) and
  the two poses of the plane's homography (`planar_poses`, IPPE's two);
- the `MINIMA_ROOTS` best-scored distinct three-point roots of the answer's triplets
  (those of `Options.spread_points` matches spread in the image, `distinct_best`).

Each start runs as a problem of its own from that pose (`jaxpose.strategy._start`: the
linear method, Levenberg-Marquardt with `MINIMA_STEPS` steps where it does not reach an
accepted pose, the finish to the stationary point of Eq. 8), all of them one batch of
the pipeline; a start is kept when its run is accepted, ends at a local minimum of Eq. 8
(`is_minimum`) and is distinct (`SAME_MINIMUM`) from the answer and from the minima
kept before it.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry._pose import Observations, Pose, observations
from ..solvers._chart import chart_at, chart_residuals
from ..solvers._components import Mat3, mat_to_array, take_along
from ..solvers._kernel_linear import matches_from_observations, pixel_error_kernel
from ..solvers._linalg import positive_definite_solve
from ._best import answer_triplets
from ._best_roots import _roots, distinct_best
from ._options import Options
from ._pipeline import Solution, solve_problems
from ._planar import planar_partner, planar_poses

__all__ = [
    "MINIMA_ROOTS",
    "MINIMA_STEPS",
    "MINIMUM_STEP",
    "SAME_MINIMUM",
    "Minima",
    "is_minimum",
    "local_minima",
    "minimum_starts",
    "rank_minima",
]

#: Three-point roots refined by `local_minima` (the best-scored distinct ones).
MINIMA_ROOTS = 8

#: Levenberg-Marquardt's step budget of each start (at least; `Options.max_steps`): the
#: valleys of the planar ambiguity are flat, and a run from the homography's poses can
#: take more than the answer's 50 steps to converge to their bottom (measured: 200 where
#: 50 left a planar problem's second minimum unconverged).
MINIMA_STEPS = 200

#: The largest Newton step of Eq. 8 (rad; object radii: `jaxpose.solvers._chart`) at a
#: pose that counts as a local minimum. (The linear method converges to its own fixed
#: point, which is Eq. 8's minimum only where the pose fits: measured, a root's run
#: accepted at 22.7 px whose Gauss-Newton step was 2 rad.)
MINIMUM_STEP = 1e-6

#: Two local minima closer than this (rotation, rad; translation, relative to the longer
#: of the two) are one.
SAME_MINIMUM = 1e-4


class Minima(NamedTuple):
    """Local minima of Eq. 8 in fixed shapes (leading axis `S`), with a mask.

    **Fields:** `pose` (`R (S, 3, 3)`, `t (S, 3)`, model to world); `error` (Eq. 8, px);
    `found`: whether the slot holds a minimum (the others are placeholders). From
    `local_minima`, one slot per start of `minimum_starts`, `found` where the start's run
    was accepted and its minimum is distinct from the answer and from the minima of the
    starts before it; from `rank_minima` (`jaxpose.minima`), the answer first among them
    and every slot sorted by error, the minima before the placeholders (the identity
    pose, error 0)."""

    pose: Pose
    error: Float[Array, " S"]
    found: Bool[Array, " S"]


def minimum_starts(obs: Observations, answer: Pose, options: Options) -> tuple[Pose, Array]:
    """The starts of `local_minima` for one problem: `(Pose` of `S = 3 + MINIMA_ROOTS`
    poses, `valid (S,))`: the answer's planar partner, the two poses of the plane's
    homography (valid only for a coplanar model), then the best distinct roots."""
    partner, flat = planar_partner(obs, answer)
    planar, planar_ok = planar_poses(obs)
    one = jax.tree.map(lambda a: a[None], obs)
    m = matches_from_observations(one)
    R, t, valid = _roots(one, m, answer_triplets(one, options), options)
    score = pixel_error_kernel(R, t, jax.tree.map(lambda a: a[:, None], m))
    big = jnp.finfo(score.dtype).max
    score = jnp.where(valid & jnp.isfinite(score), score, big)
    pick, found = distinct_best(score, R, min(MINIMA_ROOTS, score.shape[1]))
    picked = take_along([*R, *t], pick, axis=1)
    roots = Pose(mat_to_array(Mat3(*picked[:9]))[0], jnp.stack(picked[9:], axis=-1)[0])
    starts = Pose(
        jnp.concatenate([partner.R[None], planar.R, roots.R]),
        jnp.concatenate([partner.t[None], planar.t, roots.t]),
    )
    return starts, jnp.concatenate([flat[None], planar_ok, found[0]])


def is_minimum(obs: Observations, pose: Pose) -> Bool[Array, ""]:
    """Whether `pose` is a local minimum of Eq. 8: the Hessian in the chart at it
    positive definite and its Newton step below `MINIMUM_STEP`."""
    chart = chart_at(pose, obs)

    def cost(xi):
        r = chart_residuals(xi, chart, obs)
        return 0.5 * jnp.sum(r * r)

    zero = jnp.zeros(6, pose.t.dtype)
    step, positive = positive_definite_solve(jax.hessian(cost)(zero), -jax.grad(cost)(zero))
    return positive & jnp.all(jnp.abs(step) < MINIMUM_STEP)


def same_minimum(a: Pose, b: Pose) -> Bool[Array, ""]:
    """Whether two poses are one local minimum (`SAME_MINIMUM`)."""
    cos = (jnp.sum(a.R * b.R) - 1) / 2  # trace(Ra^T Rb) = 1 + 2 cos(angle)
    scale = jnp.maximum(jnp.maximum(jnp.linalg.norm(a.t), jnp.linalg.norm(b.t)), 1e-300)
    close_t = jnp.linalg.norm(a.t - b.t) < SAME_MINIMUM * scale
    return (cos > jnp.cos(SAME_MINIMUM)) & close_t


def local_minima(camera, model, image, mask, answer: Pose, options: Options) -> Minima:
    """The local minima of one problem other than its answer (module docstring).

    **Arguments:** as `jaxpose.solve` (`camera` `(3, 4)`, `model` `(n, 3)`, `image`
    `(n, 2)`, `mask` `(n,)`), `answer` its accepted pose, `options` (a static key:
    values only, `derivative=False`, is what the callers pass).

    **Returns:** a `Minima` of `S = 3 + MINIMA_ROOTS` slots.
    """
    obs = observations(camera, model, image, mask)
    options = dataclasses.replace(options, max_steps=max(options.max_steps, MINIMA_STEPS))
    starts, valid = minimum_starts(obs, answer, options)
    S = valid.shape[0]
    sol = solve_problems(
        camera,
        jnp.broadcast_to(model, (S, *model.shape)),
        jnp.broadcast_to(image, (S, *image.shape)),
        jnp.broadcast_to(mask, (S, *mask.shape)),
        options,
        starts,
    )
    finite = jnp.all(jnp.isfinite(sol.pose.R), axis=(1, 2)) & jnp.all(
        jnp.isfinite(sol.pose.t), axis=1
    )
    minimum = jax.vmap(is_minimum, in_axes=(None, 0))(obs, sol.pose)
    ok = valid & sol.accepted & finite & minimum
    distinct = []
    for i in range(S):
        pose_i = jax.tree.map(lambda a, i=i: a[i], sol.pose)
        keep = ok[i] & ~same_minimum(pose_i, answer)
        for j in range(i):
            pose_j = jax.tree.map(lambda a, j=j: a[j], sol.pose)
            keep = keep & ~(distinct[j] & same_minimum(pose_i, pose_j))
        distinct.append(keep)
    return Minima(sol.pose, sol.error, jnp.stack(distinct))


def rank_minima(solution: Solution, minima: Minima) -> Minima:
    """The answer of `solution` and the other minima of `local_minima` (its `minima`) as
    one `Minima` of `1 + S` slots sorted by Eq. 8 error: the `found` ones first (the
    answer among them, found where it was accepted; none where it was not), then the
    placeholders, the identity pose with error 0 (never a NaN). One problem; pure, for
    `jit`, `vmap` and `grad` (the order carries no derivative, the poses theirs)."""
    accepted = solution.accepted
    R = jnp.concatenate([solution.pose.R[None], minima.pose.R])
    t = jnp.concatenate([solution.pose.t[None], minima.pose.t])
    error = jnp.concatenate([solution.error[None], minima.error])
    found = jnp.concatenate([accepted[None], minima.found & accepted])
    found = found & jnp.isfinite(error)
    big = jnp.finfo(error.dtype).max
    order = jnp.argsort(jnp.where(found, error, big), stable=True)
    R, t, error, found = R[order], t[order], error[order], found[order]
    eye = jnp.eye(3, dtype=R.dtype)
    R = jnp.where(found[:, None, None], R, eye)
    t = jnp.where(found[:, None], t, 0)
    error = jnp.where(found, error, 0)
    return Minima(Pose(R, t), error, found)
