"""Tests of jaxpose.geometry._errors: pixel residuals, Eq. 8 RMS, and the paper's pose error."""

import cv2
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given

from jaxpose.geometry import _errors
from jaxpose.geometry._camera import camera_matrix


def _all_errors(C, R, t, model, image, mask):
    return {
        "residuals": _errors.reprojection_residuals(C, R, t, model, image),
        "rms": _errors.reprojection_rms(C, R, t, model, image, mask),
        "pose_error": _errors.pose_error(C, R, t, model, image, mask),
        "per_point": _errors.pose_error_per_point(C, R, t, model, image),
        "rms_unmasked": _errors.reprojection_rms(C, R, t, model, image),
        "pose_error_unmasked": _errors.pose_error(C, R, t, model, image),
    }


def _all_grads(C, R, t, model, image, mask):
    """Values and gradients of the RMS and of the pose error w.r.t. every input."""
    argnums = (0, 1, 2, 3, 4)
    return (
        jax.value_and_grad(_errors.reprojection_rms, argnums)(C, R, t, model, image, mask),
        jax.value_and_grad(_errors.pose_error, argnums)(C, R, t, model, image, mask),
    )


# Every test goes through these two compiled functions (one compilation per dtype), which
# keeps the file fast; `test_eager_matches_jit` checks the uncompiled path.
_errors_jit = jax.jit(_all_errors)
grads = jax.jit(_all_grads)


def errors(C, R, t, model, image, mask=None):
    return _errors_jit(C, R, t, model, image, np.ones(len(model), bool) if mask is None else mask)


N = 8

# --------------------------------------------------------------------------- references


def np_project(C, P):
    h = P @ C[:, :3].T + C[:, 3]
    return h[:, :2] / h[:, 2:3]


def np_pose_error_per_point(C, R, t, model, image):
    """Independent implementation: SVD null vector, solve for the ray, arccos for the angle."""
    centre_h = np.linalg.svd(C)[2][-1]
    centre = centre_h[:3] / centre_h[3]
    M = C[:, :3]
    rays = np.linalg.solve(M, np.column_stack([image, np.ones(len(image))]).T).T
    rays *= np.sign(np.linalg.det(M))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    p = model @ R.T + t
    d = np.linalg.norm(p - centre, axis=1)
    cos_a = np.clip(np.sum((p - centre) * rays, axis=1) / d, -1.0, 1.0)
    a = np.arccos(cos_a)
    return np.where(a <= np.pi / 2, d * np.sin(a), d), d, a


def make_problem(rng, noise=1.0, skew=True):
    """Camera (3, 4), pose (R, t), model (N, 3) about 2 m ahead (mm), noisy pixels (N, 2)."""
    f = rng.uniform(500, 2000)
    K = np.array(
        [
            [f, rng.uniform(-3, 3) if skew else 0.0, 384],
            [0, f * rng.uniform(0.9, 1.1), 288],
            [0, 0, 1],
        ]
    )
    R_wc, _ = cv2.Rodrigues(rng.normal(size=3) * 0.5)
    t_wc = rng.normal(size=3) * 100
    C = np.asarray(camera_matrix(K, R_wc, t_wc))
    R, _ = cv2.Rodrigues(rng.normal(size=3))
    # put the object 2 m in front of the camera: world = R_wc^T (x_cam - t_wc)
    t = R_wc.T @ (np.array([0.0, 0.0, 2000.0]) + rng.normal(size=3) * 50 - t_wc)
    model = rng.uniform(-80, 80, size=(N, 3))
    image = np_project(C, model @ R.T + t) + rng.normal(size=(N, 2)) * noise
    return C, R, t, model, image


# --------------------------------------------------------------------------- pixels

ALL = np.ones(N, dtype=bool)


@pytest.mark.parametrize("seed", range(3))
def test_residuals_and_rms_match_numpy(seed):
    rng = np.random.default_rng(seed)
    C, R, t, model, image = make_problem(rng)
    expected = np_project(C, model @ R.T + t) - image
    rms = np.sqrt(np.mean(np.sum(expected**2, axis=1)))
    for s in (1.0, -3.0, 1e-3):
        out = errors(s * C, R, t, model, image)
        np.testing.assert_allclose(out["residuals"], expected, atol=1e-9)
        assert float(out["rms"]) == pytest.approx(rms, rel=1e-10)
        assert float(out["rms_unmasked"]) == pytest.approx(rms, rel=1e-10)
    mask = rng.uniform(size=N) < 0.5
    mask[0] = True
    masked = np.sqrt(np.mean(np.sum(expected[mask] ** 2, axis=1)))
    assert float(errors(C, R, t, model, image, mask)["rms"]) == pytest.approx(masked, rel=1e-10)
    assert float(errors(C, R, t, model, image, ALL)["rms"]) == pytest.approx(rms, rel=1e-10)
    # Eq. 8 with the paper's notation: sqrt(1/N sum (du^2 + dv^2))
    du, dv = expected[:, 0], expected[:, 1]
    assert rms == pytest.approx(np.sqrt(np.sum(du**2 + dv**2) / N))


def test_all_false_mask_gives_zero():
    rng = np.random.default_rng(10)
    C, R, t, model, image = make_problem(rng)
    mask = np.zeros(N, dtype=bool)
    out = errors(C, R, t, model, image, mask)
    assert float(out["rms"]) == 0.0
    assert float(out["pose_error"]) == 0.0
    for g in jax.tree.leaves(grads(C, R, t, model, image, mask)):
        assert np.all(np.isfinite(g))
    # no points at all
    empty = errors(C, R, t, np.zeros((0, 3)), np.zeros((0, 2)))
    assert float(empty["rms_unmasked"]) == 0.0 and float(empty["pose_error_unmasked"]) == 0.0


def test_singular_camera_is_finite():
    rng = np.random.default_rng(11)
    C, R, t, model, image = make_problem(rng)
    C = C.copy()
    C[2, :3] = C[0, :3] + C[1, :3]
    out = errors(C, R, t, model, image)
    assert all(np.all(np.isfinite(v)) for v in out.values())
    # placeholder: never a deceptive zero
    assert np.all(np.asarray(out["per_point"]) > 0)


# --------------------------------------------------------------------------- pose error


@pytest.mark.parametrize("seed", range(3))
def test_pose_error_matches_arccos_reference(seed):
    rng = np.random.default_rng(20 + seed)
    C, R, t, model, image = make_problem(rng, noise=2.0)
    expected, d, a = np_pose_error_per_point(C, R, t, model, image)
    for s in (1.0, -0.5):
        out = errors(s * C, R, t, model, image)
        np.testing.assert_allclose(out["per_point"], expected, rtol=1e-6)
        assert float(out["pose_error"]) == pytest.approx(expected.mean(), rel=1e-6)
        assert float(out["pose_error_unmasked"]) == pytest.approx(expected.mean(), rel=1e-6)
    # small angles: E_i ~ d_i a_i, to second order in a_i
    per_point = np.asarray(out["per_point"])
    assert np.all(a < 0.01)
    np.testing.assert_allclose(per_point, d * a, rtol=float(np.max(a) ** 2))
    # masked mean
    mask = np.arange(N) % 2 == 0
    assert float(errors(C, R, t, model, image, mask)["pose_error"]) == pytest.approx(
        expected[mask].mean(), rel=1e-6
    )


def test_pose_error_is_distance_to_ray():
    """Moving a vertex perpendicular to its observed ray by delta gives E_i = delta."""
    rng = np.random.default_rng(30)
    C, R, t, model, image = make_problem(rng, noise=0.0)
    p = model @ R.T + t
    centre_h = np.linalg.svd(C)[2][-1]
    centre = centre_h[:3] / centre_h[3]
    ray = (p - centre) / np.linalg.norm(p - centre, axis=1, keepdims=True)
    side = np.cross(ray, rng.normal(size=(N, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    delta = rng.uniform(0.1, 3.0, size=N)
    moved_model = (p + delta[:, None] * side - t) @ R  # back to model coordinates
    np.testing.assert_allclose(errors(C, R, t, moved_model, image)["per_point"], delta, rtol=1e-7)
    # and along the ray costs nothing
    along = (p + 50.0 * ray - t) @ R
    assert np.max(errors(C, R, t, along, image)["per_point"]) < 1e-9


def test_pose_error_behind_camera_is_distance():
    """Points mirrored through the camera centre: same pixels, but E_i = d_i, not ~0."""
    rng = np.random.default_rng(40)
    C, R, t, model, image = make_problem(rng, noise=0.5)
    centre_h = np.linalg.svd(C)[2][-1]
    centre = centre_h[:3] / centre_h[3]
    # p2 = 2 o - p = R (-m) + (2 o - t): a proper rotation of the mirrored model
    mirrored_model = -model
    t2 = 2 * centre - t
    p2 = mirrored_model @ R.T + t2
    d = np.linalg.norm(p2 - centre, axis=1)
    out = errors(C, R, t2, mirrored_model, image)
    np.testing.assert_allclose(out["per_point"], d, rtol=1e-12)
    expected, _, a = np_pose_error_per_point(C, R, t2, mirrored_model, image)
    assert np.all(a > np.pi / 2)
    np.testing.assert_allclose(out["per_point"], expected, rtol=1e-9)
    # the pixel error alone cannot see it: the mirrored points project to the same pixels
    assert float(out["rms"]) == pytest.approx(float(errors(C, R, t, model, image)["rms"]))


# --------------------------------------------------------------------------- gradients


def exact_problem():
    """A pose whose residuals and pose errors are exactly zero in floating point."""
    C = np.array([[2.0, 0, 0, 0], [0, 2.0, 0, 0], [0, 0, 1.0, 0]])
    model = np.array(
        [[0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1], [-2, 0, 2], [0, -4, 4], [4, 4, 4], [0, 0, 8]],
        dtype=np.float64,
    )
    image = 2.0 * model[:, :2] / model[:, 2:3]
    return C, np.eye(3), np.zeros(3), model, image


def test_gradients_finite_at_exact_pose():
    args = exact_problem()
    out = errors(*args)
    assert np.all(np.asarray(out["residuals"]) == 0)
    assert float(out["rms"]) == 0.0
    np.testing.assert_array_equal(out["per_point"], 0.0)
    for g in jax.tree.leaves(grads(*args, ALL)):
        assert np.all(np.isfinite(g))
    # and at a realistic exact pose (residuals at rounding level)
    rng = np.random.default_rng(50)
    C, R, t, model, _ = make_problem(rng)
    image = np_project(C, model @ R.T + t)
    for g in jax.tree.leaves(grads(C, R, t, model, image, ALL)):
        assert np.all(np.isfinite(g))


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(60)
    C, R, t, model, image = make_problem(rng, noise=3.0)
    direction = rng.normal(size=3)
    h = 1e-4
    (_, g_rms), (_, g_pose) = grads(C, R, t, model, image, ALL)
    plus = errors(C, R, t + h * direction, model, image)
    minus = errors(C, R, t - h * direction, model, image)
    for g, key in ((g_rms, "rms"), (g_pose, "pose_error")):
        fd = (plus[key] - minus[key]) / (2 * h)
        assert float(g[2] @ direction) == pytest.approx(float(fd), rel=1e-5, abs=1e-9)


# --------------------------------------------------------------------------- transformations


def test_vmap_equals_loop():
    rng = np.random.default_rng(70)
    problems = [make_problem(rng) for _ in range(3)]
    batch = [np.stack(x) for x in zip(*problems, strict=True)]
    mask = np.stack([rng.uniform(size=N) < 0.7 for _ in range(3)])
    batched = jax.jit(jax.vmap(_all_errors))(*batch, mask)
    for i in range(3):
        single = errors(*problems[i], mask[i])
        for key in single:
            np.testing.assert_allclose(batched[key][i], single[key], rtol=1e-12, atol=1e-12)


def test_eager_matches_jit():
    rng = np.random.default_rng(80)
    C, R, t, model, image = make_problem(rng)
    np.testing.assert_allclose(
        _errors.reprojection_residuals(C, R, t, model, image),
        errors(C, R, t, model, image)["residuals"],
        rtol=1e-12,
        atol=1e-12,
    )


def test_float32():
    rng = np.random.default_rng(90)
    args = make_problem(rng, noise=2.0)
    args32 = [np.asarray(a, dtype=np.float32) for a in args]
    out64 = errors(*args)
    (rms32, g_rms), (pose32, g_pose) = grads(*args32, ALL)
    assert rms32.dtype == jnp.float32 and pose32.dtype == jnp.float32
    assert float(rms32) == pytest.approx(float(out64["rms"]), rel=1e-3)
    assert float(pose32) == pytest.approx(float(out64["pose_error"]), rel=1e-3)
    for g in jax.tree.leaves((g_rms, g_pose)):
        assert g.dtype == jnp.float32 and np.all(np.isfinite(g))


# --------------------------------------------------------------------------- properties


@given(
    st.integers(0, 2**32 - 1),
    st.floats(1e-3, 1e3),
    st.sampled_from([-1.0, 1.0]),
    st.floats(0.0, 20.0),
)
def test_property_scale_invariance_and_reference(seed, scale, sign, noise):
    rng = np.random.default_rng(seed)
    C, R, t, model, image = make_problem(rng, noise=noise)
    out = errors(C, R, t, model, image)
    scaled = errors(sign * scale * C, R, t, model, image)
    assert float(scaled["rms"]) == pytest.approx(float(out["rms"]), rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(scaled["per_point"], out["per_point"], rtol=1e-8, atol=1e-9)
    assert np.all(np.asarray(out["per_point"]) >= 0)
    expected, d, _ = np_pose_error_per_point(C, R, t, model, image)
    # arccos near 1 loses half the digits: the reference is good to ~sqrt(eps) * d
    np.testing.assert_allclose(out["per_point"], expected, rtol=1e-6, atol=1e-7 * d.max())
