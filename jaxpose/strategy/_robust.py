r"""Robust mode: pose recovery when some of the matches are wrong.

For one problem, as one fixed-shape batch (no random sampling: every triplet, or the
fixed seeded sample of `jaxpose.triplet_indices` above `max_triplets`):

1. the three-point method on every triplet, all four roots (near-real ones included);
2. every root scored by consensus over all matches: match `i` is an inlier of a pose
   when its point lies in front of the camera and its reprojection residual is below
   the inlier threshold, $\lVert \hat u_i - u_i \rVert < \tau$; the score is the
   inlier count, ties broken by the truncated (MSAC) cost
   $\sum_i \min(\lVert \hat u_i - u_i \rVert^2, \tau^2)$;
3. the best root refined on its inliers (the small-movement linear method, or
   Levenberg-Marquardt), inliers recomputed at the refined pose, and refined again
   (`rounds` times). A refinement is kept when it does not lose inliers or lowers the
   truncated cost.

Exhaustive scoring needs no iteration count or confidence: the answer is the
consensus optimum over all triplets' roots, the same on every call. `solve_pnp_ransac`
wraps it with `cv2.solvePnPRansac`'s conventions.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry._camera import camera_matrix, undistort_pixels
from ..geometry._pose import Observations, Pose, observations, transform
from ..geometry._rotation import matrix_to_rotvec
from ..geometry._validate import as_dist_coeffs, as_intrinsics, as_matching
from ..solvers._linear import linear
from ..solvers._nonlinear import nonlinear
from ..solvers._p3p import three_point
from ..solvers._residuals import pixel_residuals, rms, safe_inverse_depth
from ..solvers._status import Status
from ._mixed import triplet_indices

__all__ = ["REFINEMENTS", "RobustResult", "robust", "solve_pnp_ransac"]

REFINEMENTS = ("linear", "nonlinear", "none")


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
    - `triplet`: index (into `jaxpose.triplet_indices(n, max_triplets)`) of the winning
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


def _check_options(refine: str, rounds: int) -> None:
    if refine not in REFINEMENTS:
        raise ValueError(f"refine must be one of {REFINEMENTS}, got {refine!r}")
    if int(rounds) < 0:
        raise ValueError(f"rounds must be >= 0, got {rounds}")


def robust(
    camera: Float[Array, "3 4"],
    model: Float[Array, "n 3"],
    image: Float[Array, "n 2"],
    mask: Bool[Array, " n"] | None = None,
    *,
    inlier_threshold: float | Float[Array, ""] = 8.0,
    min_inliers: int | Int[Array, ""] = 4,
    min_area: float = 40.0,
    collinear_tol: float = 5e-3,
    max_triplets: int | None = 2000,
    refine: str = "linear",
    iterations: int = 5,
    rounds: int = 2,
    max_steps: int = 50,
) -> RobustResult:
    r"""The pose of a known object from matches of which some may be wrong (JAX-native).

    Pure, for ONE problem, fixed shapes: composes with `jax.jit` and `jax.vmap`. See the
    module docstring for the algorithm. No gradient is defined through the choice of
    inliers (the inputs are taken under `stop_gradient`).

    **Arguments:**
    - `camera`: the 3x4 projection matrix `C`, calibrated in the world frame.
    - `model`: `(n, 3)` model points; `image`: `(n, 2)` pixels matched to them.
    - `mask`: optional `(n,)` bool, which matches take part (padding).
    - `inlier_threshold`: the inlier test's pixel radius $\tau$ (may be traced).
    - `min_inliers`: fewest inliers for the answer to count (`OK`); may be traced.
    - `min_area`, `collinear_tol`: degenerate-triplet tests (`jaxpose.three_point`).
    - `max_triplets`: above this many triplets, a fixed seeded sample of them.
    - `refine`: `"linear"` (the small-movement method, `iterations` steps per round),
      `"nonlinear"` (Levenberg-Marquardt, `max_steps`) or `"none"`.
    - `rounds`: refine-then-recompute-inliers rounds.

    **Returns:** a `RobustResult`.
    """
    _check_options(refine, rounds)
    obs = jax.lax.stop_gradient(observations(camera, model, image, mask))
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    n = obs.model.shape[0]
    idx = jnp.asarray(triplet_indices(n, max_triplets))
    thr = jnp.asarray(inlier_threshold, dtype)

    def candidates(ijk):
        sol = three_point(
            obs.camera,
            obs.model[ijk],
            obs.image[ijk],
            min_area=min_area,
            collinear_tol=collinear_tol,
            approximate=True,
        )
        valid = sol.valid & jnp.all(obs.mask[ijk])
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

    for _ in range(int(rounds) if refine != "none" else 0):
        local = obs._replace(mask=inliers)
        if refine == "linear":
            res = linear(local, pose, iterations=iterations)
        else:
            res = nonlinear(local, pose, max_steps=max_steps)
        new_inliers, new_num, new_score = _score(obs, res.pose, thr)
        keep = (
            found
            & (jnp.sum(inliers) >= 3)
            & (res.status != Status.NOT_FINITE)
            & (res.status != Status.BEHIND_CAMERA)
            & ((new_num >= num) | (new_score <= score))
        )
        pose = jax.tree.map(lambda a, b: jnp.where(keep, a, b), res.pose, pose)
        inliers = jnp.where(keep, new_inliers, inliers)
        num = jnp.where(keep, new_num, num)
        score = jnp.where(keep, new_score, score)
        refined = refined | keep

    error = rms(pixel_residuals(transform(pose, obs.model), obs), inliers)
    finite = (
        jnp.all(jnp.isfinite(obs.camera))
        & jnp.all(jnp.where(obs.mask[:, None], jnp.isfinite(obs.model), True))
        & jnp.all(jnp.where(obs.mask[:, None], jnp.isfinite(obs.image), True))
    )
    status = jnp.select(
        [jnp.sum(obs.mask) < 3, ~finite, ~found, num < min_inliers],
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


# --------------------------------------------------------------------------- cv2-style


@functools.partial(
    jax.jit, static_argnames=("max_triplets", "refine", "iterations", "rounds", "max_steps")
)
def _robust_opencv(
    K, obj, img, threshold, min_inliers, max_triplets, refine, iterations, rounds, max_steps
):
    res = robust(
        camera_matrix(K),
        obj,
        img,
        inlier_threshold=threshold,
        min_inliers=min_inliers,
        max_triplets=max_triplets,
        refine=refine,
        iterations=iterations,
        rounds=rounds,
        max_steps=max_steps,
    )
    return res.status == Status.OK, matrix_to_rotvec(res.pose.R), res.pose.t, res.inliers


def solve_pnp_ransac(
    object_points,
    image_points,
    camera_matrix,
    dist_coeffs=None,
    *,
    reprojection_error: float = 8.0,
    min_inliers: int = 4,
    max_triplets: int | None = 2000,
    refine: str = "linear",
    iterations: int = 5,
    rounds: int = 2,
    max_steps: int = 50,
):
    """Drop-in for `cv2.solvePnPRansac`: the pose of the object in the camera frame from
    matches of which some may be wrong (jaxpose's robust mode, float64).

    Same conventions and shapes as OpenCV (numpy in and out): `object_points` `(n, 3)`
    (or `(n, 1, 3)`), `image_points` `(n, 2)`, `camera_matrix` `K` `(3, 3)`, optional
    `dist_coeffs` (removed first with `cv2.undistortPoints`, so the inlier test is on
    undistorted pixels). `reprojection_error` is the inlier threshold in pixels
    (OpenCV's default, 8). Instead of RANSAC's iterations and confidence, every triplet
    (up to `max_triplets`) is scored; see `jaxpose.robust` for the other options.

    **Returns:** `(ok, rvec, tvec, inliers)`: `rvec`, `tvec` of shape `(3, 1)` with
    `x_cam = Rodrigues(rvec) X + tvec`; `inliers` the indices of the inlier matches,
    int32 `(k, 1)`, or `None` when `ok` is False (then `rvec`, `tvec` are finite
    placeholders, zeros).
    """
    K = as_intrinsics(camera_matrix, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    obj, img = as_matching(object_points, image_points, min_count=3)
    if isinstance(reprojection_error, bool) or not (
        isinstance(reprojection_error, int | float | np.floating | np.integer)
        and math.isfinite(reprojection_error)
        and reprojection_error > 0
    ):
        raise ValueError(
            f"reprojection_error must be a positive number, got {reprojection_error!r}"
        )
    if (
        isinstance(min_inliers, bool)
        or not isinstance(min_inliers, int | np.integer)
        or min_inliers < 3
    ):
        raise ValueError(f"min_inliers must be an integer >= 3, got {min_inliers!r}")
    if max_triplets is not None and (
        isinstance(max_triplets, bool)
        or not isinstance(max_triplets, int | np.integer)
        or max_triplets < 1
    ):
        raise ValueError(f"max_triplets must be None or an integer >= 1, got {max_triplets!r}")
    _check_options(refine, rounds)
    img = undistort_pixels(img, K, dist)
    with jax.enable_x64(True):
        ok, rvec, tvec, inliers = _robust_opencv(
            jnp.asarray(K, jnp.float64),
            jnp.asarray(obj, jnp.float64),
            jnp.asarray(img, jnp.float64),
            jnp.asarray(reprojection_error, jnp.float64),
            jnp.asarray(min_inliers, jnp.int32),
            None if max_triplets is None else int(max_triplets),
            refine,
            int(iterations),
            int(rounds),
            int(max_steps),
        )
        ok = bool(ok)
        rvec, tvec = np.asarray(rvec, np.float64), np.asarray(tvec, np.float64)
        inliers = np.asarray(inliers)
    if not ok:
        return False, np.zeros((3, 1)), np.zeros((3, 1)), None
    index = np.flatnonzero(inliers).astype(np.int32).reshape(-1, 1)
    return True, rvec.reshape(3, 1), tvec.reshape(3, 1), index
