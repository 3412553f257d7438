"""Tests of jaxpose.apps._calibration: DLT + Levenberg-Marquardt camera calibration, the robot's
LED procedure, degenerate layouts, and OpenCV on the same pairs."""

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

import jaxpose as jp
from jaxpose.apps import CalibrationStatus
from jaxpose.apps._bench import random_rotation
from jaxpose.apps._calibration import (
    _calibrate_jit,
    calibrate,
    calibrate_with_robot,
    dlt,
    led_joint_grid,
    simulate_led_pairs,
)
from jaxpose.apps._robot import default_robot, forward_kinematics

BENCH = jp.default_bench()
_decompose_camera = jax.jit(jp.geometry.decompose_camera)
ROBOT = default_robot()
N = len(led_joint_grid(ROBOT))  # pairs per problem (108): the robot grid's size

# The module's own compiled `calibrate` (used by `calibrate_with_robot`): with every
# problem padded to N pairs, one compilation serves all tests.
calibrate_jit = _calibrate_jit
dlt_jit = jax.jit(dlt)


def normalised(C):
    C = np.asarray(C, np.float64)
    C = C / np.linalg.norm(C[2, :3])
    return C * np.sign(np.linalg.det(C[:, :3]))


def project(C, X):
    h = X @ C[:, :3].T + C[:, 3]
    return h[:, :2] / h[:, 2:]


def random_camera(rng):
    K = np.array(
        [[rng.uniform(500, 3000), rng.uniform(-5, 5), rng.uniform(200, 600)], [0, 0, 0], [0, 0, 1]]
    )
    K[1, 1], K[1, 2] = K[0, 0] * rng.uniform(0.9, 1.1), rng.uniform(150, 450)
    R = random_rotation(rng)
    centre = rng.normal(scale=1000.0, size=3)
    return K @ np.column_stack([R, -R @ centre]), R, centre


def points_in_front(rng, R, centre, n, depth=(800.0, 1500.0), spread=300.0):
    """`n` world points in a box in front of a camera (rotation R, centre)."""
    pc = rng.uniform([-spread, -spread, depth[0]], [spread, spread, depth[1]], size=(n, 3))
    return pc @ R + centre  # camera frame -> world


def pad(x, n=N):
    return np.concatenate([x, np.repeat(x[:1], n - len(x), axis=0)])


# --------------------------------------------------------------------------- exact data


@settings(max_examples=30)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(6, N))
def test_dlt_recovers_the_camera_from_noise_free_pairs(seed, n):
    rng = np.random.default_rng(seed)
    C, R, centre = random_camera(rng)
    X = points_in_front(rng, R, centre, n)
    mask = np.arange(N) < n
    out = dlt_jit(pad(X), pad(project(C, X)), mask)
    assert int(out.status) == CalibrationStatus.OK
    # Up to scale (the returned camera is normalised): 1e-8 relative to its largest entry.
    Cn = normalised(C)
    np.testing.assert_allclose(out.camera, Cn, atol=1e-8 * np.abs(Cn).max())
    assert float(out.error) < 1e-6


def test_calibrate_noise_free_from_the_robot():
    pairs = simulate_led_pairs(ROBOT, BENCH.camera, led_joint_grid(ROBOT), image_size=(768, 576))
    assert pairs.visible.sum() >= 30
    out = calibrate_jit(pairs.points, pairs.pixels, pairs.visible)
    assert int(out.status) == CalibrationStatus.OK
    Cn = normalised(BENCH.camera)
    np.testing.assert_allclose(out.camera, Cn, atol=1e-8 * np.abs(Cn).max())
    assert float(out.error) < 1e-8
    K, R, t, centre = (np.asarray(x) for x in _decompose_camera(out.camera))
    np.testing.assert_allclose(K, BENCH.K, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(centre, [0.0, -1550.0, 1250.0], atol=1e-6)


# --------------------------------------------------------------------------- degenerate


def test_degenerate_layouts_are_reported():
    rng = np.random.default_rng(0)
    C, R, centre = random_camera(rng)
    X = points_in_front(rng, R, centre, N)
    # Coplanar: every point on one plane (a tilted one), exactly and to 1e-6 relative.
    n = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    flat = X - np.outer((X - X.mean(0)) @ n, n)
    nearly = flat + 1e-4 * rng.normal(size=flat.shape)  # 0.1 micrometre in 300 mm
    line = X[0] + np.outer(np.linspace(-1, 1, N), [100.0, 50.0, 20.0])
    cases = {
        "coplanar": (flat, np.ones(N, bool), CalibrationStatus.COPLANAR_POINTS),
        "nearly coplanar": (nearly, np.ones(N, bool), CalibrationStatus.COPLANAR_POINTS),
        "collinear": (line, np.ones(N, bool), CalibrationStatus.DEGENERATE_MODEL),
        "five points": (X, np.arange(N) < 5, CalibrationStatus.TOO_FEW_POINTS),
    }
    for name, (P, mask, expected) in cases.items():
        uv = project(C, P) + rng.normal(scale=0.3, size=(N, 2))
        for out in (dlt_jit(P, uv, mask), calibrate_jit(P, uv, mask)):
            assert int(out.status) == expected, name
            assert all(np.all(np.isfinite(x)) for x in out), name
    # Non-finite input: a status, finite placeholders.
    bad = X.copy()
    bad[3, 1] = np.nan
    out = calibrate_jit(bad, project(C, X), np.ones(N, bool))
    assert int(out.status) == CalibrationStatus.NOT_FINITE
    assert all(np.all(np.isfinite(x)) for x in out)
    assert "coplanar" in CalibrationStatus.COPLANAR_POINTS.message


def test_coplanar_estimate_would_be_wrong():
    """Why the flag matters: on a plane, the DLT's null space has four directions; the
    matrix it returns is one of them, not the camera."""
    rng = np.random.default_rng(1)
    C, R, centre = random_camera(rng)
    X = points_in_front(rng, R, centre, N)
    n = np.array([0.0, 0.0, 1.0])
    flat = X - np.outer((X - X.mean(0)) @ n, n)
    out = dlt_jit(flat, project(C, flat), np.ones(N, bool))
    assert int(out.status) == CalibrationStatus.COPLANAR_POINTS
    off = points_in_front(rng, R, centre, 20)
    err = np.abs(project(np.asarray(out.camera), off) - project(C, off)).max()
    assert err > 1.0


def test_undetermined_camera():
    """Five coplanar points and one off their plane: not a coplanar set, yet the DLT
    system has two null directions (a plane fixes only 8 of the 11 unknowns)."""
    rng = np.random.default_rng(2)
    C, R, centre = random_camera(rng)
    X = points_in_front(rng, R, centre, 6)
    n = np.array([0.0, 0.0, 1.0])
    X[:5] -= np.outer((X[:5] - X[:5].mean(0)) @ n, n)  # five on a plane, one off it
    out = dlt_jit(pad(X), pad(project(C, X)), np.arange(N) < 6)
    assert int(out.status) == CalibrationStatus.UNDETERMINED_CAMERA


# --------------------------------------------------------------------------- with noise


def test_mask_ignores_padding():
    rng = np.random.default_rng(3)
    C, R, centre = random_camera(rng)
    X = points_in_front(rng, R, centre, 30)
    uv = project(C, X) + rng.normal(scale=0.5, size=(30, 2))
    garbage_X = np.concatenate([X, rng.normal(scale=1e4, size=(N - 30, 3))])
    garbage_uv = np.concatenate([uv, rng.normal(scale=1e4, size=(N - 30, 2))])
    a = calibrate_jit(garbage_X, garbage_uv, np.arange(N) < 30)
    b = calibrate_jit(pad(X), pad(uv), np.arange(N) < 30)
    assert int(a.status) == int(b.status) == CalibrationStatus.OK
    np.testing.assert_allclose(a.camera, b.camera, atol=1e-9 * np.abs(b.camera).max())


def _opencv(points, pixels, image_size, K0):
    """`cv2.calibrateCamera` on a non-planar rig: needs an initial K (the lens' nominal
    one); distortion fixed at zero, so that its model is a pinhole without skew."""
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
        | cv2.CALIB_ZERO_TANGENT_DIST
    )
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 1000, 1e-15)
    rms, K, _, rv, tv = cv2.calibrateCamera(
        [points.astype(np.float32)],
        [pixels.astype(np.float32)],
        image_size,
        K0.copy(),
        np.zeros(5),
        flags=flags,
        criteria=crit,
    )
    return rms, K @ np.column_stack([cv2.Rodrigues(rv[0])[0], tv[0]])


@pytest.mark.parametrize("seed", range(3))
def test_agrees_with_opencv_on_the_robot_pairs(seed):
    """The paper's procedure simulated (LED detections with 0.5 px noise): our camera
    (11 DOF) against `cv2.calibrateCamera` (10 DOF, no skew) on the same pairs."""
    cal, pairs = calibrate_with_robot(
        ROBOT, BENCH.camera, noise=0.5, seed=seed, image_size=BENCH.image_size
    )
    assert int(cal.status) == CalibrationStatus.OK
    P, U = pairs.points[pairs.visible], pairs.pixels[pairs.visible]
    # OpenCV takes float32 points: compare on exactly those values.
    P, U = P.astype(np.float32).astype(np.float64), U.astype(np.float32).astype(np.float64)
    ours = calibrate_jit(pad(P), pad(U), np.arange(N) < len(P))
    nominal = np.array([[3000.0, 0.0, 384.0], [0.0, 3000.0, 288.0], [0.0, 0.0, 1.0]])
    rms_cv, C_cv = _opencv(P, U, BENCH.image_size, nominal)
    rms = lambda C: np.sqrt(np.mean(np.sum((project(C, P) - U) ** 2, axis=1)))
    # OpenCV's reported RMS is Eq. 8 of its camera.
    assert rms(C_cv) == pytest.approx(rms_cv, rel=1e-6)
    # Ours is the optimum of a larger model: never worse on the pairs, and only a little
    # better (the one extra parameter, skew, is zero in the true camera).
    assert float(ours.error) <= rms_cv + 1e-9
    assert float(ours.error) > 0.98 * rms_cv
    # LM improves on the DLT, and the error is at the noise level.
    assert float(ours.error) <= float(ours.dlt_error)
    # Eq. 8 of 0.5 px noise per coordinate: about 0.5 sqrt(2 (2n - 11) / 2n) ~ 0.68 px.
    assert 0.55 < float(ours.error) < 0.8
    # Against the truth: reprojection of points spread over the working volume.
    rng = np.random.default_rng(10 + seed)
    held = rng.uniform([-150.0, -150.0, 0.0], [150.0, 150.0, 150.0], size=(500, 3))
    truth = project(BENCH.camera, held)
    err = lambda C: np.sqrt(np.mean(np.sum((project(C, held) - truth) ** 2, axis=1)))
    e_ours, e_cv = err(np.asarray(ours.camera)), err(C_cv)
    assert e_ours < 0.5 and e_cv < 0.5  # below the detection noise
    assert abs(e_ours - e_cv) < 0.1  # the two predict alike (a fifth of the noise)
    # Decomposition: ours against OpenCV's decomposition of the same matrix.
    K_cv, R_cv, c_cv, *_ = cv2.decomposeProjectionMatrix(np.asarray(ours.camera))
    K, Rw, _, centre = (np.asarray(x) for x in _decompose_camera(ours.camera))
    np.testing.assert_allclose(K, K_cv / K_cv[2, 2], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Rw, R_cv, atol=1e-9)
    np.testing.assert_allclose(centre, (c_cv[:3] / c_cv[3]).ravel(), atol=1e-6)
    # And the intrinsics agree with OpenCV's to the accuracy this narrow view allows.
    K_opencv = cv2.decomposeProjectionMatrix(C_cv)[0]
    K_opencv = K_opencv / K_opencv[2, 2]
    assert abs(K[0, 0] - K_opencv[0, 0]) < 0.005 * K_opencv[0, 0]


def test_led_pairs_are_forward_kinematics():
    q = led_joint_grid(ROBOT)
    pairs = simulate_led_pairs(ROBOT, BENCH.camera, q, noise=0.0, image_size=BENCH.image_size)
    fk = jax.jit(forward_kinematics)
    tips = np.stack([np.asarray(fk(ROBOT, qi).tip) for qi in q[:5]])
    np.testing.assert_allclose(pairs.points[:5], tips, atol=1e-12)
    uv = project(BENCH.camera, pairs.points)
    np.testing.assert_allclose(pairs.pixels, uv, atol=1e-9)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= 768) & (uv[:, 1] >= 0) & (uv[:, 1] <= 576)
    np.testing.assert_array_equal(pairs.visible, inside)
    # The LED heights span well over a plane's thickness.
    z = pairs.points[pairs.visible, 2]
    assert z.max() - z.min() > 100.0
    with pytest.raises(ValueError, match="joints"):
        simulate_led_pairs(ROBOT, BENCH.camera, q[:, :3])


def test_vmap_over_problems_and_float32():
    rng = np.random.default_rng(5)
    Xs, Us, Cs = [], [], []
    for _ in range(2):
        C, R, centre = random_camera(rng)
        X = points_in_front(rng, R, centre, N)
        Xs.append(X)
        Us.append(project(C, X) + rng.normal(scale=0.3, size=(N, 2)))
        Cs.append(C)
    out = jax.jit(jax.vmap(calibrate))(np.stack(Xs), np.stack(Us), np.ones((2, N), bool))
    assert np.all(np.asarray(out.status) == CalibrationStatus.OK)
    for k in range(2):
        single = calibrate_jit(Xs[k], Us[k], np.ones(N, bool))
        np.testing.assert_allclose(np.asarray(out.camera)[k], single.camera, rtol=1e-6, atol=1e-9)
    # float32: the DLT (Hartley-normalised) stays accurate.
    X, U, C = Xs[0], project(Cs[0], Xs[0]), Cs[0]
    out32 = dlt_jit(X.astype(np.float32), U.astype(np.float32), np.ones(N, bool))
    assert out32.camera.dtype == jnp.float32
    assert int(out32.status) == CalibrationStatus.OK
    assert float(out32.error) < 0.05  # px


def test_shape_errors():
    with pytest.raises(ValueError, match="points"):
        dlt(np.zeros((8, 2)), np.zeros((8, 2)))
    with pytest.raises(ValueError, match="pixels"):
        calibrate(np.zeros((8, 3)), np.zeros((7, 2)))
    with pytest.raises(ValueError, match="mask"):
        calibrate(np.zeros((8, 3)), np.zeros((8, 2)), np.ones(7, bool))
