"""Tests of jaxpose.geometry._camera: projection, decomposition, visual rays, back-projection."""

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given

from jaxpose.geometry import _camera
from jaxpose.geometry._camera import camera_matrix, undistort_pixels

N = 8  # points per problem, shared by all tests so that one compilation serves them all


def _everything(C, P, uv):
    """Every camera function at once."""
    return {
        "project": _camera.project(C, P),
        "project_with_depth": _camera.project_with_depth(C, P),
        "decompose_camera": _camera.decompose_camera(C),
        "camera_centre": _camera.camera_centre(C),
        "normalize_camera": _camera.normalize_camera(C),
        "ray_planes": _camera.ray_planes(C, uv),
        "backproject": _camera.backproject(C, uv),
    }


# One compilation per dtype (much faster than one per function, or than op-by-op dispatch);
# `test_eager_matches_jit` checks the uncompiled path.
_everything_jit = jax.jit(_everything)
_P0, _UV0 = np.zeros((N, 3)), np.zeros((N, 2))
_camera_matrix = jax.jit(camera_matrix)


def everything(C, P, uv):
    """`_everything` compiled, its outputs as numpy arrays (checked with numpy)."""
    return jax.tree.map(np.asarray, _everything_jit(C, P, uv))


def project(C, P):
    return everything(C, P, _UV0)["project"]


def project_with_depth(C, P):
    return everything(C, P, _UV0)["project_with_depth"]


def decompose_camera(C):
    return everything(C, _P0, _UV0)["decompose_camera"]


def camera_centre(C):
    return everything(C, _P0, _UV0)["camera_centre"]


def normalize_camera(C):
    return everything(C, _P0, _UV0)["normalize_camera"]


def ray_planes(C, uv):
    return everything(C, _P0, uv)["ray_planes"]


def backproject(C, uv):
    return everything(C, _P0, uv)["backproject"]


# --------------------------------------------------------------------------- fixtures


def random_intrinsics(rng, skew=False):
    fx = rng.uniform(300, 1500)
    fy = fx * rng.uniform(0.8, 1.2)
    s = rng.uniform(-5, 5) if skew else 0.0
    return np.array([[fx, s, rng.uniform(200, 500)], [0, fy, rng.uniform(150, 400)], [0, 0, 1]])


def random_camera(rng, skew=False):
    """(K, rvec, tvec, C) with a world-to-camera motion placing the origin ~5 units ahead."""
    K = random_intrinsics(rng, skew)
    rvec = rng.normal(size=3)
    tvec = rng.normal(size=3) * 0.5 + np.array([0.0, 0.0, 5.0])
    R, _ = cv2.Rodrigues(rvec)
    return K, rvec, tvec, np.asarray(_camera_matrix(K, R, tvec))


def random_scale(rng):
    return rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 100.0)


def points_in_front(rng, n=N):
    return rng.normal(size=(n, 3))


# --------------------------------------------------------------------------- projection


@pytest.mark.parametrize("seed", range(5))
def test_project_matches_cv2(seed):
    rng = np.random.default_rng(seed)
    K, rvec, tvec, C = random_camera(rng)
    P = points_in_front(rng)
    expected = cv2.projectPoints(P, rvec, tvec, K, None)[0].reshape(-1, 2)
    for scale in (1.0, random_scale(rng), -random_scale(rng)):
        np.testing.assert_allclose(project(scale * C, P), expected, rtol=0, atol=1e-9)
        uv, _ = project_with_depth(scale * C, P)
        np.testing.assert_allclose(uv, expected, rtol=0, atol=1e-9)


def test_camera_matrix_defaults():
    K = np.array([[500.0, 0, 320], [0, 510, 240], [0, 0, 1]])
    C = camera_matrix(K)
    np.testing.assert_array_equal(C, np.hstack([K, np.zeros((3, 1))]))
    assert C.shape == (3, 4)
    assert camera_matrix(np.eye(3, dtype=int)).dtype == jnp.result_type(float)


@pytest.mark.parametrize("seed", range(3))
def test_depth_sign_under_negative_scale(seed):
    rng = np.random.default_rng(seed)
    K, rvec, tvec, C = random_camera(rng)
    R, _ = cv2.Rodrigues(rvec)
    x_cam = rng.normal(size=(N, 3))
    x_cam[:, 2] = np.linspace(-4.0, 4.0, N)  # half of them behind the camera
    P = (x_cam - tvec) @ R  # world points: R^T (x - t)
    z = P @ R.T + tvec
    for scale in (1.0, 7.5, -1.0, -0.02):
        _, depth = project_with_depth(scale * C, P)
        np.testing.assert_allclose(depth, z[:, 2], rtol=1e-12, atol=1e-12)


def test_zero_depth_point_is_finite_placeholder():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    C = np.asarray(_camera_matrix(K))
    P = np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [-1.0, 0.5, 1e-300]] * 2)
    uv, depth = project_with_depth(C, P)
    assert np.all(np.isfinite(uv)) and np.all(np.isfinite(depth))
    assert np.all(np.abs(uv[0]) > 1e10)  # far off the image
    np.testing.assert_array_equal(uv[1], [0.0, 0.0])  # the centre itself
    np.testing.assert_allclose(uv[2], [820.0, 740.0])
    assert depth[0] == 0
    # gradients: see test_gradients_finite_and_correct
    # float32: no overflow either
    out32 = everything(*(x.astype(np.float32) for x in (C, P, _UV0)))
    uv32 = out32["project"]
    assert uv32.dtype == jnp.float32 and np.all(np.isfinite(uv32))
    assert np.all(np.abs(uv32[0]) > 1e5)


# --------------------------------------------------------------------------- decomposition


@pytest.mark.parametrize("seed", range(6))
def test_decompose_matches_cv2(seed):
    rng = np.random.default_rng(100 + seed)
    K, rvec, tvec, C = random_camera(rng, skew=True)
    R, _ = cv2.Rodrigues(rvec)
    scale = random_scale(rng)
    Kc, Rc, centre_h = cv2.decomposeProjectionMatrix(abs(scale) * C)[:3]
    Kc = Kc / Kc[2, 2]
    centre_c = centre_h[:3, 0] / centre_h[3, 0]
    for s in (abs(scale), -abs(scale)):
        Kj, Rj, tj, oj = decompose_camera(s * C)
        np.testing.assert_allclose(Kj, Kc, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(Rj, Rc, rtol=0, atol=1e-12)
        np.testing.assert_allclose(oj, centre_c, rtol=1e-9, atol=1e-12)
        # and the ground truth
        np.testing.assert_allclose(Kj, K, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(Rj, R, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tj, tvec, rtol=1e-9, atol=1e-12)
        assert np.linalg.det(Rj) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(Rj @ Rj.T, np.eye(3), atol=1e-13)
        assert Kj[2, 2] == 1 and Kj[0, 0] > 0 and Kj[1, 1] > 0
        np.testing.assert_array_equal(np.tril(Kj, -1), 0)


def assert_same_camera(C1, C2, atol=1e-10):
    np.testing.assert_allclose(normalize_camera(C1), normalize_camera(C2), rtol=0, atol=atol)


@pytest.mark.parametrize("seed", range(4))
def test_decompose_round_trip(seed):
    rng = np.random.default_rng(200 + seed)
    # a general camera: any 3x4 with non-singular M, any scale
    C = rng.normal(size=(3, 4)) * random_scale(rng)
    K, R, t, centre = decompose_camera(C)
    assert_same_camera(_camera_matrix(K, R, t), C, atol=1e-9)
    np.testing.assert_allclose(t, -R @ centre, atol=1e-12)
    np.testing.assert_allclose(C @ np.append(centre, 1.0), 0, atol=1e-9 * np.abs(C).max())


@pytest.mark.parametrize("seed", range(3))
def test_camera_centre_and_normalize(seed):
    rng = np.random.default_rng(300 + seed)
    K, rvec, tvec, C = random_camera(rng)
    R, _ = cv2.Rodrigues(rvec)
    s = -random_scale(rng) if seed % 2 else random_scale(rng)
    np.testing.assert_allclose(camera_centre(s * C), -R.T @ tvec, rtol=1e-10, atol=1e-12)
    Cn = np.asarray(normalize_camera(s * C))
    assert np.linalg.norm(Cn[2, :3]) == pytest.approx(1.0, abs=1e-14)
    assert np.linalg.det(Cn[:, :3]) > 0
    np.testing.assert_allclose(Cn, C, rtol=1e-12, atol=1e-9)  # C = K[R|t] is normalised
    P = rng.normal(size=(N, 3))
    np.testing.assert_allclose(P @ Cn[2, :3] + Cn[2, 3], (P @ R.T + tvec)[:, 2], atol=1e-12)


def test_singular_camera_is_finite():
    C = np.zeros((3, 4))
    C[0, :3] = [1.0, 2.0, 3.0]
    C[1, :3] = [2.0, 4.0, 6.0]
    C[2] = [0.0, 0.0, 1.0, 2.0]
    uv = np.random.default_rng(0).uniform(0, 500, size=(N, 2))
    outs = [
        camera_centre(C),
        normalize_camera(C),
        *decompose_camera(C),
        *backproject(C, uv),
        *project_with_depth(C, np.ones((N, 3))),
        *decompose_camera(np.zeros((3, 4))),
        normalize_camera(np.zeros((3, 4))),
    ]
    assert all(np.all(np.isfinite(o)) for o in outs)
    np.testing.assert_array_equal(camera_centre(C), 0)
    # gradients: see test_gradients_finite_and_correct


# --------------------------------------------------------------------------- visual rays


@pytest.mark.parametrize("seed", range(3))
def test_ray_planes_contain_projected_points(seed):
    rng = np.random.default_rng(400 + seed)
    _, _, _, C = random_camera(rng, skew=True)
    C = C * random_scale(rng)
    P = points_in_front(rng)
    uv = project(C, P)
    n1, a1, n2, a2 = ray_planes(C, uv)
    assert n1.shape == (N, 3) and a1.shape == (N,) and n2.shape == (N, 3) and a2.shape == (N,)
    for n, a in ((n1, a1), (n2, a2)):
        scale = np.linalg.norm(n, axis=1) * np.linalg.norm(P, axis=1) + np.abs(a)
        np.testing.assert_allclose(np.sum(n * P, axis=1) + a, 0, atol=1e-9 * scale.max())
        # normalised, the residual is a distance: ~1e-9 of the scene size or better
        dist = (np.sum(n * P, axis=1) + a) / np.linalg.norm(n, axis=1)
        assert np.abs(dist).max() < 1e-9
    # Eq. 5 literally
    u, v = uv[:, 0], uv[:, 1]
    np.testing.assert_allclose(n1, C[0, :3][None] - u[:, None] * C[2, :3][None], rtol=1e-13)
    np.testing.assert_allclose(a2, C[1, 3] - v * C[2, 3], rtol=1e-13)
    # a point off the ray violates them
    n1o, a1o, n2o, a2o = ray_planes(C, uv + 1.0)
    assert np.all(np.abs(np.sum(n1o * P, axis=1) + a1o) > 1e-6)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_backproject_rays_project_back(sign):
    rng = np.random.default_rng(500)
    K, rvec, tvec, C = random_camera(rng, skew=True)
    C = sign * C * 3.0
    uv = rng.uniform([0, 0], [640, 480], size=(N, 2))
    centre, d = backproject(C, uv)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(centre, camera_centre(C))
    for lam in (0.1, 1.0, 5.0, 100.0):
        p = centre[None, :] + lam * d
        uv_back, depth = project_with_depth(C, p)
        np.testing.assert_allclose(uv_back, uv, rtol=0, atol=1e-9)
        assert np.all(depth > 0)
        n1, a1, n2, a2 = ray_planes(C, uv)
        d1 = (np.sum(n1 * p, axis=1) + a1) / np.linalg.norm(n1, axis=1)
        assert np.abs(d1).max() < 1e-9 * lam + 1e-12


# --------------------------------------------------------------------------- distortion


def test_undistort_pixels():
    rng = np.random.default_rng(600)
    K, rvec, tvec, C = random_camera(rng)
    P = rng.normal(size=(N, 3)) * 0.5
    dist = np.array([-0.1, 0.02, 0.001, -0.0005, 0.0])
    distorted = cv2.projectPoints(P, rvec, tvec, K, dist)[0].reshape(-1, 2)
    ideal = np.asarray(project(C, P))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    out = undistort_pixels(distorted, K, dist, criteria=crit)
    assert isinstance(out, np.ndarray) and out.shape == (N, 2) and out.dtype == np.float64
    np.testing.assert_allclose(out, ideal, atol=1e-6)
    out_default = undistort_pixels(distorted, K, dist)
    np.testing.assert_allclose(out_default, ideal, atol=1e-2)
    out32 = undistort_pixels(distorted.astype(np.float32).reshape(-1, 1, 2), K, dist)
    assert out32.dtype == np.float32 and out32.shape == (N, 2)
    assert undistort_pixels(distorted, K, None) is distorted
    assert undistort_pixels(distorted, K, np.zeros(5)) is distorted


# --------------------------------------------------------------------------- transformations


def test_vmap_equals_loop():
    rng = np.random.default_rng(700)
    Cs = np.stack([random_camera(rng, skew=True)[3] * random_scale(rng) for _ in range(4)])
    Ps = rng.normal(size=(4, N, 3))
    uvs = rng.uniform(0, 500, size=(4, N, 2))
    batched = jax.tree.map(np.asarray, jax.jit(jax.vmap(_everything))(Cs, Ps, uvs))
    for i in range(4):
        single = everything(Cs[i], Ps[i], uvs[i])
        for b, s in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(b[i], s, rtol=1e-12, atol=1e-12)


def test_eager_matches_jit():
    rng = np.random.default_rng(800)
    C = random_camera(rng, skew=True)[3] * -2.0
    P = rng.normal(size=(N, 3))
    np.testing.assert_allclose(_camera.project(C, P), project(C, P), rtol=1e-12, atol=1e-12)


def test_float32():
    rng = np.random.default_rng(900)
    K, rvec, tvec, C = random_camera(rng, skew=True)
    P = rng.normal(size=(N, 3))
    uv = rng.uniform(0, 500, size=(N, 2))
    C32, P32, uv32 = (-C).astype(np.float32), P.astype(np.float32), uv.astype(np.float32)
    out32 = everything(C32, P32, uv32)
    for leaf in jax.tree.leaves(out32):
        assert leaf.dtype == jnp.float32 and np.all(np.isfinite(leaf))
    out64 = everything(C32.astype(np.float64), P32.astype(np.float64), uv32.astype(np.float64))
    np.testing.assert_allclose(out32["project"], out64["project"], atol=2e-3)
    K32, R32, t32, _ = out32["decompose_camera"]
    np.testing.assert_allclose(K32, K, rtol=1e-4)
    np.testing.assert_allclose(R32, cv2.Rodrigues(rvec)[0], atol=1e-5)
    np.testing.assert_allclose(t32, tvec, atol=1e-4)
    o, d = out32["backproject"]
    np.testing.assert_allclose(o, out64["camera_centre"], atol=1e-4)
    np.testing.assert_allclose(d, out64["backproject"][1], atol=1e-5)
    for a, b in zip(out32["ray_planes"], out64["ray_planes"], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-3)


def _loss(c, p):
    uv, depth = _camera.project_with_depth(c, p)
    K, R, t, o = _camera.decompose_camera(c)
    _, d = _camera.backproject(c, uv)
    n1, a1, n2, a2 = _camera.ray_planes(c, uv)
    return (
        jnp.sum(uv)
        + jnp.sum(depth)
        + jnp.sum(K)
        + jnp.sum(R * t[:, None])
        + jnp.sum(o)
        + jnp.sum(d)
        + jnp.sum(_camera.normalize_camera(c))
        + jnp.sum(n1 + n2) * 1e-3
        + jnp.sum(a1 + a2) * 1e-3
    )


def test_gradients_finite_and_correct():
    """Finite everywhere (singular and zero cameras, points at zero depth or at the centre);
    equal to central differences."""
    rng = np.random.default_rng(1000)
    C = random_camera(rng, skew=True)[3]
    P = rng.normal(size=(N, 3))
    singular = C.copy()
    singular[1, :3] = 2 * singular[0, :3]
    simple = np.asarray(_camera_matrix(np.diag([500.0, 500.0, 1.0])))
    zero_depth = np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 0.0], [-1.0, 0.5, 1e-300]] + [[1.0] * 3] * 5)
    direction = rng.normal(size=(3, 4))
    h = 1e-6
    cameras = np.stack(
        [C, C + h * direction, C - h * direction, singular, np.zeros((3, 4)), simple]
    )
    points = np.stack([P] * 5 + [zero_depth])
    values, (gc, gp) = jax.tree.map(
        np.asarray, jax.jit(jax.vmap(jax.value_and_grad(_loss, argnums=(0, 1))))(cameras, points)
    )
    assert np.all(np.isfinite(values)) and np.all(np.isfinite(gc)) and np.all(np.isfinite(gp))
    fd = (values[1] - values[2]) / (2 * h)
    assert float(np.sum(gc[0] * direction)) == pytest.approx(float(fd), rel=1e-5, abs=1e-6)


# --------------------------------------------------------------------------- properties

finite = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def cameras(draw):
    fx = draw(st.floats(100.0, 3000.0))
    fy = fx * draw(st.floats(0.5, 2.0))
    skew = draw(st.floats(-10.0, 10.0))
    cx, cy = draw(st.floats(-500.0, 1500.0)), draw(st.floats(-500.0, 1500.0))
    rvec = np.array([draw(st.floats(-3.0, 3.0)) for _ in range(3)])
    tvec = np.array([draw(finite), draw(finite), draw(st.floats(2.0, 20.0))])
    K = np.array([[fx, skew, cx], [0, fy, cy], [0, 0, 1]])
    R, _ = cv2.Rodrigues(rvec)
    scale = draw(st.sampled_from([-1.0, 1.0])) * draw(st.floats(1e-3, 1e3))
    return K, R, tvec, scale * np.asarray(_camera_matrix(K, R, tvec))


@given(cameras(), st.lists(st.tuples(finite, finite, finite), min_size=N, max_size=N))
def test_property_projection_and_depth(cam, pts):
    K, R, tvec, C = cam
    P = np.array(pts)
    x = P @ R.T + tvec
    expected = (x @ K.T)[:, :2] / x[:, 2:3]
    uv, depth = project_with_depth(C, P)
    np.testing.assert_allclose(uv, expected, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(depth, x[:, 2], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(project(C, P), uv, rtol=1e-12, atol=1e-9)


@given(cameras(), st.lists(st.tuples(finite, finite), min_size=N, max_size=N), st.floats(0.1, 50))
def test_property_backproject_round_trip(cam, pix, lam):
    K, R, tvec, C = cam
    uv = np.array(pix) * 1000.0
    centre, d = backproject(C, uv)
    uv_back, depth = project_with_depth(C, centre[None, :] + lam * d)
    np.testing.assert_allclose(uv_back, uv, rtol=1e-9, atol=1e-7)
    assert np.all(depth > 0)


@given(cameras())
def test_property_decompose(cam):
    K, R, tvec, C = cam
    Kj, Rj, tj, oj = decompose_camera(C)
    np.testing.assert_allclose(Kj, K, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(Rj, R, atol=1e-10)
    np.testing.assert_allclose(tj, tvec, atol=1e-9)
    np.testing.assert_allclose(oj, -R.T @ tvec, atol=1e-9)
