"""Drop-in for `cv2.solvePnPGeneric`: every distinct local minimum of Eq. 8 that jaxpose
finds, sorted by reprojection error, in OpenCV's conventions.

The first is `solve_pnp`'s answer. The others come from the starts of
`jaxpose.strategy.local_minima`, refined each to its own local minimum in one batched
program (`_minima_opencv`): for a coplanar model the answer's planar partner and the two
poses of the plane's homography (IPPE's two, `jaxpose.strategy.planar_poses`), and for
any model the best-scored distinct three-point roots of the answer's triplets. A minimum
is kept when its run is accepted and it is distinct from those kept before it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

from ..geometry import Pose, camera_matrix, matrix_to_rotvec, no_type_check, rotvec_to_matrix
from ..strategy import SAME_MINIMUM, Options, local_minima, split_values, with_values
from ._pnp import _pack, answer_opencv, opencv_problem, refine_opencv
from ._programs import program

__all__ = ["solve_pnp_generic"]


def _minima_opencv(packed, options: Options):
    """The other local minima of the problem whose answer is `(rvec, tvec)` (the program
    of `solve_pnp_generic`; `jaxpose.strategy.local_minima`): `packed` the traced values
    (4), `rvec`, `tvec`, then `_pack`'s vector. Returns `(found, rvec, tvec)` of each
    start, one row of 7 each (`found` 1 for a distinct minimum, 0 for a placeholder)."""
    answer = Pose(rotvec_to_matrix(packed[4:7]), packed[7:10])
    options = with_values(options, packed[:4])
    packed = packed[10:]
    n = (packed.shape[0] - 9) // 6
    K = packed[:9].reshape(3, 3)
    obj = packed[9 : 9 + 3 * n].reshape(n, 3)
    img = packed[9 + 3 * n : 9 + 5 * n].reshape(n, 2)
    mask = packed[9 + 5 * n :] > 0.5
    minima = local_minima(camera_matrix(K), obj, img, mask, answer, options)
    found = minima.found.astype(packed.dtype)[:, None]
    rvecs = jax.vmap(matrix_to_rotvec)(minima.pose.R)
    return jnp.concatenate([found, rvecs, minima.pose.t], axis=1)


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
        key, values = split_values(dataclasses.replace(options, derivative=False))
        head = np.concatenate([values, out[1:7]])
        packed = np.concatenate([head, _pack(K, problem.obj, problem.img, problem.mask)])
        with jax.enable_x64(True):
            rows = np.array(program(_minima_opencv, key)(packed))
        for row in rows[rows[:, 0] > 0.5]:
            if problem.dist is not None:
                row[1:] = refine_opencv(problem, row[1:4], row[4:7])
            other = (row[1:4].reshape(3, 1).copy(), row[4:7].reshape(3, 1).copy())
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
