"""Refine a camera's calibration by gradient: intrinsics, lens distortion and every view's
pose together, on OpenCV's chessboard photographs, beside `cv2.calibrateCamera`.

The parameters are the intrinsics `(fx, fy, cx, cy)`, OpenCV's five distortion
coefficients `(k1, k2, p1, p2, k3)` and one pose `(rvec, tvec)` per view (object to
camera). The cost is the total squared reprojection error in image pixels,

    sum_v sum_i | project_points(X_i, rvec_v, tvec_v, K(fx, fy, cx, cy), dist) - u_vi |^2

with `jaxpose.geometry.project_points` (OpenCV's projection written in JAX), minimised by
optimistix's Levenberg-Marquardt on the stacked residuals; JAX differentiates the
projection with respect to every parameter. The start is a wrong calibration (focal
length off by `--focal-error`, the principal point at the image centre, no distortion)
and the poses `jaxpose.solve_pnp` finds with it.

    python examples/refine_calibration.py [--images 01 02 ...] [--focal-error 0.03]
                                          [--method mixed]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import jaxpose as jp
from jaxpose.geometry import project_points

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "jaxpose" / "data" / "chessboard"
IMAGES = ("01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14")
PATTERN = (9, 6)  # inner corners per row, per column
SQUARE = 0.025  # metres
IMAGE_SIZE = (640, 480)  # width, height
#: The camera parameters, in the order of the vectors below.
NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def board_points(pattern: tuple[int, int] = PATTERN, square: float = SQUARE) -> np.ndarray:
    """The board's inner corners `(w h, 3)` in metres on `z = 0`, in the order
    `cv2.findChessboardCorners` returns them (row by row, `x` fastest)."""
    w, h = pattern
    points = np.zeros((w * h, 3))
    points[:, :2] = np.mgrid[0:w, 0:h].T.reshape(-1, 2) * square
    return points


def detect_corners(numbers=IMAGES, pattern: tuple[int, int] = PATTERN):
    """The sub-pixel corners of the photographs `left{number}.jpg` where the whole board
    is found: `(numbers found, corners (V, w h, 2))`."""
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    found_in, views = [], []
    for number in numbers:
        path = DATA / f"left{number}.jpg"
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise ValueError(f"cannot read {path}")
        found, corners = cv2.findChessboardCorners(gray, pattern)
        if not found:
            continue
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit)
        found_in.append(number)
        views.append(corners.reshape(-1, 2).astype(np.float64))
    if not views:
        raise ValueError(f"no chessboard found in images {list(numbers)}")
    return found_in, np.stack(views)


def opencv_file_calibration() -> tuple[np.ndarray, np.ndarray]:
    """`(K, dist)` of `left_intrinsics.yml`, OpenCV's own calibration of this camera."""
    fs = cv2.FileStorage(str(DATA / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    return K, dist


def camera_vector(K, dist) -> np.ndarray:
    """The 9 camera parameters `NAMES` of `K` (3, 3) and 5 coefficients."""
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    if K.shape != (3, 3) or dist.shape != (5,):
        raise ValueError(f"K must be (3, 3) and dist (5,), got {K.shape} and {dist.shape}")
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])


def intrinsic_matrix(camera):
    """`K` (3, 3) of the camera vector (no skew), differentiable."""
    fx, fy, cx, cy = camera[0], camera[1], camera[2], camera[3]
    zero, one = jnp.zeros_like(fx), jnp.ones_like(fx)
    return jnp.stack(
        [jnp.stack([fx, zero, cx]), jnp.stack([zero, fy, cy]), jnp.stack([zero, zero, one])]
    )


def residuals(camera, rvecs, tvecs, board, corners):
    """Reprojection residuals `(V, n, 2)` in image pixels: every view's board projected
    through the camera `(9,)` at its pose `rvecs`, `tvecs` `(V, 3)`, minus its corners
    `(V, n, 2)`. Pure JAX, differentiable in every argument."""
    K = intrinsic_matrix(camera)

    def one(rvec, tvec, seen):
        return project_points(board, rvec, tvec, K, camera[4:]) - seen

    return jax.vmap(one)(rvecs, tvecs, corners)


# The residuals evaluated outside the solver, compiled once (not op by op).
_residuals = jax.jit(residuals)


def rms(res) -> float:
    """RMS reprojection error (px) of residuals `(..., 2)`: the square root of the mean
    squared distance per corner, as `cv2.calibrateCamera` reports it."""
    r = np.asarray(res).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


def _check(camera, board, corners):
    camera = np.asarray(camera, np.float64)
    board = np.asarray(board, np.float64)
    corners = np.asarray(corners, np.float64)
    if camera.shape != (9,) or not np.all(np.isfinite(camera)):
        raise ValueError(f"camera must be 9 finite parameters {NAMES}, got {camera}")
    if not (camera[0] > 0 and camera[1] > 0):
        raise ValueError(f"the focal lengths must be positive, got {camera[:2]}")
    if board.ndim != 2 or board.shape[1] != 3 or board.shape[0] < 4:
        raise ValueError(f"board must be (n, 3) with n >= 4, got {board.shape}")
    if corners.ndim != 3 or corners.shape[1:] != (board.shape[0], 2):
        raise ValueError(f"corners must be (V, {board.shape[0]}, 2), got {corners.shape}")
    if not (np.all(np.isfinite(board)) and np.all(np.isfinite(corners))):
        raise ValueError("board and corners must be finite")
    return camera, board, corners


def initial_poses(camera, board, corners, method: str = "mixed"):
    """Every view's pose `(rvecs, tvecs)` `(V, 3)` by `jaxpose.solve_pnp` (`method`) with
    the camera vector's `K` and distortion."""
    camera, board, corners = _check(camera, board, corners)
    K = np.asarray(jax.jit(intrinsic_matrix)(camera))
    rvecs, tvecs = [], []
    for seen in corners:
        ok, rvec, tvec = jp.solve_pnp(board, seen, K, camera[4:], method=method)
        if not ok:
            raise ValueError("solve_pnp found no pose for a view")
        rvecs.append(rvec.ravel())
        tvecs.append(tvec.ravel())
    return np.array(rvecs), np.array(tvecs)


class Calibration(NamedTuple):
    """A calibration: `camera` (9,) in the order `NAMES`, the views' `rvecs`, `tvecs`
    `(V, 3)`, the RMS reprojection error (px) and the solver's step count."""

    camera: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    rms: float
    steps: int


def refine(camera, rvecs, tvecs, board, corners, *, max_steps: int = 500) -> Calibration:
    """Every parameter at once by optimistix's Levenberg-Marquardt on the stacked pixel
    residuals from the start `camera` (9,), `rvecs`, `tvecs` `(V, 3)`. The unknowns are
    one flat vector (the intrinsics divided by the start's focal length, so that every
    unknown is of order 1, the coefficients, then each view's `rvec, tvec`); the Jacobian
    is `jax.jacfwd`'s. Raises `ValueError` on bad arguments or when the solve does not
    converge."""
    camera, board, corners = _check(camera, board, corners)
    rvecs = np.asarray(rvecs, np.float64)
    tvecs = np.asarray(tvecs, np.float64)
    if rvecs.shape != (len(corners), 3) or tvecs.shape != rvecs.shape:
        raise ValueError(f"rvecs and tvecs must be ({len(corners)}, 3)")
    if not (np.all(np.isfinite(rvecs)) and np.all(np.isfinite(tvecs))):
        raise ValueError("rvecs and tvecs must be finite")
    scale = np.concatenate([np.full(4, camera[0]), np.ones(5)])
    y0 = np.concatenate([camera / scale, np.hstack([rvecs, tvecs]).ravel()])
    with jax.enable_x64(True):
        args = (jnp.asarray(scale), jnp.asarray(board), jnp.asarray(corners))
        solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-12)
        solution = optx.least_squares(
            _stacked,
            solver,
            jnp.asarray(y0),
            args=args,
            max_steps=max_steps,
            throw=False,
            options={"jac": "fwd"},
        )
        if solution.result != optx.RESULTS.successful:
            raise ValueError(f"refinement did not converge: {solution.result}")
        y = np.asarray(solution.value)
        res = jax.jit(_stacked)(y, args)
        steps = int(solution.stats["num_steps"])
    if not np.all(np.isfinite(y)):
        raise ValueError("refinement produced non-finite parameters")
    poses = y[9:].reshape(-1, 6)
    return Calibration(y[:9] * scale, poses[:, :3], poses[:, 3:], rms(res), steps)


def _stacked(y, args):
    """The residuals `(2 V n,)` of the flat unknowns `y` (see `refine`)."""
    scale, board, corners = args
    poses = y[9:].reshape(-1, 6)
    return residuals(y[:9] * scale, poses[:, :3], poses[:, 3:], board, corners).reshape(-1)


def opencv_calibration(board, corners) -> Calibration:
    """`cv2.calibrateCamera` on the same corners (5 coefficients, no flags)."""
    _, board, corners = _check(np.ones(9), board, corners)
    objects = [board.astype(np.float32)] * len(corners)
    images = [c.astype(np.float32).reshape(-1, 1, 2) for c in corners]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    err, K, dist, rv, tv = cv2.calibrateCamera(
        objects, images, IMAGE_SIZE, np.eye(3), np.zeros(5), flags=0, criteria=crit
    )
    rvecs = np.array([r.ravel() for r in rv])
    tvecs = np.array([t.ravel() for t in tv])
    camera = camera_vector(K, dist.ravel()[:5])
    with jax.enable_x64(True):
        res = _residuals(camera, rvecs, tvecs, board, corners)
    return Calibration(camera, rvecs, tvecs, rms(res), -1)


def wrong_start(focal_error: float) -> np.ndarray:
    """The start: OpenCV's file's focal length times `1 + focal_error`, the principal
    point at the image centre, no distortion."""
    if not (math.isfinite(focal_error) and -0.5 < focal_error < 0.5):
        raise ValueError(f"focal_error must be in (-0.5, 0.5), got {focal_error}")
    K, _ = opencv_file_calibration()
    w, h = IMAGE_SIZE
    f = K[0, 0] * (1 + focal_error)
    return np.array([f, f, w / 2, h / 2, 0.0, 0.0, 0.0, 0.0, 0.0])


def run(numbers=IMAGES, focal_error: float = 0.03, method: str = "mixed"):
    """Detect, start wrong, refine, and calibrate with OpenCV: `(found, start, ours,
    opencv)` (`Calibration`s; the start's poses and RMS are those of `solve_pnp` with
    `method` and the wrong camera)."""
    found, corners = detect_corners(numbers)
    board = board_points()
    camera0 = wrong_start(focal_error)
    rvecs0, tvecs0 = initial_poses(camera0, board, corners, method)
    with jax.enable_x64(True):
        res0 = _residuals(camera0, rvecs0, tvecs0, board, corners)
    start = Calibration(camera0, rvecs0, tvecs0, rms(res0), 0)
    ours = refine(camera0, rvecs0, tvecs0, board, corners)
    return found, start, ours, opencv_calibration(board, corners)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--images", nargs="*", default=list(IMAGES))
    parser.add_argument("--focal-error", type=float, default=0.03)
    parser.add_argument(
        "--method", default="mixed", choices=("mixed", "linear", "nonlinear", "three_point")
    )
    args = parser.parse_args(argv)
    found, start, ours, cv = run(args.images, args.focal_error, args.method)
    print(f"views: {len(found)} ({' '.join(found)}), {len(board_points())} corners each")
    print(
        f"RMS reprojection error (px): start {start.rms:.4f}, jaxpose {ours.rms:.6f} "
        f"({ours.steps} Levenberg-Marquardt steps), cv2.calibrateCamera {cv.rms:.6f}"
    )
    print(f"RMS difference, jaxpose - cv2: {ours.rms - cv.rms:.1e} px")
    print(f"{'':>4} {'start':>12} {'jaxpose':>14} {'cv2':>14} {'difference':>11}")
    for name, a, b, c in zip(NAMES, start.camera, ours.camera, cv.camera, strict=True):
        print(f"{name:>4} {a:12.6g} {b:14.8g} {c:14.8g} {b - c:11.2e}")
    print(
        f"largest pose difference: rvec {np.abs(ours.rvecs - cv.rvecs).max():.1e} rad, "
        f"tvec {np.abs(ours.tvecs - cv.tvecs).max():.1e} m"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
