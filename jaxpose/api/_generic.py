"""Every distinct local minimum of Eq. 8 that jaxpose finds, sorted by reprojection error:
`minima` (JAX-native, beside `jaxpose.solve`'s `Solution`) and `solve_pnp_generic` (the
drop-in for `cv2.solvePnPGeneric`, in OpenCV's conventions).

The first is the answer. The others come from the starts of
`jaxpose.strategy.local_minima`, refined each to its own local minimum in one batched
program (`_minima_program`, one per bucket of points, shared by both entry points): for a
coplanar model the answer's planar partner and the two poses of the plane's homography
(IPPE's two, `jaxpose.strategy.planar_poses`), and for any model the best-scored distinct
three-point roots of the answer's triplets. A minimum is kept when its run is accepted
and it is distinct from those kept before it.
"""

from __future__ import annotations

from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jax.core import Tracer
from jaxtyping import ArrayLike, Bool, Real

from ..geometry import Pose, check_problem, no_type_check
from ..strategy import (
    SAME_MINIMUM,
    TRACED,
    Minima,
    Options,
    Solution,
    local_minima,
    rank_minima,
    resolve,
    split_values,
    with_values,
)
from ._pnp import answer_opencv, opencv_problem, refine_opencv
from ._programs import bucket_points, program
from ._stored import values_only

__all__ = ["minima", "solve_pnp_generic"]


def _minima_program(values, camera, model, image, mask, R, t, options: Options) -> Minima:
    """`local_minima` of one problem whose answer is `Pose(R, t)`, `options` a static key
    and `values` its traced values (`jaxpose.strategy.split_values`): the stored program
    of `minima` and `solve_pnp_generic` (one per bucket of points)."""
    options = with_values(options, values)
    return local_minima(camera, model, image, mask, Pose(R, t), options)


_minima_jitted = jax.jit(_minima_program, static_argnames=("options",))


def _check_solution(solution: object) -> Solution:
    """`solution` checked: a `Solution` of one problem (`R (3, 3)`, `t (3,)`); a
    `ValueError` naming `solution` otherwise."""
    if not isinstance(solution, Solution):
        raise ValueError(f"solution must be a jaxpose.Solution, got {type(solution).__name__}")
    pose = solution.pose
    if not isinstance(pose, Pose):
        raise ValueError("solution.pose must be a jaxpose.Pose")
    for name, x, shape in (
        ("pose.R", pose.R, (3, 3)),
        ("pose.t", pose.t, (3,)),
        ("error", solution.error, ()),
        ("accepted", solution.accepted, ()),
    ):
        got = tuple(getattr(x, "shape", np.shape(x)))
        if got != shape:
            raise ValueError(
                f"solution.{name} must have shape {shape} (one problem: vmap `minima` for "
                f"a batch), got {got}"
            )
    return solution


def _no_minima(like: Solution) -> Minima:
    """`local_minima`'s result with no start (`method="three_point"`): no slot."""
    dtype = jnp.result_type(like.pose.t)
    pose = Pose(jnp.zeros((0, 3, 3), dtype), jnp.zeros((0, 3), dtype))
    return Minima(pose, jnp.zeros(0, dtype), jnp.zeros(0, bool))


# The entry points check their arguments themselves (`check_problem`: a `ValueError`
# naming the argument), so no run-time type check comes before theirs.
@no_type_check
def minima(
    solution: Solution,
    camera: Real[ArrayLike, "3 4"],
    model: Real[ArrayLike, "n 3"],
    image: Real[ArrayLike, "n 2"],
    mask: Bool[ArrayLike, " n"] | None = None,
    *,
    options: Options | None = None,
    **changes: Any,
) -> Minima:
    """Every distinct local minimum of Eq. 8 found for one problem, its answer among them,
    sorted by reprojection error: what `solve_pnp_generic` returns, for `jaxpose.solve`'s
    `Solution` (opt-in: `solve` itself does no more work for it).

    The other minima are those of `jaxpose.strategy.local_minima` (module docstring):
    for a coplanar model its planar partner and IPPE's two poses, for any model the
    best distinct three-point roots, each refined to its local minimum of Eq. 8, checked
    to be one (positive definite Hessian, no Newton step) and kept when distinct from
    the answer and from those before it (`SAME_MINIMUM`). `method="three_point"`: the
    answer alone.

    **Arguments:** `solution`, the `Solution` of `jaxpose.solve(camera, model, image,
    mask, options=options)`; the problem and `options` (`**changes`) as given to it.

    **Returns:** a `jaxpose.strategy.Minima` of fixed shapes (`S = 4 + MINIMA_ROOTS`
    slots; `1` with `method="three_point"`): `pose` (`R (S, 3, 3)`, `t (S, 3)`, model to
    world), `error` (Eq. 8, px) and `found`, the slots holding a minimum first (the
    answer among them, where it was accepted; none where it was not), by increasing
    error, then placeholders (identity pose, error 0): never a NaN. `found.sum()` is
    `solve_pnp_generic`'s `count` for the same problem without distortion.

    Pure, for ONE problem: composes with `jax.jit` and `jax.vmap` (batch `solution` and
    the arrays); under `jax.grad` each minimum carries the implicit derivative of its
    own optimality conditions, as `solve`'s answer does (`derivative=True`). A plain
    call runs a stored program, one per bucket of points (values only).
    """
    options = resolve(options, changes)
    solution = _check_solution(solution)
    check_problem(camera, model, image, mask)
    if options.method == "three_point":
        return rank_minima(solution, _no_minima(solution))
    n = np.shape(model)[0]
    arrays = (camera, model, image, mask, *jax.tree.leaves(solution))
    traced = any(isinstance(x, Tracer) for x in arrays)
    values_traced = any(isinstance(getattr(options, f), Tracer) for f in TRACED)
    if values_traced:
        mask = jnp.ones(n, bool) if mask is None else jnp.asarray(mask, bool)
        local = local_minima(camera, model, image, mask, solution.pose, options)
    elif traced:
        mask = jnp.ones(n, bool) if mask is None else jnp.asarray(mask, bool)
        key, values = split_values(options)
        R, t = solution.pose
        local = _minima_jitted(values, camera, model, image, mask, R, t, options=key)
    else:
        R, t = solution.pose
        local = _stored_minima(camera, model, image, mask, R, t, options)
    return rank_minima(solution, local)


def _stored_minima(camera, model, image, mask, R, t, options: Options) -> Minima:
    """`local_minima` of the problem whose answer is `Pose(R, t)`, on concrete inputs
    through its stored program: the points padded to their bucket (`bucket_points`, the
    padding repeating the first match, masked out), values only (`derivative=False`)."""
    camera, model, image = (np.asarray(x) for x in (camera, model, image))
    dtype = jnp.result_type(float, camera.dtype, model.dtype, image.dtype)
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))
    n = model.shape[0]
    mask = np.ones(n, bool) if mask is None else np.asarray(mask, bool)
    size = bucket_points(n)

    def points(x):
        fill = np.zeros((size - n, *x.shape[1:]), x.dtype)
        if x.dtype != np.bool_:
            fill[:] = x[:1]
        return np.concatenate([x, fill])

    model, image, mask = (points(x) for x in (model, image, mask))
    key, values = split_values(values_only(options))
    args = (values, camera, model, image, mask, R, t)
    args = tuple(np.asarray(a, dtype) if a is not mask else a for a in args)
    return program(_minima_program, key)(*args)


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether two poses `(rvec, tvec)` are one local minimum (`SAME_MINIMUM`)."""
    Ra, Rb = cv2.Rodrigues(a[0])[0], cv2.Rodrigues(b[0])[0]
    angle = np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))
    scale = max(np.linalg.norm(a[1]), np.linalg.norm(b[1]), np.finfo(float).tiny)
    return bool(angle < SAME_MINIMUM and np.linalg.norm(a[1] - b[1]) < SAME_MINIMUM * scale)


@no_type_check
def solve_pnp_generic(
    object_points: npt.ArrayLike,
    image_points: npt.ArrayLike,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
    rvec: npt.ArrayLike | None = None,
    tvec: npt.ArrayLike | None = None,
    use_extrinsic_guess: bool = False,
    *,
    options: Options | None = None,
    **changes: Any,
) -> tuple[int, tuple[np.ndarray, ...], tuple[np.ndarray, ...], np.ndarray]:
    """Drop-in for `cv2.solvePnPGeneric`: every distinct local minimum found, best first.

    Arguments as `solve_pnp` (OpenCV's, in its order; `options`, `**changes` as
    `jaxpose.solve`). The first pose found is `solve_pnp`'s answer; the others are the
    distinct local minima of Eq. 8 reached from the starts of
    `jaxpose.strategy.local_minima` (module docstring; with `dist_coeffs` each is then
    refined in the image, as the answer is; two poses within `SAME_MINIMUM` are one).
    For a coplanar model they hold the poses of `cv2.solvePnPGeneric(...,
    flags=cv2.SOLVEPNP_IPPE)` refined to their minima (on all of 1,000 planar problems,
    `benchmarks/opencv_cases.py`), and for four matches the refined P3P roots of
    `cv2.solvePnPGeneric(..., flags=cv2.SOLVEPNP_P3P)` that are local minima.
    `method="three_point"`: the answer alone.

    **Returns:** `(count, rvecs, tvecs, reprojection_errors)` as OpenCV's: `count` the
    number of poses (`0` when `solve_pnp` accepts none), `rvecs`, `tvecs` tuples of
    `(3, 1)` arrays (`x_cam = Rodrigues(rvec) X + tvec`), `reprojection_errors` `(count,
    1)` float64, OpenCV's RMSE `||projected - image|| / sqrt(2 n)` over the given pixels
    (Eq. 8 divided by `sqrt(2)`), in increasing order.
    """
    problem = opencv_problem(
        object_points,
        image_points,
        camera_matrix,
        dist_coeffs,
        rvec,
        tvec,
        use_extrinsic_guess,
        options,
        changes,
    )
    out = answer_opencv(problem)
    if not out[0]:
        return 0, (), (), np.zeros((0, 1))
    options, K, n = problem.options, problem.K, problem.count
    poses = [(out[1:4].reshape(3, 1).copy(), out[4:7].reshape(3, 1).copy())]
    if options.method != "three_point":
        camera = np.concatenate([K, np.zeros((3, 1))], axis=1)
        R = np.asarray(cv2.Rodrigues(out[1:4])[0])
        with jax.enable_x64(True):
            p = problem
            local = _stored_minima(camera, p.obj, p.img, p.mask, R, out[4:7], options)
            R, t, found = (np.asarray(x, np.float64) for x in (*local.pose, local.found))
        for Ri, ti in zip(R[found > 0.5], t[found > 0.5], strict=True):
            row = np.concatenate([cv2.Rodrigues(Ri)[0].ravel(), ti])
            if problem.dist is not None:
                row = refine_opencv(problem, row[:3], row[3:])
            other = (row[:3].reshape(3, 1).copy(), row[3:].reshape(3, 1).copy())
            if np.all(np.isfinite(row)) and not any(_same(p, other) for p in poses):
                poses.append(other)
    obj, raw = problem.obj[:n], problem.raw[:n]
    errors = []
    for rv, tv in poses:
        proj = cv2.projectPoints(obj, rv, tv, K, problem.dist)[0].reshape(-1, 2)
        errors.append(np.linalg.norm(proj - raw) / np.sqrt(2 * n))
    order = np.argsort(errors, kind="stable")
    rvecs = tuple(poses[i][0] for i in order)
    tvecs = tuple(poses[i][1] for i in order)
    return len(poses), rvecs, tvecs, np.asarray(errors, np.float64)[order].reshape(-1, 1)
