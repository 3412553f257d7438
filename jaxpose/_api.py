"""The public entry points: `solve` (JAX-native) and `solve_pnp` / `solve_pnp_batch`
(drop-in for `cv2.solvePnP`, numpy in and out)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._camera import camera_matrix, undistort_pixels
from ._errors import pose_error
from ._mixed import best_triplet, initial_poses, mixed_from_initial, triplet_indices
from ._pose import Pose, observations
from ._rotation import matrix_to_rotvec
from ._solver.linear import linear
from ._solver.nonlinear import nonlinear
from ._status import Status
from ._validate import as_dist_coeffs, as_intrinsics, as_matching, as_points

__all__ = ["METHODS", "Solution", "solve", "solve_pnp", "solve_pnp_batch"]

METHODS = ("mixed", "three_point", "linear", "nonlinear")


class Solution(NamedTuple):
    """The answer to one pose problem.

    **Fields:**
    - `pose`: `Pose(R, t)` mapping model to world, `p = R m + t` (a finite placeholder,
      the identity, when nothing was found at all).
    - `error`: Eq. 8 reprojection error (px).
    - `pose_error`: the paper's pose error (model units, e.g. mm).
    - `status`: `Status` code of the answer (`Status(int(status)).message`).
    - `accepted`: whether a pose was accepted (`ok` of `solve_pnp`).
    - `triplet`: index (into `jaxpose.triplet_indices(n, max_triplets)`) of the triplet it
      came from.
    """

    pose: Pose
    error: Float[Array, ""]
    pose_error: Float[Array, ""]
    status: Int[Array, ""]
    accepted: Bool[Array, ""]
    triplet: Int[Array, ""]


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")


def solve(
    camera: Float[Array, "3 4"],
    model: Float[Array, "n 3"],
    image: Float[Array, "n 2"],
    mask: Bool[Array, " n"] | None = None,
    *,
    method: str = "mixed",
    threshold: float | None = None,
    rel_threshold: float = 0.01,
    min_area: float = 40.0,
    collinear_tol: float = 5e-3,
    linear_iterations: int = 5,
    nonlinear_budget: int | None = 32,
    max_steps: int = 50,
    max_triplets: int | None = 2000,
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
    - `method`: `"mixed"` (default), `"three_point"`, `"linear"` or `"nonlinear"` (the last
      two started from every triplet's three-point pose, as in the paper's experiment).
    - `threshold`: acceptance threshold on Eq. 8 (px); `None`: adaptive, within
      `rel_threshold` of the best converged error.
    - `min_area`, `collinear_tol`: degenerate-triplet tests (px^2; scale-free).
    - `linear_iterations`, `nonlinear_budget`, `max_steps`: see `jaxpose.mixed`.
    - `max_triplets`: above this many triplets (`C(n, 3)`; n = 24 gives 2024) a fixed
      seeded sample of this many is used instead of all (`jaxpose.triplet_indices`).

    **Returns:** a `Solution`. Gradients: the discrete choices (triplet, root, branch)
    carry none; the pose is differentiable through the optimality conditions of Eq. 8 at
    the answer (implicit function theorem), for the three optimising methods.
    """
    _check_method(method)
    obs = observations(camera, model, image, mask)
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    initial = initial_poses(
        jax.lax.stop_gradient(obs),
        min_area=min_area,
        collinear_tol=collinear_tol,
        triplets=triplet_indices(obs.model.shape[0], max_triplets),
    )
    sobs = jax.lax.stop_gradient(obs)
    usable = initial.status == Status.OK
    if method == "three_point":
        error, status = initial.error, jnp.where(usable, Status.OK, initial.status)
        poses = initial.pose
    elif method == "mixed":
        res = mixed_from_initial(
            sobs,
            initial,
            threshold=threshold,
            rel_threshold=rel_threshold,
            linear_iterations=linear_iterations,
            nonlinear_budget=nonlinear_budget,
            max_steps=max_steps,
        )
        poses, error, status = res.pose, res.error, res.status
    else:
        if method == "linear":
            run = jax.vmap(lambda R, t: linear(sobs, Pose(R, t), iterations=linear_iterations))
        else:
            run = jax.vmap(lambda R, t: nonlinear(sobs, Pose(R, t), max_steps=max_steps))
        out = run(initial.pose.R, initial.pose.t)
        status = jnp.where(usable, out.status, initial.status)
        error = jnp.where(usable, out.error, big)
        converged = status == Status.OK
        if threshold is None:
            best = jnp.min(jnp.where(converged, error, big))
            thr = jnp.where(best < big, best * (1 + rel_threshold), big)
        else:
            thr = jnp.asarray(threshold, dtype)
        status = jnp.where(converged & (error >= thr), Status.REJECTED, status)
        poses = out.pose
    if method == "three_point" and threshold is not None:
        status = jnp.where((status == Status.OK) & (error >= threshold), Status.REJECTED, status)
    index, accepted = best_triplet(error, status)
    pose = Pose(poses.R[index], poses.t[index])
    pose = jax.tree.map(lambda a, b: jnp.where(accepted, a, b), pose, Pose.identity(dtype))
    if method != "three_point":
        pose = _polish(obs, pose, accepted)
    return Solution(
        pose=pose,
        error=jnp.where(accepted, error[index], jnp.where(error[index] < big, error[index], 0)),
        pose_error=pose_error(obs.camera, pose.R, pose.t, obs.model, obs.image, obs.mask),
        status=status[index].astype(jnp.int32),
        accepted=accepted,
        triplet=index.astype(jnp.int32),
    )


def _polish(obs, pose: Pose, accepted) -> Pose:
    """Attach implicit gradients: one Levenberg-Marquardt solve from the (converged,
    gradient-free) answer; optimistix differentiates its optimum by the implicit function
    theorem. The value is the answer's own (to solver tolerance)."""
    start = jax.lax.stop_gradient(pose)
    refined = nonlinear(obs, start, max_steps=8).pose
    delta = jax.tree.map(lambda a, b: a - jax.lax.stop_gradient(a), refined, start)
    # Value: the answer itself; derivative: the implicit one (zero when not accepted).
    return jax.tree.map(lambda s, d: s + jnp.where(accepted, d, 0), start, delta)


# --------------------------------------------------------------------------- cv2-style


@functools.partial(jax.jit, static_argnames=("method",))
def _solve_opencv(K, obj, img, method):
    C = camera_matrix(K)
    sol = solve(C, obj, img, method=method)
    return sol.accepted, matrix_to_rotvec(sol.pose.R), sol.pose.t


_batched_opencv = jax.jit(
    jax.vmap(_solve_opencv.__wrapped__, in_axes=(None, 0, 0, None)), static_argnames=("method",)
)


def _prepare(object_points, image_points, camera_matrix_, dist_coeffs, batched: bool):
    K = as_intrinsics(camera_matrix_, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    if not batched:
        obj = as_points(object_points, "object_points", 3, min_count=3)
        img = as_points(image_points, "image_points", 2, min_count=3)
        as_matching(obj, img)
        return K, obj, undistort_pixels(img, K, dist)
    img = np.asarray(image_points)
    if img.ndim != 3 or img.shape[-1] != 2:
        raise ValueError(f"image_points must have shape (B, n, 2), got {img.shape}")
    B, n = img.shape[:2]
    img = np.stack([as_points(x, "image_points", 2, min_count=3) for x in img])
    obj = np.asarray(object_points)
    if obj.ndim == 2:
        obj = np.broadcast_to(as_points(obj, "object_points", 3, min_count=3), (B, *obj.shape))
    elif obj.ndim == 3 and obj.shape[0] == B:
        obj = np.stack([as_points(x, "object_points", 3, min_count=3) for x in obj])
    else:
        raise ValueError(
            f"object_points must have shape (n, 3) or (B, n, 3) with B = {B}, got {obj.shape}"
        )
    if obj.shape[1] != n:
        raise ValueError(
            f"object_points has {obj.shape[1]} points per problem but image_points has {n}"
        )
    if dist is not None:
        img = np.stack([undistort_pixels(x, K, dist) for x in img])
    return K, obj, img


def solve_pnp(object_points, image_points, camera_matrix, dist_coeffs=None, *, method="mixed"):
    """Drop-in for `cv2.solvePnP`: the pose of the object in the camera frame.

    Same conventions and shapes as OpenCV (numpy in and out): `object_points` `(n, 3)`
    (or `(n, 1, 3)`), `image_points` `(n, 2)`, `camera_matrix` `K` `(3, 3)`, optional
    `dist_coeffs` (removed first with `cv2.undistortPoints`). Computes in float64.

    **Returns:** `(ok, rvec, tvec)` with `rvec`, `tvec` of shape `(3, 1)`: `x_cam =
    Rodrigues(rvec) X + tvec`. `ok` is False (with finite placeholders) when no pose is
    accepted. `method`: see `jaxpose.solve`.
    """
    _check_method(method)
    K, obj, img = _prepare(object_points, image_points, camera_matrix, dist_coeffs, False)
    with jax.enable_x64(True):
        ok, rvec, tvec = _solve_opencv(
            jnp.asarray(K, jnp.float64),
            jnp.asarray(obj, jnp.float64),
            jnp.asarray(img, jnp.float64),
            method,
        )
        ok, rvec, tvec = bool(ok), np.asarray(rvec, np.float64), np.asarray(tvec, np.float64)
    return ok, rvec.reshape(3, 1), tvec.reshape(3, 1)


def solve_pnp_batch(
    object_points, image_points, camera_matrix, dist_coeffs=None, *, method="mixed"
):
    """`B` independent problems of equal `n` in one compiled call (float64).

    **Arguments:** `object_points` `(B, n, 3)` or shared `(n, 3)`; `image_points`
    `(B, n, 2)`; one `camera_matrix` and `dist_coeffs` for all.

    **Returns:** `(ok (B,), rvecs (B, 3), tvecs (B, 3))`, OpenCV's conventions.
    """
    _check_method(method)
    K, obj, img = _prepare(object_points, image_points, camera_matrix, dist_coeffs, True)
    with jax.enable_x64(True):
        ok, rvecs, tvecs = _batched_opencv(
            jnp.asarray(K, jnp.float64),
            jnp.asarray(obj, jnp.float64),
            jnp.asarray(img, jnp.float64),
            method,
        )
        return np.asarray(ok), np.asarray(rvecs, np.float64), np.asarray(tvecs, np.float64)
