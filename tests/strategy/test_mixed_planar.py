"""The mixed algorithm on planar scenes with few matches: the planar-ambiguity partner
start, step 4's fallback to LM's converged pose, and LM's patience in the retries.

The reproducers are the trials of the synthetic protocol (`benchmarks/accuracy.py`,
planar, n = 4, sigma = 2 px) where the mixed method once missed the ML optimum: no pose
accepted (LM ran out of steps at a flat optimum, or step 4's linear run was repelled
from it), a local minimum accepted instead, or the wrong one of the planar pair."""

import json
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.strategy._planar import planar_partner

DATA = Path(__file__).parents[1] / "data" / "planar_mixed_reproducers.json"
ABS_TOL = 1e-6  # px: at the optimum (the benchmark's criterion)

# Jitted: one program per shape rather than one per eager operation.
_camera_matrix = jax.jit(jp.camera_matrix)
_observations = jax.jit(jp.observations)
_planar_partner = jax.jit(planar_partner)


@pytest.fixture(scope="module")
def reproducers():
    reps = json.loads(DATA.read_text())["reproducers"]
    K = np.asarray(reps[0]["K"])
    obj = np.asarray([r["object_points"] for r in reps])
    img = np.asarray([r["image_points"] for r in reps])
    ml = np.asarray([r["ml_rms_px"] for r in reps])
    return K, obj, img, ml


def _rms(K, obj, img, R, t):
    p = np.einsum("bij,bnj->bni", R, obj) + t[:, None, :]
    q = p @ K.T
    return np.sqrt(np.mean(np.sum((q[..., :2] / q[..., 2:] - img) ** 2, axis=-1), axis=-1))


def test_reproducers_reach_the_optimum_batch(reproducers):
    """`solve_pnp_batch` (the benchmark's path): every trial accepted, at the optimum."""
    K, obj, img, ml = reproducers
    ok, rv, tv = jp.solve_pnp_batch(obj, img, K, method="mixed")
    R = np.stack([cv2.Rodrigues(r)[0] for r in rv])
    err = _rms(K, obj, img, R, tv)
    assert ok.all()
    np.testing.assert_array_less(err, ml + ABS_TOL)


def test_planar_partner_is_an_involution(reproducers):
    """For a coplanar model the partner of the partner is the pose itself, the plane's
    centroid stays put, and its normal is reflected about the line of sight."""
    K, obj, img, _ = reproducers
    C = _camera_matrix(K)
    obs = _observations(C, obj[0], img[0])
    R0 = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    pose = jp.Pose(R0, np.array([0.2, -0.1, 6.0]))
    partner, flat = _planar_partner(obs, pose)
    back, _ = _planar_partner(obs, partner)
    partner, back = (jax.tree.map(np.asarray, p) for p in (partner, back))
    assert bool(flat)
    assert not np.allclose(partner.R, pose.R, atol=1e-3)
    np.testing.assert_allclose(back.R, pose.R, atol=1e-9)
    np.testing.assert_allclose(back.t, pose.t, atol=1e-9)
    centre = obj[0].mean(axis=0)
    np.testing.assert_allclose(partner.R @ centre + partner.t, pose.R @ centre + pose.t, atol=1e-9)


def test_planar_partner_not_for_a_solid_model(reproducers):
    """A model that is not coplanar gets no partner (the pose comes back unchanged)."""
    bench = jp.default_bench()
    obs = _observations(bench.camera, bench.model_points, bench.image_points)
    pose = jp.Pose(np.eye(3), np.zeros(3))
    partner, flat = _planar_partner(obs, pose)
    assert not bool(flat)
    np.testing.assert_array_equal(partner.R, pose.R)


def test_plane_fit_and_camera_centre_match_lapack():
    """The closed forms the planar partner uses (no LAPACK call) against numpy's
    eigen-decomposition and solve, on flat, thin and round point clouds."""
    from jaxpose.strategy._planar import camera_centre, plane_fit

    rng = np.random.default_rng(11)
    jitted_fit, centre = jax.jit(plane_fit), jax.jit(camera_centre)

    def fit(S):
        return (np.asarray(a) for a in jitted_fit(S))

    for i in range(300):
        X = rng.normal(size=(20, 3)) * np.array([1.0, rng.uniform(0.1, 1), rng.uniform(0, 1)])
        if i % 3 == 0:
            X[:, 2] = 0
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        S = (X @ Q.T).T @ (X @ Q.T) / 20
        smallest, middle, normal = fit(S)
        w, v = np.linalg.eigh(S)
        assert abs(smallest - w[0]) <= 1e-9 * w[2] and abs(middle - w[1]) <= 1e-9 * w[2]
        if w[1] - w[0] > 1e-6 * w[2]:
            assert 1 - abs(np.dot(np.asarray(normal), v[:, 0])) < 1e-9
        C = rng.normal(size=(3, 4))
        np.testing.assert_allclose(C @ np.append(centre(C), 1), 0, atol=1e-12)
    smallest, middle, normal = fit(2 * np.eye(3))  # round: any unit normal
    assert smallest == middle == 2 and abs(np.linalg.norm(normal) - 1) < 1e-15
