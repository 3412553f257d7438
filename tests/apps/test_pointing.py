"""Tests of jaxpose.apps._pointing: click -> ray -> nearest face -> 3D point (+ covariance)."""

import functools

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_difference_jacobian, opencv_optimum
from hypothesis import given, settings

import jaxpose as jp
from jaxpose.apps import PointingStatus
from jaxpose.apps._bench import random_rotation
from jaxpose.apps._pointing import Faces, face_normals, intersect_ray, pick, polyhedron_faces
from jaxpose.geometry._rotation import rotvec_to_matrix

BENCH = jp.default_bench()
FACES = polyhedron_faces(BENCH.model)
C = np.asarray(BENCH.camera)
TRUE = jp.Pose(jax.device_put(BENCH.R), jax.device_put(BENCH.t))

B = 512  # every batched call is padded to this size: one compilation per dtype
_camera_centre = jax.jit(jp.geometry.camera_centre)


_run = jax.jit(
    jax.vmap(
        lambda C, faces, R, t, uv, S_pose, S_px: pick(C, faces, jp.Pose(R, t), uv, S_pose, S_px),
        in_axes=(None, None, 0, 0, 0, None, None),
    )
)


def picks(uv, R=None, t=None, S_pose=None, S_px=None):
    """`pick` over clicks `(m, 2)` (and optionally poses `(m, 3, 3)`, `(m, 3)`), m <= B,
    through the one compiled batch (float64); returns the m hits."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    m = len(uv)
    R = np.broadcast_to(BENCH.R, (m, 3, 3)) if R is None else np.asarray(R)
    t = np.broadcast_to(BENCH.t, (m, 3)) if t is None else np.asarray(t)
    pad = lambda x: np.concatenate([x, np.repeat(x[:1], B - m, axis=0)])
    S_pose = np.zeros((6, 6)) if S_pose is None else S_pose
    S_px = np.zeros((2, 2)) if S_px is None else S_px
    out = _run(C, FACES, pad(R), pad(t), pad(uv), S_pose, S_px)
    return jax.tree.map(lambda x: np.asarray(x)[:m], out)


def pick_one(uv, pose=None, S_pose=None, S_px=None):
    R = None if pose is None else np.asarray(pose.R)[None]
    t = None if pose is None else np.asarray(pose.t)[None]
    return jax.tree.map(lambda x: x[0], picks(uv, R, t, S_pose, S_px))


def _project(C, p):
    h = C @ np.append(p, 1.0)
    return h[:2] / h[2]


def reference_hit(C, model, R, t, uv):
    """Independent numpy reference: every face's plane hit by the ray, the polygon test by
    `cv2.pointPolygonTest` in the face's own 2D coordinates, the nearest in front wins.
    Returns `(face, point, distance_to_the_face_boundary)` or `(-1, None, inf)`."""
    M, c4 = C[:, :3], C[:, 3]
    o = -np.linalg.solve(M, c4)
    d = np.linalg.solve(M, np.array([uv[0], uv[1], 1.0]))
    d *= np.sign(np.linalg.det(M))  # towards positive depth
    world = model.vertices @ R.T + t
    best = (-1, None, np.inf, np.inf)
    for f, face in enumerate(model.faces):
        P = world[list(face)]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        n /= np.linalg.norm(n)
        denom = n @ d
        if abs(denom) < 1e-12:
            continue
        lam = n @ (P[0] - o) / denom
        if lam <= 0:
            continue
        x = o + lam * d
        e1 = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
        e2 = np.cross(n, e1)
        poly = np.stack([(P - P[0]) @ e1, (P - P[0]) @ e2], axis=1).astype(np.float32)
        q = ((x - P[0]) @ e1, (x - P[0]) @ e2)
        dist = cv2.pointPolygonTest(poly.reshape(-1, 1, 2), (float(q[0]), float(q[1])), True)
        if dist >= 0 and lam < best[2]:
            best = (f, x, lam, dist)
    return best[0], best[1], best[3]


def test_faces_padding():
    assert FACES.vertices.shape == (14, 12, 3)
    assert FACES.mask.sum() == 12 * 2 + 4 * 12
    # Side faces are padded by repeating their first corner.
    side = FACES.vertices[2]
    np.testing.assert_array_equal(side[4:], np.broadcast_to(side[0], (8, 3)))


def test_middle_of_the_object_hits_the_top_face():
    centre = np.array([0.0, 0.0, 10.0]) @ BENCH.R.T + BENCH.t  # top face, model (0, 0, 10)
    uv = _project(C, centre)
    hit = pick_one(uv)
    assert int(hit.status) == PointingStatus.OK
    assert int(hit.face) == 0  # the top face
    np.testing.assert_allclose(hit.point, centre, atol=1e-9)
    np.testing.assert_allclose(hit.normal, BENCH.R[:, 2], atol=1e-12)
    normals = np.asarray(jax.jit(face_normals)(FACES, TRUE))
    np.testing.assert_allclose(normals[0], BENCH.R[:, 2], atol=1e-12)
    np.testing.assert_allclose(normals[1], -BENCH.R[:, 2], atol=1e-12)
    o = np.asarray(_camera_centre(C))
    assert float(hit.distance) == pytest.approx(np.linalg.norm(centre - o), rel=1e-12)


def test_agrees_with_reference_over_the_image():
    rng = np.random.default_rng(1)
    # Pixels over the object's image and around it.
    uv = rng.uniform([300.0, 170.0], [570.0, 340.0], size=(B, 2))
    hits = picks(uv)
    n_hit = 0
    for i in range(len(uv)):
        f, x, margin = reference_hit(C, BENCH.model, BENCH.R, BENCH.t, uv[i])
        if abs(margin) < 1e-3 and f >= 0:
            continue  # within a micrometre of an edge: either face is right
        assert int(hits.face[i]) == f
        if f < 0:
            assert int(hits.status[i]) == PointingStatus.NO_FACE
            np.testing.assert_array_equal(hits.point[i], 0)
        else:
            n_hit += 1
            assert int(hits.status[i]) == PointingStatus.OK
            np.testing.assert_allclose(hits.point[i], x, atol=1e-9)
            # The point reprojects onto the click.
            np.testing.assert_allclose(_project(C, np.asarray(hits.point[i])), uv[i], atol=1e-9)
    assert n_hit > 100
    assert len(set(np.asarray(hits.face).tolist())) >= 4  # top and several sides


def test_no_face_there():
    hit = pick_one(np.array([5.0, 5.0]), None, np.eye(6), np.eye(2))
    assert int(hit.status) == PointingStatus.NO_FACE
    assert int(hit.face) == -1
    for x in (hit.point, hit.normal, hit.covariance, hit.distance):
        np.testing.assert_array_equal(x, 0)
    assert "none of the object's faces" in PointingStatus.NO_FACE.message


def test_non_finite_input_gives_status_not_nan():
    uv = np.array([[445.0, 240.0], [np.nan, 240.0], [445.0, np.inf], [445.0, 240.0]])
    R = np.broadcast_to(BENCH.R, (4, 3, 3)).copy()
    R[3, 0, 0] = np.nan
    hits = picks(uv, R=R, S_pose=np.eye(6))
    assert hits.status.tolist() == [PointingStatus.OK] + [PointingStatus.NOT_FINITE] * 3
    for x in hits:
        assert np.all(np.isfinite(x))
    bad_cov = np.eye(6)
    bad_cov[0, 0] = np.inf
    hit = pick_one(uv[0], None, bad_cov)
    assert int(hit.status) == PointingStatus.NOT_FINITE
    assert all(np.all(np.isfinite(x)) for x in hit)


def test_object_behind_the_camera_is_not_hit():
    # Same ray, object mirrored behind the camera centre: nothing in front.
    o = np.asarray(_camera_centre(C))
    behind = jp.Pose(BENCH.R, 2 * o - BENCH.t)
    assert int(pick_one(_project(C, BENCH.t), behind).status) == PointingStatus.NO_FACE


def test_intersect_ray_nearest_face():
    ray = jax.jit(intersect_ray)
    # From above the object straight down: the top face first (the bottom is farther).
    top = np.array([0.0, 0.0, 10.0]) @ BENCH.R.T + BENCH.t
    hit = ray(top + 500 * BENCH.R[:, 2], -BENCH.R[:, 2], FACES, TRUE)
    assert int(hit.face) == 0
    np.testing.assert_allclose(hit.point, top, atol=1e-9)
    assert float(hit.distance) == pytest.approx(500.0, rel=1e-12)
    # From the object's centre, the ray leaves through the bottom face.
    hit = ray(BENCH.t, -BENCH.R[:, 2], FACES, TRUE)
    assert int(hit.face) == 1 and float(hit.distance) == pytest.approx(10.0, rel=1e-12)


def test_float32():
    uv = np.array([[445.0, 240.0], [400.0, 300.0], [520.0, 260.0]], np.float32)
    f32 = Faces(FACES.vertices.astype(np.float32), FACES.mask)
    pose32 = jp.Pose(jnp.asarray(BENCH.R, jnp.float32), jnp.asarray(BENCH.t, jnp.float32))
    run32 = jax.jit(jax.vmap(pick, in_axes=(None, None, None, 0)))
    h32 = run32(C.astype(np.float32), f32, pose32, uv)
    h64 = picks(uv)
    assert h32.point.dtype == jnp.float32
    np.testing.assert_array_equal(h32.face, h64.face)
    np.testing.assert_allclose(h32.point, h64.point, atol=0.05)  # mm, 2 m away


def test_shape_errors_name_the_argument():
    with pytest.raises(ValueError, match="pixel"):
        pick(C, FACES, TRUE, np.zeros(3))
    with pytest.raises(ValueError, match="camera"):
        pick(C[:, :3], FACES, TRUE, np.zeros(2))
    with pytest.raises(ValueError, match="pose_covariance"):
        pick(C, FACES, TRUE, np.zeros(2), np.eye(5))
    with pytest.raises(ValueError, match="pixel_covariance"):
        pick(C, FACES, TRUE, np.zeros(2), None, np.eye(3))
    with pytest.raises(ValueError, match="faces.mask"):
        pick(C, Faces(FACES.vertices, FACES.mask[:, :3]), TRUE, np.zeros(2))
    bad = jp.Polyhedron("bad", np.zeros((4, 3)), np.zeros((0, 2)), ((0, 1),))
    with pytest.raises(ValueError, match=r"model.faces\[0\]"):
        polyhedron_faces(bad)
    bad = jp.Polyhedron("bad", np.zeros((4, 3)), np.zeros((0, 2)), ((0, 1, 7),))
    with pytest.raises(ValueError, match="outside"):
        polyhedron_faces(bad)


def test_click_jacobian_matches_finite_differences():
    """With a unit click covariance, the propagated covariance is `J J^T`, `J` the
    derivative of the point with respect to the click (jax.jacfwd): against central
    differences of the picked points."""
    uv = np.array([[445.0, 240.0], [400.0, 300.0], [520.0, 260.0]])
    h = 1e-3
    shifted = np.concatenate([uv + h * e for e in np.eye(2)] + [uv - h * e for e in np.eye(2)])
    hits = picks(np.concatenate([uv, shifted]), S_px=np.eye(2))
    p = np.asarray(hits.point).reshape(5, 3, 3)  # (base, +u, +v, -u, -v) x clicks x xyz
    fd = np.stack([(p[1] - p[3]) / (2 * h), (p[2] - p[4]) / (2 * h)], axis=-1)
    np.testing.assert_allclose(hits.covariance[:3], fd @ fd.transpose(0, 2, 1), rtol=1e-6)


# --------------------------------------------------------------------------- covariance


def _perturbed(R, t, delta):
    """The pose parameterisation of the covariances: `R = exp(hat(w)) R^`, `t = t^ + dt`."""
    return rotvec_to_matrix(delta[:3]) @ R, t + delta[3:]


def test_covariance_matches_monte_carlo():
    """First-order propagation against sampling: pose and click noise, 8 x 512 samples."""
    rng = np.random.default_rng(2)
    uv = np.array([445.0, 240.0])  # on the top face
    A = np.array([2e-3, 2e-3, 2e-3, 0.5, 0.5, 0.5])[:, None] * rng.normal(size=(6, 6))
    S_pose = A @ A.T / 6
    S_px = np.array([[0.3, 0.1], [0.1, 0.2]])
    hit = pick_one(uv, None, S_pose, S_px)
    points = []
    perturbed = jax.jit(jax.vmap(_perturbed, in_axes=(None, None, 0)))
    for _ in range(8):
        deltas = rng.multivariate_normal(np.zeros(6), S_pose, size=B)
        clicks = uv + rng.multivariate_normal(np.zeros(2), S_px, size=B)
        R, t = perturbed(BENCH.R, BENCH.t, deltas)
        out = picks(clicks, np.asarray(R), np.asarray(t))
        assert np.all(np.asarray(out.face) == 0)
        points.append(np.asarray(out.point))
    empirical = np.cov(np.concatenate(points).T)
    sd = np.sqrt(np.diag(hit.covariance))
    # 4096 samples: relative standard error of a standard deviation about 1.1%.
    np.testing.assert_allclose(np.sqrt(np.diag(empirical)), sd, rtol=0.05)
    corr = empirical / np.outer(sd, sd)
    np.testing.assert_allclose(corr, np.asarray(hit.covariance) / np.outer(sd, sd), atol=0.05)


def test_pose_only_covariance_is_along_the_ray():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6)) * 1e-2
    hit = pick_one(np.array([445.0, 240.0]), None, A @ A.T)
    w, V = np.linalg.eigh(np.asarray(hit.covariance))
    assert w[1] < 1e-10 * w[2]  # rank one
    o = np.asarray(_camera_centre(C))
    ray = (np.asarray(hit.point) - o) / float(hit.distance)
    assert abs(V[:, 2] @ ray) == pytest.approx(1.0, abs=1e-9)


def _pose_covariance(bench, R, t):
    """Gauss-Newton pose covariance `sigma^2 (J^T J)^-1` in the `(w, dt)` parameterisation
    (numpy, central differences: the test's own, independent of the library's)."""

    def residuals(delta):
        Rd = cv2.Rodrigues(delta[:3])[0] @ R
        world = bench.model_points @ Rd.T + t + delta[3:]
        h = world @ bench.camera[:, :3].T + bench.camera[:, 3]
        return (h[:, :2] / h[:, 2:] - bench.image_points).ravel()

    J = central_difference_jacobian(residuals, np.zeros(6))
    return bench.noise**2 * np.linalg.inv(J.T @ J)


SEEDS = 24


@functools.cache
def _estimates():
    """For bench seeds 0..23: the Eq. 8 optimum (OpenCV's SQPnP + LM refinement) and its
    Gauss-Newton covariance."""
    out = []
    for s in range(SEEDS):
        bench = jp.default_bench(seed=s)
        R, t = opencv_optimum(bench)
        out.append((R, t, _pose_covariance(bench, R, t)))
    return out


def test_clicked_point_within_noise_propagated_tolerance():
    """On 24 noisy bench images: click the pixel of a true surface point, intersect with
    the estimated object; the error (along the ray) is within the propagated sigma."""
    estimates = _estimates()
    o = np.asarray(_camera_centre(C))
    for m in (np.array([0.0, 0.0, 10.0]), np.array([60.0, 20.0, 10.0])):  # on the top face
        truth = m @ BENCH.R.T + BENCH.t
        ray = (truth - o) / np.linalg.norm(truth - o)
        uv = np.broadcast_to(_project(C, truth), (SEEDS, 2))
        zs = []
        for s in range(SEEDS):
            R, t, cov = estimates[s]
            hit = pick_one(uv[s], jp.Pose(R, t), cov)
            assert int(hit.status) == PointingStatus.OK and int(hit.face) == 0
            err = np.asarray(hit.point) - truth
            along = err @ ray
            np.testing.assert_allclose(err, along * ray, atol=1e-9)  # on the ray
            sigma = np.sqrt(ray @ np.asarray(hit.covariance) @ ray)
            assert 0 < sigma < 20  # mm: depth along a ray 2 m long
            zs.append(along / sigma)
        zs = np.asarray(zs)
        assert np.all(np.abs(zs) < 4), zs
        # 24 independent images: mean z^2 is chi^2(24)/24, 99.9% within [0.40, 2.16].
        assert 0.4 < np.mean(zs**2) < 2.16, np.mean(zs**2)


def test_clicked_point_with_click_noise_mahalanobis():
    """Click noise too: the 3D error's Mahalanobis distance follows chi^2(3)."""
    rng = np.random.default_rng(4)
    estimates = _estimates()
    truth = np.array([0.0, 0.0, 10.0]) @ BENCH.R.T + BENCH.t
    d2 = []
    for s in range(SEEDS):
        uv = _project(C, truth) + rng.normal(scale=0.5, size=2)
        R, t, cov = estimates[s]
        hit = pick_one(uv, jp.Pose(R, t), cov, 0.25 * np.eye(2))
        err = np.asarray(hit.point) - truth
        d2.append(err @ np.linalg.solve(np.asarray(hit.covariance), err))
    d2 = np.asarray(d2)
    assert np.all(d2 < 22.0)  # chi^2(3) 99.995%
    # The mean of 24 chi^2(3) draws is chi^2(72)/24, 99.9% within [1.90, 4.46].
    assert 1.9 < np.mean(d2) < 4.46, np.mean(d2)


@settings(max_examples=25)
@given(
    seed=st.integers(0, 2**31 - 1),
    u=st.floats(250.0, 620.0),
    v=st.floats(130.0, 380.0),
)
def test_random_poses_agree_with_reference(seed, u, v):
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    t = BENCH.t + rng.normal(scale=30.0, size=3)
    hit = pick_one(np.array([u, v]), jp.Pose(R, t))
    f, x, margin = reference_hit(C, BENCH.model, R, t, np.array([u, v]))
    if abs(margin) < 1e-3 and f >= 0:
        return
    assert int(hit.face) == f
    if f >= 0:
        np.testing.assert_allclose(hit.point, x, atol=1e-8)
