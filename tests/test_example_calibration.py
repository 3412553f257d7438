"""`examples/refine_calibration.py`: intrinsics, distortion and poses refined together by
Levenberg-Marquardt with JAX's derivatives reach `cv2.calibrateCamera`'s optimum on
OpenCV's chessboard photographs; the derivatives with respect to the camera parameters
match central differences."""

import importlib.util
from pathlib import Path

import jax
import numpy as np
import pytest

PATH = Path(__file__).resolve().parents[1] / "examples" / "refine_calibration.py"
SPEC = importlib.util.spec_from_file_location("refine_calibration", PATH)
assert SPEC is not None and SPEC.loader is not None
example = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(example)

IMAGES = ("01", "02", "03", "04")


@pytest.fixture(scope="module")
def calibrations():
    # the start's poses by the linear method (its program compiles fastest)
    return example.run(IMAGES, focal_error=0.03, method="linear")


def test_reaches_opencv_calibration(calibrations):
    """Measured on these four views: both RMS 0.613226 px, ours lower by about 1e-11 px;
    fx, fy, cx within 3e-5 px of OpenCV's, the coefficients within 1e-6, the poses
    within 1e-7."""
    found, start, ours, cv = calibrations
    assert tuple(found) == IMAGES
    assert start.rms > 1.0  # the wrong start is visibly wrong
    assert ours.rms <= cv.rms + 1e-9
    assert ours.rms == pytest.approx(cv.rms, abs=1e-8)
    np.testing.assert_allclose(ours.camera[:4], cv.camera[:4], rtol=0, atol=1e-3)  # px
    np.testing.assert_allclose(ours.camera[4:], cv.camera[4:], rtol=0, atol=2e-5)
    np.testing.assert_allclose(ours.rvecs, cv.rvecs, rtol=0, atol=1e-6)  # rad
    np.testing.assert_allclose(ours.tvecs, cv.tvecs, rtol=0, atol=1e-6)  # m
    assert np.all(np.isfinite(ours.camera)) and ours.steps > 0


def test_camera_gradient_matches_central_differences(calibrations):
    """d residuals / d (fx, fy, cx, cy, k1, k2, p1, p2, k3) by `jax.jacfwd` against a
    central difference (float64), at a calibration with every coefficient non-zero."""
    _, _, ours, _ = calibrations
    _, corners = example.detect_corners(IMAGES[:2])
    board = example.board_points()
    rvecs, tvecs = ours.rvecs[:2], ours.tvecs[:2]
    camera = ours.camera + np.array([3.0, -2.0, 1.5, -1.0, 0.01, 0.02, 1e-3, -1e-3, 0.03])

    @jax.jit
    def f(cam):
        return example.residuals(cam, rvecs, tvecs, board, corners)

    J = np.asarray(jax.jit(jax.jacfwd(f))(camera))  # (V, n, 2, 9)
    assert J.shape == (2, 54, 2, 9) and np.all(np.isfinite(J))
    for j, name in enumerate(example.NAMES):
        h = 1e-5 * max(1.0, abs(camera[j]))
        e = np.zeros(9)
        e[j] = h
        fd = np.asarray(f(camera + e)) - np.asarray(f(camera - e))
        fd /= 2 * h
        scale = np.abs(fd).max()
        np.testing.assert_allclose(J[..., j], fd, rtol=0, atol=1e-7 * scale, err_msg=name)


def test_arguments_are_checked():
    board = example.board_points()
    corners = np.zeros((2, len(board), 2))
    good = example.wrong_start(0.03)
    with pytest.raises(ValueError, match="camera"):
        example.refine(good[:5], np.zeros((2, 3)), np.ones((2, 3)), board, corners)
    with pytest.raises(ValueError, match="focal"):
        example.refine(good * -1, np.zeros((2, 3)), np.ones((2, 3)), board, corners)
    with pytest.raises(ValueError, match="corners"):
        example.refine(good, np.zeros((2, 3)), np.ones((2, 3)), board, corners[:, :5])
    with pytest.raises(ValueError, match="rvecs"):
        example.refine(good, np.zeros((3, 3)), np.ones((3, 3)), board, corners)
    bad = corners.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        example.refine(good, np.zeros((2, 3)), np.ones((2, 3)), board, bad)
    with pytest.raises(ValueError, match="focal_error"):
        example.wrong_start(float("nan"))
