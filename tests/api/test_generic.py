"""`solve_pnp_generic` against `cv2.solvePnPGeneric`: on planar targets its poses are
IPPE's two after refinement to their local minima, with OpenCV's errors."""

import cv2
import numpy as np

import jaxpose as jp

#: Planar problems compared with IPPE (`benchmarks/opencv_cases.py` runs 1,000; 200
#: here, about 2.5 minutes on a 2-core CPU).
PLANAR_PROBLEMS = 200


def _refined_ippe(obj, img, K, dist):
    """IPPE's two poses, each refined to its local minimum of the reprojection error:
    by `solve_pnp` from it (`use_extrinsic_guess`, checked against OpenCV's own
    refinement in `test_initial.py`; `cv2.solvePnPRefineLM`'s 20 iterations stop short
    in the flat valleys of the planar ambiguity, up to 0.2 rad from the bottom, measured).
    Each is at an error no higher than `cv2.solvePnPRefineLM`'s from the same start."""
    n, rs, ts, _ = cv2.solvePnPGeneric(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    out = []
    for r, t in zip(rs, ts, strict=True):
        r_cv, t_cv = cv2.solvePnPRefineLM(obj, img, K, dist, r.copy(), t.copy())
        ok, r, t = jp.solve_pnp(obj, img, K, dist, r, t, True)
        if not ok:  # no minimum reached from it (a flat valley: see `solve_pnp_generic`)
            continue
        assert _error(obj, img, K, dist, r, t) <= _error(obj, img, K, dist, r_cv, t_cv) * (1 + 1e-9)
        out.append((r, t))
    return out


def _error(obj, img, K, dist, r, t):
    proj = cv2.projectPoints(obj, r, t, K, dist)[0].reshape(-1, 2)
    return np.linalg.norm(proj - img) / np.sqrt(2 * len(obj))


def _matches(ours, theirs, obj, img, K, dist):
    """One local minimum: the same pose (to the solvers' tolerance) and error."""
    (r, t), (rc, tc) = ours, theirs
    close = np.abs(r - rc).max() < 1e-5 and np.abs(t - tc).max() < 1e-5 * np.abs(tc).max()
    e, ec = _error(obj, img, K, dist, r, t), _error(obj, img, K, dist, rc, tc)
    return close and abs(e - ec) <= 1e-9 * ec


def planar_case(rng, dist=None):
    n = int(rng.integers(4, 12))
    obj = np.c_[rng.uniform(-1, 1, (n, 2)), np.zeros(n)]
    K = np.array([[rng.uniform(300, 2000), 0, 320], [0, 0, 240], [0, 0, 1]])
    K[1, 1] = K[0, 0] * rng.uniform(0.9, 1.1)
    rvec = rng.normal(0, 0.6, 3)
    tvec = np.array([*rng.normal(0, 0.5, 2), rng.uniform(4, 15)])
    img = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
    return obj, img + rng.normal(0, rng.uniform(0.1, 2.0), img.shape), K


def compare_with_ippe(obj, img, K, dist=None):
    """`(same, count)`: whether jaxpose's minima are IPPE's refined ones (each found in
    the other), sorted, with OpenCV's errors; and how many jaxpose found."""
    count, rvecs, tvecs, errs = jp.solve_pnp_generic(obj, img, K, dist)
    ours = list(zip(rvecs, tvecs, strict=True))
    theirs = _refined_ippe(obj, img, K, dist)
    if count == 0:
        return False, count
    for (r, t), e in zip(ours, errs[:, 0], strict=True):
        if not np.isclose(e, _error(obj, img, K, dist, r, t), rtol=1e-9):
            return False, count
    if list(errs[:, 0]) != sorted(errs[:, 0]):
        return False, count
    found = all(any(_matches(o, c, obj, img, K, dist) for o in ours) for c in theirs)
    back = all(any(_matches(o, c, obj, img, K, dist) for c in theirs) for o in ours)
    return found and back, count


def test_planar_targets_give_ippe_refined_poses():
    rng = np.random.default_rng(30)
    failed = []
    twos = 0
    for k in range(PLANAR_PROBLEMS):
        obj, img, K = planar_case(rng)
        same, count = compare_with_ippe(obj, img, K)
        if not same:
            failed.append(k)
        twos += count == 2
    # The planar partner of the answer (a reflection about the line of sight) starts
    # the search for the other minimum; where the noise makes the two minima far from
    # mirror images (near a frontal view, few points), the start can fall in the
    # answer's basin and the other minimum is missed: 1 problem of these 200 (seed 30).
    assert len(failed) <= PLANAR_PROBLEMS // 100, failed
    assert twos > PLANAR_PROBLEMS // 4  # the ambiguity is common at these distances


def test_generic_conventions_and_a_3d_model():
    rng = np.random.default_rng(31)
    obj = rng.uniform(-1, 1, (8, 3))
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    rvec, tvec = np.array([0.1, 0.2, 0.3]), np.array([0.1, -0.2, 6.0])
    img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
    img = img + rng.normal(0, 0.5, img.shape)
    count, rvecs, tvecs, errs = jp.solve_pnp_generic(obj, img, K, None)
    n_cv, r_cv, t_cv, e_cv = cv2.solvePnPGeneric(obj, img, K, None)
    assert count == n_cv == 1 and isinstance(rvecs, tuple) and rvecs[0].shape == (3, 1)
    assert errs.shape == e_cv.shape == (1, 1) and errs.dtype == np.float64
    np.testing.assert_allclose(rvecs[0], r_cv[0], atol=1e-6)
    np.testing.assert_allclose(tvecs[0], t_cv[0], atol=1e-6)
    np.testing.assert_allclose(errs, e_cv, rtol=1e-6)
    # no pose: a count of 0 and empty tuples, as OpenCV's
    bad = np.zeros_like(img)
    count, rvecs, tvecs, errs = jp.solve_pnp_generic(obj, bad, K, None)
    assert count == 0 and rvecs == () and tvecs == () and errs.shape == (0, 1)
