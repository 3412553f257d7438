"""Drop-in for `cv2.solvePnPGeneric`: every distinct local minimum of Eq. 8 that jaxpose
finds, sorted by reprojection error, in OpenCV's conventions.

A coplanar model has two poses that image it nearly alike (the planar ambiguity; IPPE's
two solutions): `solve_pnp`'s answer is the better of them (the mixed algorithm refines
the planar partner of its answer and keeps the better, the paper's Section 3 with
`Options.planar_partner`). Here the other one is reported too: the planar partner of the
answer (`jaxpose.strategy.planar_partner`) is refined from where it is by the paper's
small-movement linear method and Levenberg-Marquardt (`jaxpose.solve`'s `initial`), and
kept when it converges to a local minimum distinct from the answer.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

from ..geometry import (
    Pose,
    camera_matrix,
    matrix_to_rotvec,
    no_type_check,
    observations,
    rotvec_to_matrix,
)
from ..strategy import Options, planar_partner, split_values, with_values
from ._pnp import _pack, answer_opencv, opencv_problem, refine_opencv
from ._programs import program
from ._solve import solve

__all__ = ["solve_pnp_generic"]

#: Two local minima closer than this (rotation, rad; translation, relative to its
#: length) are one.
SAME_MINIMUM = 1e-4


def _partner_opencv(packed, options: Options):
    """The planar partner of the pose `(rvec, tvec)`, refined (the program of
    `solve_pnp_generic`): `packed` the traced values (4), `rvec`, `tvec`, then
    `_pack`'s vector. Returns `(ok, rvec, tvec)` as one vector of 7; `ok` False for a
    model that is not coplanar or a partner that does not converge."""
    start = Pose(rotvec_to_matrix(packed[4:7]), packed[7:10])
    options = with_values(options, packed[:4])
    packed = packed[10:]
    n = (packed.shape[0] - 9) // 6
    K = packed[:9].reshape(3, 3)
    obj = packed[9 : 9 + 3 * n].reshape(n, 3)
    img = packed[9 + 3 * n : 9 + 5 * n].reshape(n, 2)
    mask = packed[9 + 5 * n :] > 0.5
    C = camera_matrix(K)
    partner, flat = planar_partner(observations(C, obj, img, mask), start)
    sol = solve(C, obj, img, mask, options=options, initial=partner)
    ok = (flat & sol.accepted).astype(packed.dtype)[None]
    return jnp.concatenate([ok, matrix_to_rotvec(sol.pose.R), sol.pose.t])


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
    `jaxpose.solve`). The first pose is `solve_pnp`'s answer; for a coplanar model the
    second is the other pose of the planar ambiguity (module docstring), refined to its
    own local minimum of Eq. 8, when it converges to one distinct from the first (two
    poses within `SAME_MINIMUM` are one). After refinement these are the poses of
    `cv2.solvePnPGeneric(..., flags=cv2.SOLVEPNP_IPPE)` refined by
    `cv2.solvePnPRefineLM`. A non-coplanar model has one.

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
            out = np.array(program(_partner_opencv, key)(packed))
        if out[0] and problem.dist is not None:
            out[1:] = refine_opencv(problem, out[1:4], out[4:7])
        other = (out[1:4].reshape(3, 1).copy(), out[4:7].reshape(3, 1).copy())
        if out[0] and np.all(np.isfinite(out)) and not _same(poses[0], other):
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
