"""Public entry points: solve_pnp / solve_pnp_batch against cv2.solvePnP, validation."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.apps import sample_path

DATA = sample_path("chessboard")


def _opencv_scene(rng, n=8, noise=1.0, kind="ordinary"):
    """A random problem in OpenCV's form (8 matches: the point bucket of the default
    `solve_pnp` program that `test_solve_pnp_batch_equals_the_loop` and the other files'
    8-point problems run, compiled once for all of them)."""
    s = jp.apps.random_scene(rng, n, noise=noise, kind=kind, world_camera=False)
    K = s.camera[:, :3]
    return s, K


def _opencv_reference(obj, img, K, dist=None):
    ok, rv, tv = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_SQPNP)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
    return cv2.solvePnPRefineLM(obj, img, K, dist, rv, tv, criteria=crit)


def _reproj(obj, img, K, rv, tv, dist=None):
    p, _ = cv2.projectPoints(obj, rv, tv, K, dist)
    return float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - img) ** 2, axis=1))))


@pytest.mark.parametrize("method", ["mixed", "linear", "nonlinear"])
def test_solve_pnp_matches_opencv(method):
    rng = np.random.default_rng(1)
    for _ in range(4):
        s, K = _opencv_scene(rng)
        obj, img = s.model_points, s.image_points
        ok, rv, tv = jp.solve_pnp(obj, img, K, method=method)
        assert ok and rv.shape == (3, 1) and tv.shape == (3, 1)
        rv_ref, tv_ref = _opencv_reference(obj, img, K)
        assert _reproj(obj, img, K, rv, tv) == pytest.approx(
            _reproj(obj, img, K, rv_ref, tv_ref), abs=1e-6
        )
        np.testing.assert_allclose(rv, rv_ref, atol=1e-7)
        np.testing.assert_allclose(tv, tv_ref, atol=1e-7 * np.linalg.norm(tv_ref))


def test_three_point_method_is_close():
    rng = np.random.default_rng(2)
    s, K = _opencv_scene(rng, noise=0.5)
    ok, rv, tv = jp.solve_pnp(s.model_points, s.image_points, K, method="three_point")
    assert ok
    assert _reproj(s.model_points, s.image_points, K, rv, tv) < 3.0


def test_solve_pnp_with_distortion_and_opencv_layouts():
    rng = np.random.default_rng(3)
    s, K = _opencv_scene(rng, noise=0.0)
    dist = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
    R_true = s.R  # the scene's model-to-camera pose (world = camera frame)
    rv_true = cv2.Rodrigues(R_true)[0]
    img, _ = cv2.projectPoints(s.model_points, rv_true, s.t, K, dist)
    ok, rv, tv = jp.solve_pnp(s.model_points.reshape(-1, 1, 3), img, K, dist)
    assert ok
    np.testing.assert_allclose(rv, rv_true, atol=1e-6)
    np.testing.assert_allclose(tv.ravel(), s.t, atol=1e-6 * np.linalg.norm(s.t))


def test_solve_pnp_batch_equals_the_loop():
    rng = np.random.default_rng(4)
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    scenes = [jp.apps.random_scene(rng, 8, noise=1.0, world_camera=False) for _ in range(5)]
    obj = np.stack([s.model_points for s in scenes])
    img = np.stack([s.image_points for s in scenes])
    ok, rvecs, tvecs = jp.solve_pnp_batch(obj, img, K)
    assert ok.shape == (5,) and rvecs.shape == (5, 3) and tvecs.shape == (5, 3)
    for b in range(5):
        ok1, rv, tv = jp.solve_pnp(obj[b], img[b], K)
        assert ok1 == ok[b]
        np.testing.assert_allclose(rvecs[b], rv.ravel(), atol=1e-9)
        np.testing.assert_allclose(tvecs[b], tv.ravel(), atol=1e-9)
    # shared object points (the same shapes: no new compilation)
    ok2, rv2, _ = jp.solve_pnp_batch(obj[0], img[[0, 0, 0, 0, 0]], K)
    np.testing.assert_allclose(rv2, np.broadcast_to(rvecs[0], (5, 3)), atol=1e-9)


def test_solve_pnp_on_the_opencv_chessboards():
    fs = cv2.FileStorage(str(DATA / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat()
    fs.release()
    board = np.zeros((54, 3))
    board[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.025
    solved = 0
    for path in sorted(DATA.glob("left*.jpg")):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCorners(gray, (9, 6))
        if not found:
            continue
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)
        ok, rv, tv = jp.solve_pnp(board, corners, K, dist)
        assert ok, path.name
        rv_ref, tv_ref = _opencv_reference(board, corners, K, dist)
        e_ours = _reproj(board, corners, K, rv, tv, dist)
        e_ref = _reproj(board, corners, K, rv_ref, tv_ref, dist)
        # Same Eq. 8 optimum as OpenCV's (residuals measured on undistorted pixels by us,
        # on distorted ones by OpenCV: equal to a few 1e-3 px).
        assert e_ours <= e_ref + 5e-3, path.name
        np.testing.assert_allclose(tv, tv_ref, atol=2e-3)  # metres
        solved += 1
    assert solved >= 12


@pytest.mark.parametrize(
    "args, name",
    [
        ((np.zeros((5, 2)), np.zeros((5, 2))), "object_points"),
        ((np.zeros((5, 3)), np.zeros((4, 2))), "image_points"),
        ((np.full((5, 3), np.nan), np.zeros((5, 2))), "object_points"),
        ((np.zeros((2, 3)), np.zeros((2, 2))), "object_points"),
    ],
)
def test_solve_pnp_validates(args, name):
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    with pytest.raises(ValueError, match=name):
        jp.solve_pnp(*args, K)


def test_solve_pnp_validates_camera_and_method():
    obj, img = np.random.default_rng(0).normal(size=(5, 3)), np.zeros((5, 2))
    with pytest.raises(ValueError, match="camera_matrix"):
        jp.solve_pnp(obj, img, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="method"):
        jp.solve_pnp(obj, img, np.eye(3), method="epnp")
    with pytest.raises(ValueError, match="dist_coeffs"):
        jp.solve_pnp(obj, img, np.eye(3), np.zeros(3) + 0.1)


def test_import_leaves_jax_config_alone():
    code = "import jax, jaxpose; assert not jax.config.read('jax_enable_x64')"
    subprocess.run([sys.executable, "-c", code], check=True)
