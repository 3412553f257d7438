"""Shared helpers for the tests: reference poses, finite differences, recordings."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np


def verify_recording(path) -> None:
    """`rerun rrd verify`, the rerun command line's own check that a file loads."""
    out = subprocess.run(
        [sys.executable, "-m", "rerun", "rrd", "verify", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "verified without error" in out.stdout + out.stderr


def central_difference_jacobian(f, x, h=1e-6):
    """Jacobian of `f: R^k -> R^m` at `x` by central differences (numpy, float64)."""
    x = np.asarray(x, dtype=np.float64)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = h
        cols.append((np.asarray(f(x + e)) - np.asarray(f(x - e))).ravel() / (2 * h))
    return np.stack(cols, axis=-1)


def opencv_optimum(scene_or_bench):
    """OpenCV's reference optimum: SQPnP then solvePnPRefineLM, returned as a world-frame
    pose `(R, t)` (p = R m + t) for a scene whose camera is `K [R_wc | t_wc]`."""
    C = np.asarray(scene_or_bench.camera, dtype=np.float64)
    K, R_wc, t_wc = _decompose(C)
    m = np.asarray(scene_or_bench.model_points, dtype=np.float64)
    img = np.asarray(scene_or_bench.image_points, dtype=np.float64)
    ok, rv, tv = cv2.solvePnP(m, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
    rv, tv = cv2.solvePnPRefineLM(m, img, K, None, rv, tv, criteria=crit)
    Rc, _ = cv2.Rodrigues(rv)
    # camera-frame pose -> world-frame pose
    R = R_wc.T @ Rc
    t = R_wc.T @ (tv.ravel() - t_wc)
    return R, t


def _decompose(C):
    K, R, c, *_ = cv2.decomposeProjectionMatrix(C)
    K = K / K[2, 2]
    centre = (c[:3] / c[3]).ravel()
    if np.linalg.det(R) < 0:  # pragma: no cover - only for negative-scale cameras
        R = -R
    return K, R, -R @ centre


def rms_px(C, R, t, m, img):
    h = (m @ R.T + t) @ C[:, :3].T + C[:, 3]
    return float(np.sqrt(np.mean(np.sum((h[:, :2] / h[:, 2:] - img) ** 2, axis=1))))


def chessboard_corners(path) -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's 9 x 6 chessboard in a photograph: the board's corners `(54, 3)` (0.025 m
    squares, z = 0) and their pixels `(54, 2)` (`cv2.findChessboardCorners`, then
    `cv2.cornerSubPix`), or None when the board is not found."""
    import cv2

    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(gray, (9, 6))
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)
    board = np.zeros((54, 3))
    board[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.025
    return board, corners
