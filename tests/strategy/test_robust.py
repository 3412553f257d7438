"""Robust mode: the consensus optimum over all triplets finds the right matches and the
Eq. 8 optimum over them (checked against OpenCV on the known right matches)."""

from __future__ import annotations

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose import Status

N = 16  # every problem here has 16 matches: one compiled shape


def _swap(image, wrong):
    """Wrong matches: each chosen match gets the pixel of the next chosen one."""
    out = image.copy()
    out[wrong] = image[np.roll(wrong, 1)]
    return out


def _angle(R1, R2):
    """Rotation angle between two rotation matrices (numpy, accurate near zero)."""
    return 2 * np.arcsin(min(np.linalg.norm(R1 - R2) / (2 * np.sqrt(2)), 1.0))


def _inlier_optimum(obj, img, K, inliers):
    """OpenCV's Eq. 8 optimum over the given matches (SQPnP, then LM to convergence)."""
    ok, rv, tv = cv2.solvePnP(obj[inliers], img[inliers], K, None, flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
    rv, tv = cv2.solvePnPRefineLM(obj[inliers], img[inliers], K, None, rv, tv, criteria=crit)
    return cv2.Rodrigues(rv)[0], tv.ravel()


def _bench_cases():
    """Bench problems with 0-50% wrong matches, plus masked and degenerate ones."""
    cases = []
    for seed, k in enumerate([0, 2, 3, 5, 6, 8]):
        b = jp.default_bench(seed=seed)
        wrong = np.sort(np.random.default_rng(100 + seed).choice(N, k, replace=False))
        img = _swap(b.image_points, wrong)
        cases.append((b, b.model_points, img, np.ones(N, bool), wrong))
    # Six right matches among ten wrong ones spread far wider than the object: every
    # triangle of right matches is below the aligned test's area relative to the spread
    # of all matches (`area_threshold`), not below the inlier test's tau^2 (robust mode's
    # cap; without it, no pose: OpenCV's USAC case with 90% wrong matches).
    b = jp.default_bench(seed=10)
    wrong = np.sort(np.random.default_rng(110).choice(N, 10, replace=False))
    img = b.image_points.copy()
    img[wrong] = np.random.default_rng(111).uniform(-2e4, 2e4, (10, 2))
    cases.append((b, b.model_points, img, np.ones(N, bool), wrong))
    b = jp.default_bench(seed=9)
    wrong = np.array([1, 4, 9, 12])
    img = _swap(b.image_points, wrong)
    mask = np.ones(N, bool)
    mask[[2, 3, 14]] = False  # padding: three rows that do not take part
    cases.append((b, b.model_points, img, mask, wrong))
    return cases


@pytest.fixture(scope="module")
def bench_results():
    cases = _bench_cases()
    b0 = cases[0][0]
    # Degenerate problems in the same batch: collinear model points; two usable matches.
    line = np.column_stack([np.linspace(-50, 50, N), np.zeros(N), np.zeros(N)])
    two = np.zeros(N, bool)
    two[:2] = True
    models = np.stack([c[1] for c in cases] + [line, b0.model_points])
    images = np.stack([c[2] for c in cases] + [b0.image_points, b0.image_points])
    masks = np.stack([c[3] for c in cases] + [np.ones(N, bool), two])
    run = jax.jit(jax.vmap(lambda M, I, m: jp.robust(b0.camera, M, I, m)))
    out = jax.tree.map(np.asarray, run(jnp.asarray(models), jnp.asarray(images), masks))
    return cases, out


def test_robust_finds_the_right_matches_on_the_bench(bench_results):
    cases, out = bench_results
    for i, (b, obj, img, mask, wrong) in enumerate(cases):
        assert out.status[i] == Status.OK, i
        right = mask.copy()
        right[wrong] = False
        np.testing.assert_array_equal(out.inliers[i], right, err_msg=str(i))
        assert out.num_inliers[i] == right.sum()
        assert out.refined[i]
        # The pose is the Eq. 8 optimum over the right matches (camera frame compared).
        Rc, tc = _inlier_optimum(obj, img, b.K, np.flatnonzero(right))
        R = b.R_wc @ out.pose.R[i]
        t = b.R_wc @ out.pose.t[i] + b.t_wc
        assert _angle(R, Rc) < 1e-7
        assert np.linalg.norm(t - tc) < 1e-7 * np.linalg.norm(tc)
        h = (obj @ out.pose.R[i].T + out.pose.t[i]) @ b.camera[:, :3].T + b.camera[:, 3]
        r2 = np.sum((h[:, :2] / h[:, 2:] - img) ** 2, axis=1)
        assert out.error[i] == pytest.approx(np.sqrt(np.mean(r2[right])), rel=1e-9)


def test_robust_reports_degenerate_problems(bench_results):
    cases, out = bench_results
    n = len(cases)
    assert out.status[n] == Status.NO_SOLUTION  # collinear model: no triplet is usable
    assert out.status[n + 1] == Status.TOO_FEW_POINTS
    for i in (n, n + 1):
        assert not out.inliers[i].any() and out.num_inliers[i] == 0
        np.testing.assert_array_equal(out.pose.R[i], np.eye(3))
    for leaf in jax.tree.leaves(out):
        if np.issubdtype(leaf.dtype, np.floating):
            assert np.all(np.isfinite(leaf))


def test_robust_in_float32():
    b = jp.default_bench(seed=4)
    wrong = np.array([0, 5, 7, 11, 13])
    img = _swap(b.image_points, wrong)
    res = jax.jit(jp.robust)(
        jnp.asarray(b.camera, jnp.float32),
        jnp.asarray(b.model_points, jnp.float32),
        jnp.asarray(img, jnp.float32),
    )
    assert res.pose.R.dtype == jnp.float32
    assert res.status == Status.OK
    right = np.ones(N, bool)
    right[wrong] = False
    np.testing.assert_array_equal(np.asarray(res.inliers), right)
    Rc, tc = _inlier_optimum(b.model_points, img, b.K, np.flatnonzero(right))
    R = b.R_wc @ np.asarray(res.pose.R, np.float64)
    t = b.R_wc @ np.asarray(res.pose.t, np.float64) + b.t_wc
    assert _angle(R, Rc) < 1e-3
    assert np.linalg.norm(t - tc) < 1e-3 * np.linalg.norm(tc)


def _opencv_problem(seed, outliers):
    """A random scene in OpenCV's convention with `outliers` matches moved 30-200 px away."""
    rng = np.random.default_rng(seed)
    s = jp.apps.random_scene(rng, N, noise=0.5, world_camera=False)
    img = s.image_points.copy()
    wrong = np.sort(rng.choice(N, outliers, replace=False))
    angle = rng.uniform(0, 2 * np.pi, outliers)
    img[wrong] += rng.uniform(30, 200, (outliers, 1)) * np.column_stack(
        [np.cos(angle), np.sin(angle)]
    )
    return s, img, wrong


@settings(max_examples=12)
@given(seed=st.integers(0, 2**31 - 1), outliers=st.integers(0, 7))
def test_solve_pnp_ransac_against_the_right_matches(seed, outliers):
    s, img, wrong = _opencv_problem(seed, outliers)
    K = s.camera[:, :3]
    ok, rvec, tvec, inliers = jp.solve_pnp_ransac(s.model_points, img, K)
    assert ok
    assert rvec.shape == (3, 1) and tvec.shape == (3, 1)
    assert inliers.shape == (N - outliers, 1) and inliers.dtype == np.int32
    right = np.setdiff1d(np.arange(N), wrong)
    np.testing.assert_array_equal(inliers.ravel(), right)
    Rc, tc = _inlier_optimum(s.model_points, img, K, right)
    assert _angle(cv2.Rodrigues(rvec)[0], Rc) < 1e-7
    assert np.linalg.norm(tvec.ravel() - tc) < 1e-7 * np.linalg.norm(tc)
    # OpenCV's RANSAC on the same problem agrees (to its own refinement's accuracy).
    ok_cv, rv_cv, tv_cv, inl_cv = cv2.solvePnPRansac(
        s.model_points, img, K, None, iterationsCount=1000, confidence=0.999
    )
    if ok_cv and len(inl_cv) == len(right):
        assert _angle(cv2.Rodrigues(rv_cv)[0], Rc) < 1e-3


def test_solve_pnp_ransac_failure_and_distortion():
    rng = np.random.default_rng(3)
    s = jp.apps.random_scene(rng, N, noise=0.0, world_camera=False)
    K = s.camera[:, :3]
    # Pure noise: no pose with min_inliers consistent matches.
    garbage = rng.uniform(0, 640, (N, 2))
    ok, rvec, tvec, inliers = jp.solve_pnp_ransac(
        s.model_points, garbage, K, reprojection_error=0.5, min_inliers=8
    )
    assert not ok and inliers is None
    assert np.all(rvec == 0) and np.all(tvec == 0) and rvec.shape == (3, 1)
    # With lens distortion: pixels are undistorted first, as in jaxpose.solve_pnp.
    dist = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
    rv_true, tv_true = cv2.Rodrigues(s.R)[0], s.t
    img, _ = cv2.projectPoints(s.model_points, rv_true, tv_true, K, dist)
    img = img.reshape(-1, 2)
    img[[2, 7]] += 80.0
    ok, rvec, tvec, inliers = jp.solve_pnp_ransac(s.model_points, img, K, dist)
    assert ok
    np.testing.assert_array_equal(inliers.ravel(), np.setdiff1d(np.arange(N), [2, 7]))
    # (cv2.undistortPoints iterates a fixed number of times: not exact)
    np.testing.assert_allclose(tvec.ravel(), tv_true, rtol=1e-4)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"reprojection_error": 0.0}, "reprojection_error"),
        ({"reprojection_error": float("nan")}, "reprojection_error"),
        ({"min_inliers": 2}, "min_inliers"),
        ({"min_inliers": 4.5}, "min_inliers"),
        ({"max_triplets": 0}, "max_triplets"),
        ({"refine": "ransac"}, "refine"),
        ({"rounds": -1}, "rounds"),
    ],
)
def test_solve_pnp_ransac_option_validation(kwargs, name):
    s = jp.apps.random_scene(np.random.default_rng(0), 8, world_camera=False)
    with pytest.raises(ValueError, match=name):
        jp.solve_pnp_ransac(s.model_points, s.image_points, s.camera[:, :3], **kwargs)


@pytest.mark.parametrize(
    "args, name",
    [
        ((np.zeros((8, 2)), np.zeros((8, 2)), np.eye(3)), "object_points"),
        ((np.zeros((8, 3)), np.zeros((7, 2)), np.eye(3)), "image_points"),
        ((np.zeros((8, 3)), np.zeros((8, 3)), np.eye(3)), "image_points"),
        ((np.zeros((8, 3)), np.zeros((8, 2)), np.zeros((3, 3))), "camera_matrix"),
    ],
)
def test_solve_pnp_ransac_argument_validation(args, name):
    with pytest.raises(ValueError, match=name):
        jp.solve_pnp_ransac(*args)
