"""`planar_poses`: the two poses of a coplanar model from its homography (IPPE's)."""

import cv2
import jax
import numpy as np

from jaxpose.geometry import camera_matrix, observations
from jaxpose.strategy import planar_poses


@jax.jit
def _poses(K, obj, img):
    return planar_poses(observations(camera_matrix(K), obj, img))


def _angle(Ra, Rb):
    """The angle between two rotations (rad), accurate near zero."""
    return 2 * np.arcsin(min(np.linalg.norm(Ra - Rb) / np.sqrt(8), 1.0))


def test_exact_data_give_the_true_pose_and_ippe_s_two():
    """On exact data one of the two poses is the truth; with four matches (an exact
    homography) both are `cv2.solvePnPGeneric(SOLVEPNP_IPPE)`'s. A tilted plane (not
    z = 0) and a non-square pixel grid included; a model off its plane is refused."""
    rng = np.random.default_rng(3)
    for n in (4, 4, 6, 9):
        normal = rng.normal(size=3)
        basis = np.linalg.qr(np.c_[normal, rng.normal(size=(3, 2))])[0]
        obj = rng.uniform(-1, 1, (n, 2)) @ basis[:, 1:].T + rng.normal(size=3)
        K = np.array([[900.0, 0, 300], [0, 850, 250], [0, 0, 1]])
        rvec, tvec = rng.normal(0, 0.5, 3), np.array([0.2, -0.1, 8.0])
        img = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
        P, ok = _poses(K, obj, img)
        R, t = np.asarray(P.R), np.asarray(P.t)
        assert np.all(np.asarray(ok))
        R_true = cv2.Rodrigues(rvec)[0]
        k = int(np.argmin([_angle(R[j], R_true) for j in range(2)]))
        assert _angle(R[k], R_true) < 1e-9
        np.testing.assert_allclose(t[k], tvec, atol=1e-8)
        if n == 4:
            _, rs, ts, _ = cv2.solvePnPGeneric(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
            for r_cv, t_cv in zip(rs, ts, strict=True):
                R_cv = cv2.Rodrigues(r_cv)[0]
                assert min(_angle(R[j], R_cv) for j in range(2)) < 1e-6
    obj = rng.uniform(-1, 1, (6, 3))  # not coplanar
    img = cv2.projectPoints(obj, np.zeros(3), np.array([0, 0, 5.0]), K, None)[0].reshape(-1, 2)
    assert not np.any(np.asarray(_poses(K, obj, img)[1]))
