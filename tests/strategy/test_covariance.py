"""Pose covariance (`jaxpose.pose_covariance`): its convention, Monte-Carlo agreement with
the scatter of solved poses, the sigma estimate, and NaN-free degenerate inputs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose.solvers._linalg import symmetric_pinv

covariance = jax.jit(lambda C, M, I, pose, sigma: jp.pose_covariance(C, M, I, pose, sigma=sigma))
estimate = jax.jit(lambda C, M, I, pose, mask: jp.pose_covariance(C, M, I, pose, mask))
_rotvec_to_matrix = jax.jit(jp.rotvec_to_matrix)
_symmetric_pinv = jax.jit(symmetric_pinv)


@jax.jit
def _estimate_and_grad(C, M, I, pose, mask):
    """The estimated-sigma covariance and the gradient of its trace w.r.t. the image."""
    trace = lambda img: jnp.trace(jp.pose_covariance(C, M, img, pose, mask).covariance)
    return jp.pose_covariance(C, M, I, pose, mask), jax.grad(trace)(I)


def _residuals_in_convention(xi, C, M, I, R_hat, t_hat):
    """Pixel residuals at `R = exp(hat(w)) R_hat`, `t = t_hat + dt`, `xi = (w, dt)`,
    written out independently of the library's chart."""
    R = jp.rotvec_to_matrix(xi[:3]) @ R_hat
    world = M @ R.T + (t_hat + xi[3:])[None, :]
    h = world @ C[:, :3].T + C[:, 3][None, :]
    return (h[:, :2] / h[:, 2:] - I).reshape(-1)


_jacobian_in_convention = jax.jit(jax.jacfwd(_residuals_in_convention))


def _reference_covariance(C, M, I, R, t, sigma):
    J = _jacobian_in_convention(np.zeros(6), C, M, I, R, t)
    J = np.asarray(J)
    return sigma**2 * np.linalg.inv(J.T @ J)


def test_convention_is_w_then_dt_about_the_given_pose():
    """Against the Jacobian of the residuals written directly in `(w, dt)`, at poses away
    from the optimum too (the convention does not depend on where it is taken)."""
    rng = np.random.default_rng(0)
    for kind in ("ordinary", "planar", "quasi_singular"):
        s = jp.apps.random_scene(rng, 8, noise=0.7, kind=kind)
        R = np.asarray(_rotvec_to_matrix(rng.normal(scale=0.01, size=3))) @ s.R
        t = s.t + rng.normal(scale=0.01, size=3)
        out = covariance(s.camera, s.model_points, s.image_points, jp.Pose(R, t), 0.7)
        ref = _reference_covariance(s.camera, s.model_points, s.image_points, R, t, 0.7)
        assert out.covariance.shape == (6, 6) and int(out.rank) == 6
        np.testing.assert_allclose(out.covariance, ref, rtol=1e-7, atol=1e-10 * np.abs(ref).max())
        assert float(out.sigma) == 0.7


def test_sigma_estimate_is_rss_over_redundancy():
    rng = np.random.default_rng(1)
    s = jp.apps.random_scene(rng, 9, noise=1.3)
    out = estimate(s.camera, s.model_points, s.image_points, jp.Pose(s.R, s.t), np.ones(9, bool))
    h = np.c_[s.model_points @ s.R.T + s.t, np.ones(9)] @ s.camera.T
    rss = np.sum((h[:, :2] / h[:, 2:] - s.image_points) ** 2)
    assert float(out.sigma) == pytest.approx(np.sqrt(rss / (2 * 9 - 6)), rel=1e-10)
    given = covariance(s.camera, s.model_points, s.image_points, jp.Pose(s.R, s.t), out.sigma)
    np.testing.assert_allclose(out.covariance, given.covariance, rtol=1e-12)


def _monte_carlo(camera, model, clean, R, t, sigma, draws, seed):
    """Solve `draws` noisy copies of a problem (Gauss-Newton to the Eq. 8 optimum, from
    the true pose) and return their `(w, dt)` about the truth, and the sigma estimates."""
    rng = np.random.default_rng(seed)
    images = clean[None] + rng.normal(scale=sigma, size=(draws, *clean.shape))

    @jax.jit
    @jax.vmap
    def one(image):
        obs = jp.observations(camera, model, image)
        res = jp.solvers.linear(obs, jp.Pose(jnp.asarray(R), jnp.asarray(t)), iterations=8)
        w = jp.matrix_to_rotvec(res.pose.R @ R.T)
        est = jp.pose_covariance(camera, model, image, res.pose)
        return jnp.concatenate([w, res.pose.t - t]), res.status, est.sigma

    xi, status, sigma_hat = one(images)
    assert np.all(np.asarray(status) == jp.Status.OK)
    return np.asarray(xi), np.asarray(sigma_hat)


@pytest.mark.parametrize("case", ["bench", "random"])
def test_covariance_matches_monte_carlo(case):
    if case == "bench":
        b = jp.default_bench(noise=0.0)
        camera, model, clean, R, t, sigma = b.camera, b.model_points, b.clean_points, b.R, b.t, 0.8
    else:
        s = jp.apps.random_scene(np.random.default_rng(2), 7)
        camera, model, clean, R, t, sigma = s.camera, s.model_points, s.clean_points, s.R, s.t, 1.0
    predicted = np.asarray(covariance(camera, model, clean, jp.Pose(R, t), sigma).covariance)
    xi, sigma_hat = _monte_carlo(camera, model, clean, R, t, sigma, 2000, 3)
    empirical = np.cov(xi, rowvar=False)
    # variances within 15% (the sampling error of a variance over 2000 draws is 3.2%)
    ratio = np.diag(empirical) / np.diag(predicted)
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    # correlations within 0.1 (sampling error <= 0.022)
    d_emp, d_pred = np.sqrt(np.diag(empirical)), np.sqrt(np.diag(predicted))
    corr_emp = empirical / np.outer(d_emp, d_emp)
    corr_pred = predicted / np.outer(d_pred, d_pred)
    assert np.abs(corr_emp - corr_pred).max() < 0.1
    # whitened: the mean squared Mahalanobis distance is 6 (sampling error 1.3%)
    maha = np.einsum("bi,ij,bj->b", xi, np.linalg.inv(predicted), xi)
    assert np.mean(maha) == pytest.approx(6.0, rel=0.05)
    # the estimated sigma is unbiased in the mean square: E[RSS / (2n - 6)] = sigma^2
    assert np.sqrt(np.mean(sigma_hat**2)) == pytest.approx(sigma, rel=0.03)


def test_degenerate_inputs_are_finite():
    rng = np.random.default_rng(4)
    s = jp.apps.random_scene(rng, 6, noise=0.5)
    pose = jp.Pose(s.R, s.t)
    line = np.outer(np.linspace(-1, 1, 6), [1.0, 2.0, 0.5])  # all model points collinear
    h = np.c_[line @ s.R.T + s.t, np.ones(6)] @ s.camera.T
    on_line = h[:, :2] / h[:, 2:]
    every = np.ones(6, bool)
    cases = {
        "collinear": (s.camera, line, on_line, pose, every),
        "three points": (s.camera, s.model_points, s.image_points, pose, np.arange(6) < 3),
        "no points": (s.camera, s.model_points, s.image_points, pose, np.zeros(6, bool)),
        "zero camera": (np.zeros((3, 4)), s.model_points, s.image_points, pose, every),
        "identity": (
            s.camera,
            s.model_points,
            s.image_points,
            jp.Pose(np.eye(3), np.zeros(3)),
            every,
        ),
    }
    results = {}
    for name, (C, M, I, P, mask) in cases.items():
        results[name] = out, grad = _estimate_and_grad(C, M, I, P, mask)
        for leaf in (*out, grad):
            assert np.all(np.isfinite(np.asarray(leaf))), name
    assert int(results["collinear"][0].rank) == 5  # the roll about the line is undetermined
    three = results["three points"][0]
    assert float(three.sigma) == 0 and int(three.rank) == 6  # no redundancy to estimate it
    assert np.all(np.asarray(results["no points"][0].covariance) == 0)


def test_covariance_under_vmap_and_float32():
    rng = np.random.default_rng(5)
    scenes = [jp.apps.random_scene(rng, 6, noise=0.5) for _ in range(4)]
    C = np.stack([s.camera for s in scenes])
    M = np.stack([s.model_points for s in scenes])
    I = np.stack([s.image_points for s in scenes])
    poses = jp.Pose(np.stack([s.R for s in scenes]), np.stack([s.t for s in scenes]))
    run = jax.jit(jax.vmap(lambda C, M, I, P: jp.pose_covariance(C, M, I, P, sigma=0.5)))
    out64 = run(C, M, I, poses)
    out32 = run(*(x.astype(np.float32) for x in (C, M, I)), jax.tree.map(np.float32, poses))
    assert out32.covariance.dtype == jnp.float32
    np.testing.assert_allclose(
        out32.covariance,
        out64.covariance,
        rtol=2e-2,
        atol=1e-3 * np.abs(np.asarray(out64.covariance)).max(),
    )


@given(
    rank=st.integers(0, 6),
    seed=st.integers(0, 2**32 - 1),
    scale=st.floats(1e-6, 1e6),
)
def test_symmetric_pseudo_inverse(rank, seed, scale):
    """Finite for every rank, and a pseudo-inverse: A A+ A = A, A+ A A+ = A+."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(6, rank)) * rng.uniform(0.1, 10, size=6)[:, None] * scale
    A = B @ B.T
    P, r, positive = _symmetric_pinv(A)
    P = np.asarray(P)
    assert np.all(np.isfinite(P)) and int(r) == rank and bool(positive) == (rank == 6)
    tol = 1e-8 * np.abs(A).max() + 1e-300
    np.testing.assert_allclose(A @ P @ A, A, atol=tol)
    if rank:
        np.testing.assert_allclose(P @ A @ P, P, atol=1e-8 * np.abs(P).max())
