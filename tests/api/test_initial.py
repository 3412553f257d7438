"""Starting from a given pose (`solve_pnp(..., rvec, tvec, use_extrinsic_guess=True)`,
`jaxpose.solve(..., initial=Pose)`): the paper's small-movement linear method from it
(Section 2.2), compared with `cv2.solvePnP(useExtrinsicGuess=True)` on fresh noisy
problems; another guess compiles nothing."""

import cv2
import jax
import numpy as np
import pytest

import jaxpose as jp


def _problem(rng, n=10, noise=0.5):
    obj = rng.uniform(-1, 1, (n, 3))
    K = np.array([[800.0, 0, 320], [0, 780, 240], [0, 0, 1]])
    rvec = rng.normal(0, 0.4, 3)
    tvec = np.array([*rng.normal(0, 0.3, 2), rng.uniform(5, 8)])
    img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
    return obj, img + rng.normal(0, noise, img.shape), K, rvec, tvec


def _compiles():
    seen = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            seen.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    return seen, listen


def test_extrinsic_guess_matches_opencv():
    rng = np.random.default_rng(20)
    for _ in range(12):
        obj, img, K, rvec, tvec = _problem(rng)
        r0 = rvec + rng.normal(0, 0.05, 3)
        t0 = tvec + rng.normal(0, 0.1, 3)
        ok, r, t = jp.solve_pnp(obj, img, K, None, r0.reshape(3, 1), t0, True)
        ok_cv, r_cv, t_cv = cv2.solvePnP(obj, img, K, None, r0.copy(), t0.copy(), True)
        assert ok and ok_cv and r.shape == (3, 1) and t.shape == (3, 1)
        np.testing.assert_allclose(r, r_cv, atol=1e-6)
        np.testing.assert_allclose(t, t_cv, atol=1e-6)


def test_another_guess_compiles_nothing():
    rng = np.random.default_rng(21)
    obj, img, K, rvec, tvec = _problem(rng)
    C = np.hstack([K, np.zeros((3, 1))])
    jp.solve_pnp(obj, img, K, None, rvec, tvec, True)
    jp.solve(C, obj, img, initial=jp.Pose(cv2.Rodrigues(rvec)[0], tvec))
    seen, listen = _compiles()
    try:
        for k in range(3):
            r0, t0 = rvec + 0.02 * k, tvec - 0.05 * k
            ok, r, t = jp.solve_pnp(obj, img, K, None, r0, t0, True)
            sol = jp.solve(C, obj, img, initial=jp.Pose(cv2.Rodrigues(r0)[0], t0))
            assert ok and bool(sol.accepted)
            np.testing.assert_allclose(np.asarray(sol.pose.t), t.ravel(), atol=1e-8)
        assert not seen
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def test_the_start_is_local_on_a_planar_target():
    """A planar target has two local optima: each start gives the one near it, as
    OpenCV's iterative method from the same start does."""
    rng = np.random.default_rng(22)
    obj = np.c_[rng.uniform(-1, 1, (6, 2)), np.zeros(6)]
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    found = 0
    for _ in range(30):
        rvec, tvec = rng.normal(0, 0.5, 3), np.array([0, 0, 12.0])
        img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
        img = img + rng.normal(0, 1.0, img.shape)
        n, rs, ts, errs = cv2.solvePnPGeneric(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
        if n < 2 or errs[1, 0] > 2 * errs[0, 0] + 1:
            continue
        found += 1
        for r0, t0 in zip(rs, ts, strict=True):
            _, r_cv, t_cv = cv2.solvePnP(obj, img, K, None, r0.copy(), t0.copy(), True)
            ok, r, t = jp.solve_pnp(obj, img, K, None, r0, t0, True)
            assert ok
            # the same local optimum, at an error no higher than OpenCV's (near the
            # planar ambiguity the valley is flat: OpenCV's iterations stop up to 5e-4
            # rad short of its bottom, at a higher error)
            np.testing.assert_allclose(r, r_cv, atol=2e-3)
            np.testing.assert_allclose(t, t_cv, atol=2e-2)
            assert _error(obj, img, K, r, t) <= _error(obj, img, K, r_cv, t_cv) * (1 + 1e-9)
    assert found >= 3


def _error(obj, img, K, r, t):
    proj = cv2.projectPoints(obj, r, t, K, None)[0].reshape(-1, 2)
    return np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1)))


def test_guess_arguments_are_checked():
    rng = np.random.default_rng(23)
    obj, img, K, rvec, tvec = _problem(rng)
    with pytest.raises(ValueError, match="rvec"):
        jp.solve_pnp(obj, img, K, None, None, tvec, True)
    with pytest.raises(ValueError, match="tvec"):
        jp.solve_pnp(obj, img, K, None, rvec, [0.0, np.nan, 1.0], True)
    with pytest.raises(ValueError, match="use_extrinsic_guess"):
        jp.solve_pnp(obj, img, K, None, rvec, tvec, "yes")
    C = np.hstack([K, np.zeros((3, 1))])
    with pytest.raises(ValueError, match="initial"):
        jp.solve(C, obj, img, initial=jp.Pose(np.eye(3), np.zeros(2)))
    # without the flag the guess is ignored, as OpenCV ignores it
    ok, r, _ = jp.solve_pnp(obj, img, K, None, rvec + 1.0, tvec, False)
    assert ok and np.allclose(r, jp.solve_pnp(obj, img, K)[1])
