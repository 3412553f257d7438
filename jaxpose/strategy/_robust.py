r"""Robust mode: pose recovery when some of the matches are wrong.

For one problem, as one fixed-shape batch (no random sampling: every triplet, or the
fixed seeded sample of `jaxpose.strategy.triplet_indices` above `max_triplets`):

1. the three-point method on every triplet, all four roots (near-real ones included). A
   triplet counts as aligned below the smaller of two areas: `min_area` times the spread
   of all matches (`jaxpose.strategy.area_threshold`, as the mixed algorithm's) and
   $\tau^2$, the inlier test's own scale. The spread of all matches counts the wrong
   ones too: a small patch of right matches among wrong ones spread over the image would
   otherwise count as aligned, and no pose would be found (OpenCV's USAC test with 90% of
   the matches wrong);
2. every root scored by consensus over all matches: match `i` is an inlier of a pose
   when its point lies in front of the camera and its reprojection residual is below
   the inlier threshold, $\lVert \hat u_i - u_i \rVert < \tau$; the score is the
   inlier count, ties broken by the truncated (MSAC) cost
   $\sum_i \min(\lVert \hat u_i - u_i \rVert^2, \tau^2)$;
3. the best root refined on its inliers (the small-movement linear method, or
   Levenberg-Marquardt), inliers recomputed at the refined pose, and refined again
   (`rounds` times). A refinement is kept when it does not lose inliers or lowers the
   truncated cost;
4. the answer is refitted on the final inliers (the same refinement, from the pose of
   step 3, kept whenever it is finite and in front of the camera), as
   `cv2.solvePnPRansac` refits on its inliers: with a refinement, never the minimal
   sample's pose. Its inliers are those it was fitted on.

Exhaustive scoring needs no iteration count or confidence: the answer is the
consensus optimum over all triplets' roots, the same on every call. Above
`max_triplets` triplets, the triplets are a seeded sample (`triplet_indices(n,
max_triplets, seed)`, or the `triplets` given): the same seed, the same answer.
`jaxpose.solve_pnp_ransac` wraps it with `cv2.solvePnPRansac`'s conventions; the options
are a `jaxpose.RobustOptions`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from ..geometry._pose import Observations, Pose, observations, transform
from ..solvers._nonlinear import nonlinear
from ..solvers._residuals import pixel_residuals, rms, safe_inverse_depth
from ..solvers._status import Status
from ._linear_runs import linear_from
from ._options import RobustOptions, resolve
from ._triplets import area_threshold, triplet_indices, triplet_roots

__all__ = ["RobustResult", "robust"]


class RobustResult(NamedTuple):
    """The robust answer to one pose problem.

    **Fields:**
    - `pose`: `Pose(R, t)` mapping model to world (the identity when nothing was found).
    - `error`: Eq. 8 reprojection error over the inliers (px).
    - `inliers`: `(n,)` bool, the matches consistent with the pose.
    - `num_inliers`: their count.
    - `status`: `OK` (at least `min_inliers` inliers), `REJECTED` (fewer),
      `NO_SOLUTION` (no triplet gave a pose), `TOO_FEW_POINTS` (fewer than 3 matches)
      or `NOT_FINITE`.
    - `triplet`: index (into `jaxpose.strategy.triplet_indices(n, max_triplets)`) of the winning
      triplet; `root`: which of its four three-point slots.
    - `refined`: whether the pose is the refined one (else the winning root itself).
    - `cost`: the truncated cost of the pose (px^2).
    """

    pose: Pose
    error: Float[Array, ""]
    inliers: Bool[Array, " n"]
    num_inliers: Int[Array, ""]
    status: Int[Array, ""]
    triplet: Int[Array, ""]
    root: Int[Array, ""]
    refined: Bool[Array, ""]
    cost: Float[Array, ""]


def _score(obs: Observations, pose: Pose, threshold):
    """Inlier mask, inlier count and truncated cost of one pose over all matches.

    Written elementwise (no small matrix products): it runs for every root of every
    triplet, and batched 3x3 products are slow on CPU."""
    R, t, C, m = pose.R, pose.t, obs.camera, obs.model
    world = [m[:, 0] * R[k, 0] + m[:, 1] * R[k, 1] + m[:, 2] * R[k, 2] + t[k] for k in range(3)]
    h = [world[0] * C[k, 0] + world[1] * C[k, 1] + world[2] * C[k, 2] + C[k, 3] for k in range(3)]
    depth = h[2]  # the camera is normalised: c3 . [p 1] is the depth
    inverse = safe_inverse_depth(depth)
    r2 = (h[0] * inverse - obs.image[:, 0]) ** 2 + (h[1] * inverse - obs.image[:, 1]) ** 2
    inliers = obs.mask & (depth > 0) & (r2 < threshold**2)
    cost = jnp.sum(jnp.where(obs.mask, jnp.where(inliers, r2, threshold**2), 0))
    return inliers, jnp.sum(inliers).astype(jnp.int32), cost


def robust(
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "n 3"],
    image: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    options: RobustOptions | None = None,
    triplets: Int[ArrayLike, "T 3"] | None = None,
    **changes,
) -> RobustResult:
    r"""The pose of a known object from matches of which some may be wrong (JAX-native).

    Pure, for ONE problem, fixed shapes: composes with `jax.jit` and `jax.vmap`. See the
    module docstring for the algorithm. No gradient is defined through the choice of
    inliers (the inputs are taken under `stop_gradient`).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points; `image`: `(n, 2)` pixels matched to them.
    - `mask`: optional `(n,)` bool, which matches take part (padding).
    - `options`: a `RobustOptions` (default: `RobustOptions()`): the inlier test's pixel
      radius $\tau$ (`inlier_threshold`) and `min_inliers` (either may be traced, given
      as a keyword shorthand), the refinement (`refine`, `rounds`, `iterations`,
      `max_steps`) and the triplets (`min_area`, `collinear_tol`, `max_triplets`).
    - `triplets`: `(T, 3)` index triplets to score, possibly traced (default:
      `triplet_indices(n, max_triplets)`; `solve_pnp_ransac` passes a seeded sample).
    - `**changes`: keyword shorthands for fields of `options`
      (`robust(C, M, I, inlier_threshold=2.0)`); an unknown one raises `ValueError`.

    **Returns:** a `RobustResult`.
    """
    options = resolve(options, changes, RobustOptions)
    obs = jax.lax.stop_gradient(observations(camera, model, image, mask))
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    n = obs.model.shape[0]
    idx = jnp.asarray(
        triplet_indices(n, options.max_triplets) if triplets is None else triplets, jnp.int32
    )
    thr = jnp.asarray(options.inlier_threshold, dtype)
    area = jnp.minimum(area_threshold(obs, options), thr * thr)  # step 1's aligned test

    def candidates(ijk):
        sol = triplet_roots(obs, ijk, options, area)
        # (a triplet that repeats a match is degenerate: padding, see solve_pnp_ransac)
        distinct = (ijk[0] != ijk[1]) & (ijk[1] != ijk[2]) & (ijk[0] != ijk[2])
        valid = sol.valid & jnp.all(obs.mask[ijk]) & distinct
        _, count, cost = jax.vmap(lambda R, t: _score(obs, Pose(R, t), thr))(sol.R, sol.t)
        return sol.R, sol.t, valid, count, cost

    Rs, ts, valid, count, cost = jax.vmap(candidates)(idx)  # (T, 4, ...)
    count = jnp.where(valid, count, -1).reshape(-1)
    cost = jnp.where(valid, cost, big).reshape(-1)
    best_count = jnp.max(count)
    k = jnp.argmin(jnp.where(count == best_count, cost, big))
    found = jnp.any(valid)
    eye = jnp.eye(3, dtype=dtype)
    pose = Pose(
        jnp.where(found, Rs.reshape(-1, 3, 3)[k], eye),
        jnp.where(found, ts.reshape(-1, 3)[k], 0),
    )
    inliers, num, score = _score(obs, pose, thr)
    refined = jnp.zeros((), dtype=bool)

    def refit(pose, inliers):
        local = obs._replace(mask=inliers)
        if options.refine == "linear":
            res = linear_from(local, pose, options.iterations)
        else:
            res = nonlinear(local, pose, max_steps=options.max_steps)
        usable = (
            found
            & (jnp.sum(inliers) >= 3)
            & (res.status != Status.NOT_FINITE)
            & (res.status != Status.BEHIND_CAMERA)
        )
        return res.pose, usable

    for _ in range(options.rounds if options.refine != "none" else 0):
        new_pose, usable = refit(pose, inliers)
        new_inliers, new_num, new_score = _score(obs, new_pose, thr)
        keep = usable & ((new_num >= num) | (new_score <= score))
        pose = jax.tree.map(lambda a, b: jnp.where(keep, a, b), new_pose, pose)
        inliers = jnp.where(keep, new_inliers, inliers)
        num = jnp.where(keep, new_num, num)
        score = jnp.where(keep, new_score, score)
        refined = refined | keep

    if options.refine != "none":  # step 4: the answer is the refit on its inliers
        new_pose, keep = refit(pose, inliers)
        pose = jax.tree.map(lambda a, b: jnp.where(keep, a, b), new_pose, pose)
        _, _, new_score = _score(obs, pose, thr)
        score = jnp.where(keep, new_score, score)
        refined = refined | keep

    error = rms(pixel_residuals(transform(pose, obs.model), obs), inliers)
    finite = (
        jnp.all(jnp.isfinite(obs.camera))
        & jnp.all(jnp.where(obs.mask[:, None], jnp.isfinite(obs.model), True))
        & jnp.all(jnp.where(obs.mask[:, None], jnp.isfinite(obs.image), True))
    )
    status = jnp.select(
        [jnp.sum(obs.mask) < 3, ~finite, ~found, num < options.min_inliers],
        [Status.TOO_FEW_POINTS, Status.NOT_FINITE, Status.NO_SOLUTION, Status.REJECTED],
        Status.OK,
    ).astype(jnp.int32)
    ok_pose = finite & found
    pose = jax.tree.map(lambda a, b: jnp.where(ok_pose, a, b), pose, Pose.identity(dtype))
    return RobustResult(
        pose=pose,
        error=jnp.where(ok_pose & jnp.isfinite(error), error, 0),
        inliers=inliers & ok_pose,
        num_inliers=jnp.where(ok_pose, num, 0).astype(jnp.int32),
        status=status,
        triplet=(k // 4).astype(jnp.int32),
        root=(k % 4).astype(jnp.int32),
        refined=refined & ok_pose,
        cost=jnp.where(ok_pose, score, 0),
    )
