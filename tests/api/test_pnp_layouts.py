"""`solve_pnp` and `solve_pnp_ransac` take every layout `cv2.solvePnP` takes (and the
transposed one), return OpenCV's shapes, and `solve_pnp_ransac` is repeatable, refitted
on its inliers, and answers `False` (no exception) where OpenCV does."""

import cv2
import numpy as np
import pytest

import jaxpose as jp


def _problem(rng, n):
    obj = rng.uniform(-1, 1, (n, 3)) + [0, 0, 6]
    K = np.array([[800.0, 0, 320], [0, 790, 240], [0, 0, 1]])
    rvec, tvec = rng.normal(0, 0.3, 3), rng.normal(0, 0.3, 3)
    img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
    return obj, img, K, rvec, tvec


def _layouts(a):
    """The layouts of one `(n, d)` array that OpenCV takes, and the transposed one."""
    n, d = a.shape
    strided = np.zeros((n, 2 * d))
    strided[:, ::2] = a
    return {
        "(n, d)": a,
        "(n, 1, d)": a.reshape(n, 1, d),
        "(1, n, d)": a.reshape(1, n, d),
        "(d, n)": np.ascontiguousarray(a.T),
        "float32": a.astype(np.float32),
        "non-contiguous": strided[:, ::2],
        "list": a.tolist(),
    }


def test_every_layout_gives_the_same_pose():
    rng = np.random.default_rng(7)
    obj, img, K, rvec, tvec = _problem(rng, 8)
    ok, r0, t0 = jp.solve_pnp(obj, img, K)
    assert ok and r0.shape == (3, 1) and t0.shape == (3, 1)
    np.testing.assert_allclose(r0.ravel(), rvec, atol=1e-8)
    for (a, o), (b, i) in zip(_layouts(obj).items(), _layouts(img).items(), strict=True):
        ok, r, t = jp.solve_pnp(o, i, K)
        tol = 1e-3 if "float32" in (a, b) else 1e-9
        assert ok, (a, b)
        np.testing.assert_allclose(r, r0, atol=tol, err_msg=a)
        np.testing.assert_allclose(t, t0, atol=tol, err_msg=a)
        ok, r, t, inl = jp.solve_pnp_ransac(o, i, K)
        assert ok and inl is not None and r.shape == (3, 1)
        assert inl.shape == (8, 1) and inl.dtype == np.int32
        np.testing.assert_allclose(r, r0, atol=tol, err_msg=a)


def test_ambiguous_and_wrong_layouts():
    rng = np.random.default_rng(8)
    obj, img, K, rvec, _ = _problem(rng, 3)
    # (3, 3) is read as three points, one per row (as OpenCV reads it)
    ok, r, _ = jp.solve_pnp(obj, img, K, method="three_point")
    assert ok
    with pytest.raises(ValueError, match="object_points"):
        jp.solve_pnp(np.zeros((5, 4)), np.zeros((5, 2)), K)
    with pytest.raises(ValueError, match="image_points"):
        jp.solve_pnp(np.zeros((5, 3)), np.zeros((4, 5)), K)


def test_ransac_few_matches_and_no_inliers_answer_false():
    rng = np.random.default_rng(9)
    obj, img, K, _, _ = _problem(rng, 8)
    for n in (0, 1, 3):
        ok, r, t, inl = jp.solve_pnp_ransac(obj[:n], img[:n], K)
        assert ok is False and inl is None
        assert np.array_equal(r, np.zeros((3, 1))) and np.array_equal(t, np.zeros((3, 1)))
        # OpenCV answers False too (or refuses the input outright)
        try:
            assert not cv2.solvePnPRansac(obj[:n], img[:n], K, None)[0]
        except cv2.error:
            pass
    wrong = rng.permutation(img)  # no pose explains these
    ok, r, t, inl = jp.solve_pnp_ransac(obj, wrong, K, reprojection_error=1e-9)
    assert ok is False and inl is None and not np.any(r) and not np.any(t)


def test_ransac_refits_on_the_inliers_and_repeats_with_a_seed():
    rng = np.random.default_rng(10)
    n = 30  # C(30, 3) = 4060 triplets: above max_triplets, a seeded sample
    obj, img, K, rvec, tvec = _problem(rng, n)
    img = img + rng.normal(0, 0.5, img.shape)
    bad = rng.choice(n, 6, replace=False)
    img[bad] += rng.uniform(40, 80, (6, 2))
    ok, r, t, inl = jp.solve_pnp_ransac(obj, img, K, seed=3)
    assert ok and inl is not None and set(bad).isdisjoint(inl.ravel())
    # the pose is the least-squares fit on the inliers (OpenCV's refinement of them), to
    # the linear method's few steps; a three-point pose from 0.5 px noise is ~1e-2 off
    idx = inl.ravel()
    _, rr, tt = cv2.solvePnP(obj[idx], img[idx], K, None, flags=cv2.SOLVEPNP_ITERATIVE)
    np.testing.assert_allclose(r, rr, atol=1e-4)
    np.testing.assert_allclose(t, tt, atol=1e-4)

    def err(r, t):
        proj = cv2.projectPoints(obj[idx], r, t, K, None)[0][:, 0]
        return np.sqrt(np.mean((proj - img[idx]) ** 2))

    assert err(r, t) <= err(rr, tt) * (1 + 1e-6)
    again = jp.solve_pnp_ransac(obj, img, K, seed=3)
    for a, b in zip((ok, r, t, inl), again, strict=True):
        np.testing.assert_array_equal(a, b)
    other = jp.solve_pnp_ransac(obj, img, K, seed=4)  # another sample, the same answer here
    assert other[0]
    np.testing.assert_allclose(other[1], r, atol=1e-6)
    with pytest.raises(ValueError, match="seed"):
        jp.solve_pnp_ransac(obj, img, K, seed=-1)
