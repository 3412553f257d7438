"""OpenCV's distortion model in JAX: projection against `cv2.projectPoints`, derivatives
against finite differences, and `solve_pnp` / `solve_pnp_batch` with `dist_coeffs` at
the image-space optimum of `cv2.solvePnPRefineLM`."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.geometry import distort, project_points, refine_in_image

K = np.array([[800.0, 0.0, 320.0], [0.0, 780.0, 240.0], [0.0, 0.0, 1.0]])

# The library's functions as the tests call them, jitted: one program per shape rather
# than one per eager operation.
_distort = jax.jit(distort)
_project_points = jax.jit(project_points)
_refine_in_image = jax.jit(refine_in_image)


def _coefficients(rng, size: int) -> np.ndarray:
    """Coefficients of a strong wide-angle lens (`k1` down to -0.4) and small others."""
    d = rng.normal(scale=0.02, size=size)
    d[0] = rng.uniform(-0.4, 0.2)
    d[2:4] = rng.normal(scale=1e-3, size=2)
    if size == 14:
        d[12:] = rng.normal(scale=0.02, size=2)
    return d


@pytest.mark.parametrize("size", [4, 5, 8, 12, 14])
def test_projection_equals_opencv(size):
    rng = np.random.default_rng(size)
    for _ in range(5):
        d = _coefficients(rng, size)
        X = rng.uniform([-1.5, -1.5, 3], [1.5, 1.5, 6], size=(30, 3))
        rvec, tvec = rng.normal(scale=0.2, size=3), rng.normal(scale=0.3, size=3)
        ref, _ = cv2.projectPoints(X, rvec, tvec, K, d)
        ours = np.asarray(_project_points(X, rvec, tvec, K, d))
        np.testing.assert_allclose(ours, ref.reshape(-1, 2), rtol=0, atol=1e-9)


def test_no_coefficients_is_the_pinhole():
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=20), rng.normal(size=20)
    xd, yd = _distort(x, y, np.zeros(5))
    np.testing.assert_array_equal(np.asarray(xd), x)
    np.testing.assert_array_equal(np.asarray(yd), y)


def test_derivatives_match_finite_differences():
    """With respect to the coefficients, the intrinsics and the pose."""
    rng = np.random.default_rng(2)
    X = rng.uniform([-1, -1, 3], [1, 1, 5], size=(8, 3))
    d0 = _coefficients(rng, 8)
    r0, t0 = rng.normal(scale=0.2, size=3), rng.normal(scale=0.2, size=3)

    @jax.jit
    def f(d, k, r, t):
        Km = jnp.array([[k[0], 0.0, k[2]], [0.0, k[1], k[3]], [0.0, 0.0, 1.0]])
        return jnp.sum(jnp.sin(project_points(X, r, t, Km, d) / 100))

    k0 = np.array([800.0, 780.0, 320.0, 240.0])
    args = [d0, k0, r0, t0]
    grads = [np.asarray(g) for g in jax.jit(jax.grad(f, argnums=(0, 1, 2, 3)))(*args)]
    for i, (a, g) in enumerate(zip(args, grads, strict=True)):
        h = 1e-6 * max(1.0, float(np.max(np.abs(a))))
        for j in range(a.shape[0]):
            e = np.zeros_like(a)
            e[j] = h
            up = [x + e if k == i else x for k, x in enumerate(args)]
            down = [x - e if k == i else x for k, x in enumerate(args)]
            fd = (float(f(*up)) - float(f(*down))) / (2 * h)
            assert float(g[j]) == pytest.approx(fd, rel=1e-5, abs=1e-7)


def _problems(rng, count: int, n: int = 12, noise: float = 1.0, lens=None):
    """Problems seen through a lens (`lens`, else a random one each, `k1` in
    [-0.4, 0.2]): object points, distorted pixels with `noise` px, coefficients."""
    out = []
    for _ in range(count):
        s = jp.apps.random_scene(rng, n, noise=0.0, world_camera=False)
        _, rvec, tvec = cv2.solvePnP(s.model_points, s.image_points, K, None)
        d = _coefficients(rng, 5) if lens is None else lens
        img, _ = cv2.projectPoints(s.model_points, rvec, tvec, K, d)
        out.append((s.model_points, img.reshape(-1, 2) + rng.normal(scale=noise, size=(n, 2)), d))
    return out


def _image_rms(obj, img, d, rvec, tvec) -> float:
    proj, _ = cv2.projectPoints(obj, np.asarray(rvec, float), np.asarray(tvec, float), K, d)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))


def _opencv_optimum(obj, img, d) -> float:
    _, rvec, tvec = cv2.solvePnP(obj, img, K, d, flags=cv2.SOLVEPNP_SQPNP)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-15)
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, d, rvec, tvec, criteria=crit)
    return _image_rms(obj, img, d, rvec, tvec)


def test_solve_pnp_reaches_the_image_space_optimum():
    rng = np.random.default_rng(3)
    for obj, img, d in _problems(rng, 12):
        ok, rvec, tvec = jp.solve_pnp(obj, img, K, d)
        assert ok
        ref = _opencv_optimum(obj, img, d)
        assert _image_rms(obj, img, d, rvec, tvec) <= ref + max(1e-6 * ref, 1e-9)


def test_solve_pnp_batch_reaches_the_image_space_optimum():
    """One lens for the whole batch (as the entry point takes it), 40 problems, the
    padding of 12 points to 16 masked out of the refinement."""
    rng = np.random.default_rng(4)
    d = _coefficients(rng, 5)
    d[0] = -0.4
    problems = _problems(rng, 40, lens=d)
    obj = np.stack([p[0] for p in problems])
    img = np.stack([p[1] for p in problems])
    ok, rvecs, tvecs = jp.solve_pnp_batch(obj, img, K, d)
    assert np.all(ok)
    for b in range(len(problems)):
        ref = _opencv_optimum(obj[b], img[b], d)
        assert _image_rms(obj[b], img[b], d, rvecs[b], tvecs[b]) <= ref + max(1e-6 * ref, 1e-9)


def test_refine_in_image_ignores_masked_matches():
    rng = np.random.default_rng(5)
    obj, img, d = _problems(rng, 1, n=10)[0]
    _, rvec, tvec = cv2.solvePnP(obj, img, K, d)
    wild = np.concatenate([img, rng.uniform(0, 640, size=(3, 2))])
    more = np.concatenate([obj, rng.uniform(-1, 1, size=(3, 3))])
    mask = np.arange(13) < 10
    with jax.enable_x64(True):
        a = _refine_in_image(K, d, obj, img, np.ones(10, bool), rvec.ravel(), tvec.ravel())
        b = _refine_in_image(K, d, more, wild, mask, rvec.ravel(), tvec.ravel())
    np.testing.assert_allclose(np.asarray(a[0]), np.asarray(b[0]), atol=1e-10)
    np.testing.assert_allclose(np.asarray(a[1]), np.asarray(b[1]), atol=1e-9)
    assert float(a[2]) == pytest.approx(_image_rms(obj, img, d, a[0], a[1]), rel=1e-9)
