"""The public entry points: `solve` (JAX-native) and `solve_pnp` / `solve_pnp_batch`
(drop-in for `cv2.solvePnP`, numpy in and out)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry._camera import camera_matrix, undistort_pixels
from ..geometry._errors import pose_error
from ..geometry._pose import Observations, Pose, observations, transform
from ..geometry._rotation import matrix_to_rotvec
from ..geometry._validate import (
    as_dist_coeffs,
    as_intrinsics,
    as_matching,
    as_points,
    check_problem,
)
from ..solvers._linear import linear
from ..solvers._nonlinear import nonlinear
from ..solvers._residuals import in_front, pixel_residuals, rms, rounding_level
from ..solvers._status import Status
from ..strategy._covariance import _chart_at, _chart_pose, _chart_residuals, _symmetric_pinv
from ..strategy._mixed import (
    CHUNK,
    best_triplet,
    initial_poses,
    mixed_from_initial,
    mixed_from_initial_batch,
    spread_triplets,
    triplet_indices,
)

__all__ = ["METHODS", "Solution", "solve", "solve_many", "solve_pnp", "solve_pnp_batch"]

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


def _check_budget(triplet_budget: int | None) -> None:
    if triplet_budget is None:
        return
    if isinstance(triplet_budget, bool) or not isinstance(triplet_budget, (int, np.integer)):
        raise ValueError(f"triplet_budget must be a positive int or None, got {triplet_budget!r}")
    if triplet_budget < 1:
        raise ValueError(f"triplet_budget must be >= 1, got {triplet_budget}")


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
    triplet_budget: int | None = None,
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
    - `triplet_budget`: solve only this many triplets, the ones with the largest image
      triangles (`jaxpose.spread_triplets`): the fast path for large batches of easy
      problems (`None`: all of them).

    **Returns:** a `Solution`.

    **Gradients** (`jax.grad`, `jax.jacfwd`, `jax.jacrev`, under `jit` and `vmap`): for
    the three optimising methods, `pose` (and `error`, `pose_error`) are differentiable
    with respect to `camera`, `model` and `image` through the optimality conditions of
    Eq. 8 at the answer (implicit function theorem, the full Hessian: exact first
    derivatives, not an unrolled iteration; see `_polish`). The discrete choices (triplet,
    root, branch, acceptance) carry none. A problem with no accepted pose returns its
    placeholder with a zero gradient; `method="three_point"` gives no gradient to the pose.
    """
    _check_method(method)
    _check_budget(triplet_budget)
    check_problem(camera, model, image, mask)
    camera, model, image, finite = _finite_inputs(camera, model, image)
    obs = observations(camera, model, image, mask)
    rows, initial = _initial(obs, min_area, collinear_tol, max_triplets, triplet_budget)
    sobs = jax.lax.stop_gradient(obs)
    if method == "mixed":
        res = mixed_from_initial(
            sobs,
            initial,
            threshold=threshold,
            rel_threshold=rel_threshold,
            linear_iterations=linear_iterations,
            nonlinear_budget=nonlinear_budget,
            max_steps=max_steps,
        )
        found = (res.pose, res.error, res.status)
    else:
        found = _per_triplet(
            method, sobs, initial, threshold, rel_threshold, linear_iterations, max_steps
        )
    return _not_finite(_finish(method, obs, rows, *found), finite)


def solve_many(
    camera: Float[Array, "3 4"] | Float[Array, "B 3 4"],
    model: Float[Array, "B n 3"],
    image: Float[Array, "B n 2"],
    mask: Bool[Array, "B n"] | None = None,
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
    triplet_budget: int | None = None,
) -> Solution:
    """`solve` for a batch of `B` problems of equal `n`: the same answers as
    `jax.vmap(solve)`, computed batch-first. `camera` is `(3, 4)`, one camera for every
    problem (`jax.vmap(solve, in_axes=(None, 0, 0, 0))`), or `(B, 3, 4)`, one per problem.

    The difference is the cost: under a plain `vmap`, every problem pays for the mixed
    algorithm's full Levenberg-Marquardt buffer (`vmap` turns its "only when needed" into
    "always"); here the triplets of the whole batch that need it share one buffer
    (`jaxpose.mixed_from_initial_batch`), and the cheap steps run in cache-sized passes.
    Arguments as `solve` (`model`, `image`, `mask` with a leading batch axis); pure, for
    `jit` and `grad`.
    """
    _check_method(method)
    _check_budget(triplet_budget)
    _check_many(camera, model, image, mask)
    B = model.shape[0]
    shared = None if jnp.ndim(camera) == 2 else 0
    camera, model, image, finite = jax.vmap(_finite_inputs, in_axes=(shared, 0, 0))(
        camera, model, image
    )
    if mask is None:
        # (The barrier keeps XLA from constant-folding the all-true mask through the
        # triplet gathers, which costs seconds of compile time for nothing.)
        mask = jax.lax.optimization_barrier(jnp.ones(model.shape[:2], dtype=bool))
    obs = jax.vmap(observations)(camera, model, image, mask)
    T = _triplet_count(model.shape[1], max_triplets, triplet_budget)

    def initial_of(o):
        return _initial(o, min_area, collinear_tol, max_triplets, triplet_budget)

    rows, initial = jax.lax.map(initial_of, obs, batch_size=max(1, min(B, CHUNK // T)))
    sobs = jax.lax.stop_gradient(obs)
    if method == "mixed":
        res = mixed_from_initial_batch(
            sobs,
            initial,
            threshold=threshold,
            rel_threshold=rel_threshold,
            linear_iterations=linear_iterations,
            nonlinear_budget=nonlinear_budget,
            max_steps=max_steps,
        )
        found = (res.pose, res.error, res.status)
    else:
        found = jax.vmap(
            lambda o, i: _per_triplet(
                method, o, i, threshold, rel_threshold, linear_iterations, max_steps
            )
        )(sobs, initial)
    return jax.vmap(_not_finite)(
        jax.vmap(functools.partial(_finish, method))(obs, rows, *found), finite
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
        triplet=pick(sol.triplet, 0),
    )


def _triplet_count(n: int, max_triplets: int | None, triplet_budget: int | None) -> int:
    T = triplet_indices(n, max_triplets).shape[0]
    return T if triplet_budget is None else min(T, triplet_budget)


def _initial(obs: Observations, min_area, collinear_tol, max_triplets, triplet_budget):
    """Step 1: the triplets used (rows of `triplet_indices(n, max_triplets)`) and their
    best three-point roots (no gradient)."""
    sobs = jax.lax.stop_gradient(obs)
    candidates = triplet_indices(obs.model.shape[0], max_triplets)
    rows = jnp.arange(candidates.shape[0])
    triplets = candidates
    if triplet_budget is not None and triplet_budget < candidates.shape[0]:
        rows, triplets = spread_triplets(sobs, candidates, triplet_budget)
    initial = initial_poses(sobs, min_area=min_area, collinear_tol=collinear_tol, triplets=triplets)
    return rows, initial


def _per_triplet(method, sobs, initial, threshold, rel_threshold, linear_iterations, max_steps):
    """Every triplet's pose, error and status for the methods other than mixed."""
    dtype = sobs.camera.dtype
    big = jnp.finfo(dtype).max
    usable = initial.status == Status.OK
    if method == "three_point":
        # The three-point solver checks only its own triplet's depths: a pose that puts
        # other used matches behind the camera is reported, not accepted.
        front = jax.vmap(lambda R, t: in_front(transform(Pose(R, t), sobs.model), sobs))(
            initial.pose.R, initial.pose.t
        )
        error = initial.error
        status = jnp.where(
            usable, jnp.where(front, Status.OK, Status.BEHIND_CAMERA), initial.status
        )
        if threshold is not None:
            reject = (status == Status.OK) & (error >= threshold)
            status = jnp.where(reject, Status.REJECTED, status)
        return initial.pose, error, status
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
        floor = rounding_level(sobs)
        thr = jnp.where(best < big, jnp.maximum(best * (1 + rel_threshold), floor), big)
    else:
        thr = jnp.asarray(threshold, dtype)
    status = jnp.where(converged & (error >= thr), Status.REJECTED, status)
    return out.pose, error, status


def _finish(method, obs: Observations, rows, poses: Pose, error, status) -> Solution:
    """The answer from every triplet's outcome: the best accepted, polished (with the
    implicit derivative attached) for the optimising methods."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    index, accepted = best_triplet(error, status)
    pose = Pose(poses.R[index], poses.t[index])
    pose = jax.tree.map(lambda a, b: jnp.where(accepted, a, b), pose, Pose.identity(dtype))
    error = jnp.where(accepted, error[index], jnp.where(error[index] < big, error[index], 0))
    if method != "three_point":
        pose = _polish(obs, pose, accepted)
        final = rms(pixel_residuals(transform(pose, obs.model), obs), obs.mask)
        error = jnp.where(accepted, final, error)
    return Solution(
        pose=pose,
        error=error,
        pose_error=pose_error(obs.camera, pose.R, pose.t, obs.model, obs.image, obs.mask),
        status=status[index].astype(jnp.int32),
        accepted=accepted,
        triplet=rows[index].astype(jnp.int32),
    )


def _polish(obs: Observations, pose: Pose, accepted: Bool[Array, ""]) -> Pose:
    """The answer, polished by Newton steps, with the implicit derivative attached.

    In the chart `xi = (w, u)` around the (gradient-free) answer `(R^, t^)` of
    `jaxpose._covariance` (`R = exp(hat(w)) R^`, rotation about the centroid of the world
    points, translation scaled by their RMS radius), let `f(xi, theta) = |r(xi, theta)|^2 / 2`
    be Eq. 8's cost, `theta` the camera, model and image, `g = df/dxi`, `H = d^2f/dxi^2`
    (the full Hessian, not Gauss-Newton's). At the optimum `g(0, theta) = 0`, so by the
    implicit function theorem

        dxi*/dtheta = -H^-1 dg/dtheta.

    That is the derivative of the Newton step `xi = -H^-1 g(0, theta)` with `H` held
    constant. Two Newton steps are taken from the answer (each only when `H` is positive
    definite and the step is below `1e-3`, rad and object radii: at a converged answer they
    move the pose by rounding, and they finish a pose that a solver left within its
    tolerance, e.g. `1e-6` from Levenberg-Marquardt), the second carrying exactly the
    implicit derivative. A singular `H` (a pose the matches do not determine) uses the
    pseudo-inverse. Not accepted: the answer with a zero derivative. First derivatives
    only (`H` carries none).
    """
    sobs = jax.lax.stop_gradient(obs)
    start = _newton(sobs, jax.lax.stop_gradient(pose), accepted)
    return _newton(obs, jax.lax.stop_gradient(start), accepted)


def _newton(obs: Observations, pose: Pose, accepted: Bool[Array, ""]) -> Pose:
    """One guarded Newton step of Eq. 8 from `pose` (no derivative w.r.t. `pose`); its
    derivative w.r.t. `obs` is the implicit one (see `_polish`)."""
    sobs = jax.lax.stop_gradient(obs)
    chart = _chart_at(pose, sobs)
    zero = jnp.zeros(6, pose.t.dtype)

    def cost(xi, o):
        r = _chart_residuals(xi, chart, o)
        return 0.5 * jnp.sum(r * r)

    g = jax.grad(cost)(zero, obs)
    H = jax.hessian(cost)(zero, sobs)
    H_inv, _, positive = _symmetric_pinv(H)
    step = -(H_inv @ g)
    value = jax.lax.stop_gradient(step)
    # Taken only within the quadratic convergence region of a minimum: H positive definite
    # (so the step descends) and a step below 1e-3 (rad, object radii). The cost itself is
    # no judge there: its rounding (~eps times the plane terms, not the cost) exceeds the
    # decrease of a 1e-11 step.
    local = jnp.all(jnp.abs(value) < 1e-3) & jnp.all(jnp.isfinite(value))
    xi = jnp.where(positive & local, value, 0) + (step - value)
    return _chart_pose(jnp.where(accepted, xi, 0), chart)


# --------------------------------------------------------------------------- cv2-style


@functools.partial(jax.jit, static_argnames=("method", "triplet_budget"))
def _solve_opencv(K, obj, img, method, triplet_budget=None):
    C = camera_matrix(K)
    sol = solve(C, obj, img, method=method, triplet_budget=triplet_budget)
    return sol.accepted, matrix_to_rotvec(sol.pose.R), sol.pose.t


@functools.partial(jax.jit, static_argnames=("method", "triplet_budget"))
def _batched_opencv(K, obj, img, method, triplet_budget=None):
    sol = solve_many(camera_matrix(K), obj, img, method=method, triplet_budget=triplet_budget)
    return sol.accepted, jax.vmap(matrix_to_rotvec)(sol.pose.R), sol.pose.t


def _read_array(x, name: str) -> np.ndarray:
    """`np.asarray(x)`, with numpy's complaints (ragged lists and the like) naming `name`."""
    if x is None:
        raise ValueError(f"{name} is required, got None")
    try:
        return np.asarray(x)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{name} could not be read as an array: {exc}") from exc


def _prepare(object_points, image_points, camera_matrix_, dist_coeffs, batched: bool):
    K = as_intrinsics(camera_matrix_, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    if not batched:
        obj = as_points(object_points, "object_points", 3, min_count=3)
        img = as_points(image_points, "image_points", 2, min_count=3)
        as_matching(obj, img)
        return K, obj, undistort_pixels(img, K, dist)
    img = _read_array(image_points, "image_points")
    if img.ndim != 3 or img.shape[-1] != 2:
        raise ValueError(f"image_points must have shape (B, n, 2), got {img.shape}")
    B, n = img.shape[:2]
    if B == 0:
        raise ValueError("image_points must hold at least one problem, got an empty batch")
    img = np.stack([as_points(x, "image_points", 2, min_count=3) for x in img])
    obj = _read_array(object_points, "object_points")
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


def solve_pnp(
    object_points,
    image_points,
    camera_matrix,
    dist_coeffs=None,
    *,
    method="mixed",
    triplet_budget=None,
):
    """Drop-in for `cv2.solvePnP`: the pose of the object in the camera frame.

    Same conventions and shapes as OpenCV (numpy in and out): `object_points` `(n, 3)`
    (or `(n, 1, 3)`), `image_points` `(n, 2)`, `camera_matrix` `K` `(3, 3)`, optional
    `dist_coeffs` (removed first with `cv2.undistortPoints`). Computes in float64.

    **Returns:** `(ok, rvec, tvec)` with `rvec`, `tvec` of shape `(3, 1)`: `x_cam =
    Rodrigues(rvec) X + tvec`. `ok` is False (with finite placeholders) when no pose is
    accepted. `method`, `triplet_budget`: see `jaxpose.solve`.
    """
    _check_method(method)
    _check_budget(triplet_budget)
    K, obj, img = _prepare(object_points, image_points, camera_matrix, dist_coeffs, False)
    with jax.enable_x64(True):
        ok, rvec, tvec = _solve_opencv(
            jnp.asarray(K, jnp.float64),
            jnp.asarray(obj, jnp.float64),
            jnp.asarray(img, jnp.float64),
            method,
            triplet_budget,
        )
        ok, rvec, tvec = bool(ok), np.asarray(rvec, np.float64), np.asarray(tvec, np.float64)
    return ok, rvec.reshape(3, 1), tvec.reshape(3, 1)


def solve_pnp_batch(
    object_points,
    image_points,
    camera_matrix,
    dist_coeffs=None,
    *,
    method="mixed",
    triplet_budget=None,
    chunk_size=None,
    devices=None,
):
    """`B` independent problems of equal `n` in one compiled call (float64).

    **Arguments:** `object_points` `(B, n, 3)` or shared `(n, 3)`; `image_points`
    `(B, n, 2)`; one `camera_matrix` and `dist_coeffs` for all.

    `triplet_budget`: solve only this many well-spread triplets per problem (see
    `jaxpose.solve`); the exhaustive `C(n, 3)` costs `n^3` per problem.

    `chunk_size`: at most this many problems per compiled call (bounded memory; `None`:
    all at once); `devices`: the batch is split over these (`None`: all of
    `jax.devices()`; an int: the first ones); see `jaxpose.run_batched`.

    **Returns:** `(ok (B,), rvecs (B, 3), tvecs (B, 3))`, OpenCV's conventions.
    """
    _check_method(method)
    _check_budget(triplet_budget)
    K, obj, img = _prepare(object_points, image_points, camera_matrix, dist_coeffs, True)
    from ._batch import run_batched

    with jax.enable_x64(True):
        ok, rvecs, tvecs = run_batched(
            _batched_opencv,
            (np.asarray(K, np.float64),),
            (np.asarray(obj, np.float64), np.asarray(img, np.float64)),
            static=(method, triplet_budget),
            chunk_size=chunk_size,
            devices=devices,
        )
        return np.asarray(ok), np.asarray(rvecs, np.float64), np.asarray(tvecs, np.float64)
