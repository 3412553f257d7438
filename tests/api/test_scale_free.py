"""The geometric thresholds are scale-free (`Options.min_area`, the paper's Section 2.1
test relative to the problem's own spread): one problem gives the same pose in pixels
at any focal length, with non-square pixels, and in normalised coordinates (`K = I`)."""

import cv2
import numpy as np
import pytest

import jaxpose as jp

FOCALS = (1.0, 20.0, 800.0, 3000.0, 10000.0)


def _camera(f, aspect=1.0):
    return np.array([[f, 0, 0.4 * f], [0, f * aspect, 0.3 * f], [0, 0, 1.0]])


def _scene(rng, n, planar=False):
    obj = rng.uniform(-1, 1, (n, 3))
    if planar:
        obj[:, 2] = 0
    rvec = rng.normal(0, 0.5, 3)
    tvec = np.array([*rng.normal(0, 0.3, 2), rng.uniform(4, 8)])
    return obj, rvec, tvec


@pytest.mark.parametrize("n, planar", [(4, False), (4, True), (6, False), (12, True)])
def test_same_pose_at_every_focal_length_and_in_normalised_coordinates(n, planar):
    rng = np.random.default_rng(100 + n + planar)
    for _ in range(3):
        obj, rvec, tvec = _scene(rng, n, planar)
        cameras = [np.eye(3)] + [_camera(f) for f in FOCALS] + [_camera(800, aspect=0.05)]
        poses = []
        for K in cameras:
            img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
            ok, r, t = jp.solve_pnp(obj, img, K)
            assert ok, K[0, 0]
            poses.append(np.concatenate([r.ravel(), t.ravel()]))
            ok, r, t, inl = jp.solve_pnp_ransac(obj, img, K, reprojection_error=1e-3 * K[0, 0])
            if n > 4:  # with 4 matches, three-point poses that fit all four can differ
                assert ok and inl is not None and len(inl) == n, K[0, 0]
        poses = np.array(poses)
        np.testing.assert_allclose(poses, poses[:1].repeat(len(poses), 0), atol=1e-6)
        if n > 4 or not planar:
            np.testing.assert_allclose(poses[0], np.concatenate([rvec, tvec]), atol=1e-6)


def test_the_normalised_coordinates_example():
    L = 0.5
    obj = np.array([(-L, -L, L), (L, -L, L), (L, L, L), (-L, L, L), (-L, -L, -L), (L, -L, -L)])
    rvec, tvec = np.array([0.407, 0.092, 0.88]), np.array([0.576, -0.43, 1.3798])
    img = cv2.projectPoints(obj, rvec, tvec, np.eye(3), None)[0].reshape(-1, 2)
    ok, r, t = jp.solve_pnp(obj, img, np.eye(3), None)
    assert ok
    np.testing.assert_allclose(r.ravel(), rvec, atol=1e-9)
    np.testing.assert_allclose(t.ravel(), tvec, atol=1e-9)
    ok, r, t, inl = jp.solve_pnp_ransac(obj, img, np.eye(3), None)
    assert ok and inl is not None and len(inl) == 6
    np.testing.assert_allclose(r.ravel(), rvec, atol=1e-9)


def test_the_bench_selects_the_triplets_of_the_paper_test():
    """The default `min_area` flags as aligned, on the paper's bench (f = 3000 px),
    exactly the triplets whose image triangle is below the paper's 40 px^2."""
    for seed in (0, 1, 2):
        bench = jp.default_bench(seed=seed)
        obs = jp.observations(bench.camera, bench.model_points, bench.image_points)
        init = jp.strategy.initial_poses(obs)
        img = np.asarray(bench.image_points)[np.asarray(init.triplets)]  # (T, 3, 2)
        e1, e2 = img[:, 1] - img[:, 0], img[:, 2] - img[:, 0]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        flagged = np.asarray(init.status) == jp.Status.DEGENERATE_IMAGE
        np.testing.assert_array_equal(flagged, area < 40)
        assert 5 <= flagged.sum() <= 40
