"""Drop-ins for OpenCV's PnP functions: `solve_pnp` (`cv2.solvePnP`), `solve_pnp_batch`
(many problems in one compiled call) and `solve_pnp_ransac` (`cv2.solvePnPRansac`).

The boundary between numpy and JAX: numpy in and out, OpenCV's conventions (the camera
frame is the world frame, `C = K [I | 0]`; the pose is `rvec, tvec`, object to camera;
`dist_coeffs`: the answer is found on pixels undistorted with `cv2.undistortPoints`, then
refined in the image, where OpenCV measures its error: `jaxpose.geometry.refine_in_image`,
OpenCV's distortion model in JAX), float64 inside whatever the
process's JAX configuration, inputs checked with `ValueError` naming the argument.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

from ..geometry import (
    COEFFICIENTS,
    Pose,
    as_dist_coeffs,
    as_intrinsics,
    as_matching,
    as_point_batch,
    as_points,
    camera_matrix,
    matrix_to_rotvec,
    no_type_check,
    refine_in_image,
    rotvec_to_matrix,
    undistort_pixels,
)
from ..solvers import Status
from ..strategy import (
    Options,
    RobustOptions,
    escalation,
    resolve,
    robust,
    split_values,
    triplet_indices,
    with_values,
)
from ._batch import run_batched
from ._programs import bucket_points, program, stored_jit
from ._solve import solve, solve_many
from ._stored import climb, values_only

__all__ = ["solve_pnp", "solve_pnp_batch", "solve_pnp_ransac"]


def _pack(K: np.ndarray, obj: np.ndarray, img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """One problem as one float64 vector `(9 + 6 n,)`: `K`, the points, the pixels and
    the mask (one transfer to the device instead of four)."""
    parts = (K, obj, img, mask.astype(np.float64))
    return np.concatenate([np.asarray(a, np.float64).ravel() for a in parts])


def _values(options: Options) -> np.ndarray:
    """The traced values of `options` (`jaxpose.strategy.split_values`)."""
    return split_values(options)[1]


def _solve_opencv(packed, options: Options):
    """One problem in OpenCV's conventions (the program of `solve_pnp`): `packed` the
    traced values of the options (`_values`, 4) then `_pack`'s vector; `options` a key
    of `_stages`. Returns `(ok, rvec, tvec)` as one vector of 7 (one transfer back)."""
    options = with_values(options, packed[:4])
    packed = packed[4:]
    n = (packed.shape[0] - 9) // 6
    K = packed[:9].reshape(3, 3)
    obj = packed[9 : 9 + 3 * n].reshape(n, 3)
    img = packed[9 + 3 * n : 9 + 5 * n].reshape(n, 2)
    mask = packed[9 + 5 * n :] > 0.5
    sol = solve(camera_matrix(K), obj, img, mask, options=options)
    ok = sol.accepted.astype(packed.dtype)[None]
    return jnp.concatenate([ok, matrix_to_rotvec(sol.pose.R), sol.pose.t])


def _solve_opencv_from(packed, options: Options):
    """`_solve_opencv` from a given pose (the program of `solve_pnp` with
    `use_extrinsic_guess`): `packed` the traced values (4), `rvec`, `tvec` (6), then
    `_pack`'s vector."""
    start = Pose(rotvec_to_matrix(packed[4:7]), packed[7:10])
    options = with_values(options, packed[:4])
    packed = packed[10:]
    n = (packed.shape[0] - 9) // 6
    K = packed[:9].reshape(3, 3)
    obj = packed[9 : 9 + 3 * n].reshape(n, 3)
    img = packed[9 + 3 * n : 9 + 5 * n].reshape(n, 2)
    mask = packed[9 + 5 * n :] > 0.5
    sol = solve(camera_matrix(K), obj, img, mask, options=options, initial=start)
    ok = sol.accepted.astype(packed.dtype)[None]
    return jnp.concatenate([ok, matrix_to_rotvec(sol.pose.R), sol.pose.t])


def _guess(x, name: str) -> np.ndarray:
    """A `rvec` or `tvec` of `solve_pnp`: 3 finite reals, any of OpenCV's shapes."""
    arr = _read_array(x, name)
    if arr.size != 3 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise ValueError(f"{name} must hold 3 real numbers (shape (3, 1) or (3,)), got {arr.shape}")
    arr = arr.astype(np.float64).reshape(3)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


#: Levenberg-Marquardt steps of the image-space refinement with `dist_coeffs`.
REFINE_STEPS = 30


def _all_coefficients(dist: np.ndarray) -> np.ndarray:
    """OpenCV's coefficients zero-padded to the full model's `COEFFICIENTS` (one program
    for every form)."""
    d = np.zeros(COEFFICIENTS)
    d[: len(dist)] = dist
    return d


def _pack_refine(K, dist, rvec, tvec, obj, raw, mask) -> np.ndarray:
    """The image-space refinement's inputs as one float64 vector: `K` (9), the 14
    coefficients (zero-padded), `rvec`, `tvec`, then as `_pack`."""
    d = _all_coefficients(dist)
    head = np.concatenate([np.asarray(K, np.float64).ravel(), d, rvec, tvec])
    return np.concatenate([head, _pack(np.eye(3), obj, raw, mask)[9:]])


def _refine_opencv(packed, steps: int):
    """`refine_in_image` on `_pack_refine`'s vector (the distortion program of
    `solve_pnp`): the refined `(rvec, tvec)` as one vector of 6."""
    n = (packed.shape[0] - 29) // 6
    K, dist = packed[:9].reshape(3, 3), packed[9:23]
    rvec, tvec, rest = packed[23:26], packed[26:29], packed[29:]
    obj = rest[: 3 * n].reshape(n, 3)
    raw = rest[3 * n : 5 * n].reshape(n, 2)
    mask = rest[5 * n :] > 0.5
    rvec, tvec, _ = refine_in_image(K, dist, obj, raw, mask, rvec, tvec, steps)
    return jnp.concatenate([rvec, tvec])


def _refined_batch(K, dist, rvec, tvec, obj, raw, mask, steps: int):
    """`refine_in_image` over a batch (the distortion program of `solve_pnp_batch`)."""
    one = functools.partial(refine_in_image, iterations=steps)
    rvec, tvec, _ = jax.vmap(one, in_axes=(None, None, 0, 0, 0, 0, 0))(
        K, dist, obj, raw, mask, rvec, tvec
    )
    return rvec, tvec


def _batched_opencv(K, values, obj, img, mask, options: Options):
    """A batch in OpenCV's conventions (the program of `solve_pnp_batch`): `options` a
    key of `_stages`, `values` its traced values (`_values`)."""
    options = with_values(options, values)
    sol = solve_many(camera_matrix(K), obj, img, mask, options=options)
    return sol.accepted, jax.vmap(matrix_to_rotvec)(sol.pose.R), sol.pose.t


def _pad_points(obj: np.ndarray, img: np.ndarray):
    """`(obj, img, mask)` with the point axis (the second to last) padded to its bucket
    (`bucket_points`): padding rows repeat the first point, masked out."""
    n = obj.shape[-2]
    size = bucket_points(n)
    mask = np.zeros((*obj.shape[:-2], size), bool)
    mask[..., :n] = True
    if size == n:
        return obj, img, mask

    def pad(x):
        first = np.broadcast_to(x[..., :1, :], (*x.shape[:-2], size - n, x.shape[-1]))
        return np.concatenate([x, first], axis=-2)

    return pad(obj), pad(img), mask


@functools.lru_cache(maxsize=64)
def _stages(options: Options) -> tuple[Options, ...]:
    """The programs an OpenCV-convention call runs: the rungs of the pipeline's
    `escalation` (the best roots of the spread triplets, of more triplets, the whole
    mixed algorithm), each a program of its own, run only for the problems the rungs
    before it did not settle and compiled when first needed. Values only
    (`derivative=False`: the numpy outputs carry no derivative). Each is a program's key
    (`jaxpose.strategy.split_values`): the thresholds and tolerances are the program's
    arguments (`_values`), so that changing them compiles nothing."""
    rungs = escalation(values_only(options))
    return tuple(split_values(rung)[0] for rung in rungs)


def _read_array(x, name: str) -> np.ndarray:
    """`np.asarray(x)`, with numpy's complaints (ragged lists and the like) naming `name`."""
    if x is None:
        raise ValueError(f"{name} is required, got None")
    try:
        return np.asarray(x)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{name} could not be read as an array: {exc}") from exc


def _prepare(object_points, image_points, camera_matrix_, dist_coeffs, batched: bool):
    """The checked arguments: `(K, dist, obj, raw, img)`, `raw` the pixels as given and
    `img` the same undistorted (`raw` itself without distortion, `dist` then `None`)."""
    K = as_intrinsics(camera_matrix_, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    if not batched:
        obj, img = as_matching(object_points, image_points, min_count=3)
        if dist is None:
            return K, dist, obj, img, img
        return K, dist, obj, img, np.asarray(undistort_pixels(img, K, dist))
    img = as_point_batch(image_points, "image_points", 2, min_count=3)
    B, n = img.shape[:2]
    obj = _read_array(object_points, "object_points")
    if obj.ndim == 2:
        obj = np.broadcast_to(as_points(obj, "object_points", 3, min_count=3), (B, *obj.shape))
    elif obj.ndim == 3 and obj.shape[0] == B:
        obj = as_point_batch(obj, "object_points", 3, min_count=3)
    else:
        raise ValueError(
            f"object_points must have shape (n, 3) or (B, n, 3) with B = {B}, got {obj.shape}"
        )
    if obj.shape[1] != n:
        raise ValueError(
            f"object_points has {obj.shape[1]} points per problem but image_points has {n}"
        )
    if dist is None:
        return K, dist, obj, img, img
    flat = np.asarray(undistort_pixels(img.reshape(-1, 2), K, dist))
    return K, dist, obj, img, flat.reshape(img.shape)


@dataclasses.dataclass(frozen=True)
class OpenCVProblem:
    """One problem's arguments in OpenCV's conventions, checked (`opencv_problem`), in
    float64 with the point axis padded to its bucket (`_pad_points`).

    `options` the resolved `Options`; `guess` the start `(rvec, tvec)` as 6 values when
    `use_extrinsic_guess`, else `None`; `K` `(3, 3)`; `dist` OpenCV's coefficients or
    `None`; `obj` `(m, 3)`; `img` `(m, 2)` the pixels undistorted (`raw` itself without
    distortion); `raw` `(m, 2)` the pixels as given; `mask` `(m,)` the `count` given
    points (the first ones)."""

    options: Options
    guess: np.ndarray | None
    K: np.ndarray
    dist: np.ndarray | None
    obj: np.ndarray
    img: np.ndarray
    raw: np.ndarray
    mask: np.ndarray
    count: int


def opencv_problem(
    object_points,
    image_points,
    camera_matrix_,
    dist_coeffs,
    rvec,
    tvec,
    use_extrinsic_guess,
    options: Options | None,
    changes: dict[str, Any],
) -> OpenCVProblem:
    """The arguments of `cv2.solvePnP`'s signature (`solve_pnp`, `solve_pnp_generic`)
    checked and prepared: a `ValueError` naming the argument, in the order given."""
    options = resolve(options, changes)
    if not isinstance(use_extrinsic_guess, bool | np.bool_):
        raise ValueError(f"use_extrinsic_guess must be a bool, got {use_extrinsic_guess!r}")
    guess = None
    if use_extrinsic_guess:
        guess = np.concatenate([_guess(rvec, "rvec"), _guess(tvec, "tvec")])
    K, dist, obj, raw, img = _prepare(
        object_points, image_points, camera_matrix_, dist_coeffs, False
    )
    count = obj.shape[0]
    obj, raw = np.asarray(obj, np.float64), np.asarray(raw, np.float64)
    _, raw, _ = _pad_points(obj, raw)
    obj, img, mask = _pad_points(obj, np.asarray(img, np.float64))
    K, dist = np.asarray(K, np.float64), None if dist is None else np.asarray(dist, np.float64)
    return OpenCVProblem(options, guess, K, dist, obj, img, raw, mask, count)


def answer_opencv(problem: OpenCVProblem) -> np.ndarray:
    """`solve_pnp`'s answer to a prepared problem: `(ok, rvec, tvec)` as one float64
    vector of 7 (the escalation's rungs, or the start from `guess`, then the refinement
    in the image with `dist`)."""
    options, K, obj, mask = problem.options, problem.K, problem.obj, problem.mask
    rungs = _stages(options)
    with jax.enable_x64(True):
        # (numpy in: one transfer each way, no conversion program to compile on a first
        # call, and no separate `device_put` call)
        packed = np.concatenate([_values(options), _pack(K, obj, problem.img, mask)])
        if problem.guess is not None:
            packed = np.concatenate([packed[:4], problem.guess, packed[4:]])
            key = split_values(values_only(options))[0]
            out = np.array(program(_solve_opencv_from, key)(packed))
            rungs = rungs[:1]
        else:
            out = np.array(program(_solve_opencv, rungs[0])(packed))

        def later(rung, rows):  # (one problem: its vector as a batch of one)
            return np.array(program(_solve_opencv, rung)(packed))[None]

        lifted = out[None]
        climb(lifted, lifted[:, 0] == 0, mask.sum()[None], rungs[1:], later, lambda f: f[:, 0])
        out = lifted[0]
        if problem.dist is not None and out[0] and options.method != "three_point":
            # the pose that minimises the error in the image, as OpenCV's
            out[1:] = refine_opencv(problem, out[1:4], out[4:7])
    return out


def refine_opencv(problem: OpenCVProblem, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """The pose `(rvec, tvec)` refined to least pixel error in the image with the
    problem's `dist` (`jaxpose.geometry.refine_in_image`): `(rvec, tvec)` as 6 values."""
    p = problem
    packed = _pack_refine(p.K, p.dist, rvec, tvec, p.obj, p.raw, p.mask)
    with jax.enable_x64(True):
        return np.asarray(program(_refine_opencv, REFINE_STEPS)(packed))


# The entry points check their arguments themselves (a `ValueError` naming the argument,
# whatever its type), so no run-time type check comes before theirs.
@no_type_check
def solve_pnp(
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
) -> tuple[bool, np.ndarray, np.ndarray]:
    """Drop-in for `cv2.solvePnP`: the pose of the object in the camera frame.

    Same conventions and shapes as OpenCV (numpy in and out): `object_points` `(n, 3)`
    (or `(n, 1, 3)`), `image_points` `(n, 2)`, `camera_matrix` `K` `(3, 3)`, optional
    `dist_coeffs` (4, 5, 8, 12 or 14, OpenCV's order: the answer is found on the pixels
    undistorted by `cv2.undistortPoints`, then, for the optimising methods (not
    `"three_point"`), refined to the pose of least pixel error in the image, as
    `cv2.solvePnP` and `cv2.solvePnPRefineLM` minimise it;
    `jaxpose.geometry.refine_in_image`). Computes in float64.

    `options`: a `jaxpose.Options` (default `Options()`: `method="mixed"`); `**changes`:
    keyword shorthands for its fields, e.g. `method="linear"` (one of `"mixed"`,
    `"three_point"`, `"linear"`, `"nonlinear"`) or `triplet_budget=8` (see
    `jaxpose.solve`).

    `rvec`, `tvec`, `use_extrinsic_guess`: OpenCV's, in its order. With
    `use_extrinsic_guess=True` the answer starts from the pose `(rvec, tvec)` (both
    required, 3 values each) instead of the three-point roots: the paper's
    small-movement linear method (Section 2.2) from it, Levenberg-Marquardt where that
    does not reach an accepted pose, then the usual acceptance and finish
    (`jaxpose.solve`'s `initial`): the local optimum near the guess, as OpenCV's
    iterative method gives. One stored program serves every guess. Without it, `rvec`
    and `tvec` are ignored (as OpenCV ignores them); the result is always new arrays.

    **Returns:** `(ok, rvec, tvec)` with `rvec`, `tvec` of shape `(3, 1)`: `x_cam =
    Rodrigues(rvec) X + tvec`. `ok` is False (with finite placeholders) when no pose is
    accepted.
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
    return bool(out[0]), out[1:4].reshape(3, 1).copy(), out[4:7].reshape(3, 1).copy()


#: Problems per compiled call of `solve_pnp_batch` (`chunk_size=None`). A batch runs
#: in chunks of this size, its remainder in the smallest `MIN_CHUNK * 2^k` that holds
#: it: a handful of compiled programs whatever `B`, memory bounded by the chunk. Sized
#: for the cache: B = 10^4 ordinary problems, n = 16, in chunks of 4096 / 2048 / 1024,
#: 19.4 / 16.3 / 17.6 us per problem of process time (AMD EPYC, 2 cores, same run;
#: planar 36.1 / 31.2 / 31.7 us).
CHUNK = 2048
MIN_CHUNK = 16
#: The same for the problems the first rung leaves (the later rungs of the escalation,
#: every triplet each): their remainder padded to the smallest power of two that holds
#: it (a lone problem costs one problem's run, not `MIN_CHUNK`'s: the escalation's
#: middle rung, on a quasi-singular problem, n = 16, AMD EPYC process time: 7 ms for one, 93 ms
#: padded to 16; the whole mixed algorithm 8 ms and 411 ms).
FALLBACK_CHUNK = 64


@no_type_check
def solve_pnp_batch(
    object_points: npt.ArrayLike,
    image_points: npt.ArrayLike,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
    *,
    options: Options | None = None,
    chunk_size: int | None = None,
    devices=None,
    **changes: Any,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`B` independent problems of equal `n` in one compiled call (float64).

    **Arguments:** `object_points` `(B, n, 3)` or shared `(n, 3)`; `image_points`
    `(B, n, 2)`; one `camera_matrix` and `dist_coeffs` for all.

    `options`, `**changes`: as `solve_pnp`. By default each problem's answer comes from
    the best roots of its well-spread triplets (`Options.refine`, `spread_points`); the
    problems those leave climb the pipeline's escalation together (the mixed
    algorithm's steps from the best roots of 12 spread matches, then the whole mixed
    algorithm: `jaxpose.strategy.escalation`), each rung a compiled program of its own,
    built only when a problem first needs it.

    `chunk_size`: at most this many problems per compiled call (`None`: `CHUNK`, 2048,
    a smaller batch or the remainder padded to the smallest bucket of `16 * 2^k`
    problems that holds it, so that every batch size of a bucket runs one compiled
    program; memory is bounded by the chunk whatever `B`);
    `devices`: the batch is split over these (`None`: all of `jax.devices()`; an int:
    the first ones); see `jaxpose.api.run_batched`.

    **Returns:** `(ok (B,), rvecs (B, 3), tvecs (B, 3))`, OpenCV's conventions.
    """
    options = resolve(options, changes)
    K, dist, obj, raw, img = _prepare(object_points, image_points, camera_matrix, dist_coeffs, True)
    rungs, options_given = _stages(options), options
    K = np.asarray(K, np.float64)
    _, raw, _ = _pad_points(obj, np.asarray(raw, np.float64))
    obj, img, mask = _pad_points(np.asarray(obj, np.float64), np.asarray(img, np.float64))
    with jax.enable_x64(True):

        def run(obj, img, mask, options, largest, smallest):
            return run_batched(
                _batched_opencv,
                (K, _values(options_given)),
                (obj, img, mask),
                static=(options,),
                chunk_size=largest if chunk_size is None else chunk_size,
                devices=devices,
                min_tail=smallest if chunk_size is None else None,
            )

        ok, rvecs, tvecs = run(obj, img, mask, rungs[0], CHUNK, MIN_CHUNK)

        def later(rung, rows):  # the problems the rungs before did not settle
            return run(obj[rows], img[rows], mask[rows], rung, FALLBACK_CHUNK, 1)

        need = ~np.asarray(ok)
        climb((ok, rvecs, tvecs), need, mask.sum(axis=1), rungs[1:], later, lambda f: f[0])
        if dist is not None and options.method != "three_point":
            # the poses that minimise the error in the image, as OpenCV's
            rv, tv = run_batched(
                _refined_batch,
                (K, _all_coefficients(dist)),
                (np.asarray(rvecs, np.float64), np.asarray(tvecs, np.float64), obj, raw, mask),
                static=(REFINE_STEPS,),
                chunk_size=CHUNK if chunk_size is None else chunk_size,
                devices=devices,
                min_tail=MIN_CHUNK if chunk_size is None else None,
            )
            ok = np.asarray(ok)
            rvecs = np.where(ok[:, None], np.asarray(rv), rvecs)
            tvecs = np.where(ok[:, None], np.asarray(tv), tvecs)
        return np.asarray(ok), np.asarray(rvecs, np.float64), np.asarray(tvecs, np.float64)


#: The fewest matches `solve_pnp_ransac` solves from (`cv2.solvePnPRansac`'s minimal
#: set); fewer give `ok` False.
RANSAC_MIN_MATCHES = 4


# A stored program (compiled once per number of matches, loaded by later processes).
@stored_jit(static_argnames=("options",))
def _robust_opencv(K, obj, img, mask, threshold, min_inliers, triplets, options: RobustOptions):
    res = robust(
        camera_matrix(K),
        obj,
        img,
        mask,
        options=options,
        triplets=triplets,
        inlier_threshold=threshold,
        min_inliers=min_inliers,
    )
    return res.status == Status.OK, matrix_to_rotvec(res.pose.R), res.pose.t, res.inliers


@no_type_check
def solve_pnp_ransac(
    object_points: npt.ArrayLike,
    image_points: npt.ArrayLike,
    camera_matrix: npt.ArrayLike,
    dist_coeffs: npt.ArrayLike | None = None,
    *,
    reprojection_error: float | None = None,
    seed: int = 0,
    options: RobustOptions | None = None,
    **changes: Any,
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray | None]:
    """Drop-in for `cv2.solvePnPRansac`: the pose of the object in the camera frame from
    matches of which some may be wrong (jaxpose's robust mode, `jaxpose.robust`, float64).

    Same conventions and shapes as OpenCV (numpy in and out): `object_points` `(n, 3)`
    (or `(n, 1, 3)`), `image_points` `(n, 2)`, `camera_matrix` `K` `(3, 3)`, optional
    `dist_coeffs` (removed first with `cv2.undistortPoints`, so the inlier test is on
    undistorted pixels). `reprojection_error` is the inlier threshold in pixels (`None`:
    `options.inlier_threshold`, by default OpenCV's 8). Instead of RANSAC's iterations and
    confidence, every triplet (up to `max_triplets`) is scored: the answer is the same on
    every call. Above `max_triplets` triplets (`C(n, 3)`: n > 23 by default) the triplets
    scored are a uniform sample drawn with `seed` (an int >= 0, default `0`): the same
    seed, the same answer; another seed, another sample (no new compilation). Below it,
    `seed` changes nothing: there is nothing to sample.

    The answer is refitted on its inliers (`jaxpose.robust`'s step 4), never the minimal
    sample's pose (unless `refine="none"`). Fewer than 4 matches (`cv2.solvePnPRansac`'s
    minimal set), or fewer inliers than `min_inliers`, give `(False, zeros, zeros,
    None)`, no exception.

    `options`: a `jaxpose.RobustOptions`; `**changes`: keyword shorthands for its fields
    (`min_inliers`, `max_triplets`, `refine`, `iterations`, `rounds`, `max_steps`, ...).

    **Returns:** `(ok, rvec, tvec, inliers)`: `rvec`, `tvec` of shape `(3, 1)` with
    `x_cam = Rodrigues(rvec) X + tvec`; `inliers` the indices of the inlier matches,
    int32 `(k, 1)`, or `None` when `ok` is False (then `rvec`, `tvec` are finite
    placeholders, zeros).
    """
    if reprojection_error is not None and (
        isinstance(reprojection_error, bool)
        or not (
            isinstance(reprojection_error, int | float | np.floating | np.integer)
            and math.isfinite(reprojection_error)
            and reprojection_error > 0
        )
    ):
        raise ValueError(
            f"reprojection_error must be a positive number, got {reprojection_error!r}"
        )
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}")
    options = resolve(options, changes, RobustOptions)
    K = as_intrinsics(camera_matrix, "camera_matrix")
    dist = as_dist_coeffs(dist_coeffs, "dist_coeffs")
    obj, img = as_matching(object_points, image_points, min_count=0)
    if obj.shape[0] < RANSAC_MIN_MATCHES:
        return False, np.zeros((3, 1)), np.zeros((3, 1)), None
    triplets = triplet_indices(obj.shape[0], options.max_triplets, int(seed))
    threshold = options.inlier_threshold if reprojection_error is None else reprojection_error
    # The threshold and the inlier count are traced: one compiled program serves them all.
    program = dataclasses.replace(
        options,
        inlier_threshold=RobustOptions.inlier_threshold,
        min_inliers=RobustOptions.min_inliers,
    )
    img = undistort_pixels(img, K, dist)
    # One program per bucket of matches and of triplets (the padding masked out, the
    # padding triplets repeat a match: degenerate), so that a new number of matches, as a
    # tracker's re-initialisations meet, seldom compiles anything; the triplets padded by
    # at most a third.
    n = obj.shape[0]
    obj, img, mask = _pad_points(obj, np.asarray(img, np.float64))
    rows = 1 << (len(triplets) - 1).bit_length()  # a power of two, or three quarters of one
    rows = rows * 3 // 4 if rows * 3 // 4 >= len(triplets) else rows
    triplets = np.concatenate([triplets, np.zeros((rows - len(triplets), 3), triplets.dtype)])
    with jax.enable_x64(True):
        ok, rvec, tvec, inliers = _robust_opencv(
            np.asarray(K, np.float64),
            np.asarray(obj, np.float64),
            np.asarray(img, np.float64),
            mask,
            np.asarray(threshold, np.float64),
            np.asarray(options.min_inliers, np.int32),
            np.asarray(triplets, np.int32),
            program,
        )
        ok = bool(ok)
        rvec, tvec = np.asarray(rvec, np.float64), np.asarray(tvec, np.float64)
        inliers = np.asarray(inliers)[:n]
    if not ok:
        return False, np.zeros((3, 1)), np.zeros((3, 1)), None
    index = np.flatnonzero(inliers).astype(np.int32).reshape(-1, 1)
    return True, rvec.reshape(3, 1), tvec.reshape(3, 1), index
