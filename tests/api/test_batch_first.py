"""The batch-first path (`solve_many`, `mixed_from_initial_batch`, `triplet_budget`) and
the unrolled linear algebra under it."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxpose as jp
from jaxpose.solvers._linalg import cholesky_solve

# Jitted: one program per shape rather than one per eager operation.
_cholesky_solve = jax.jit(cholesky_solve)
_rotation_distance = jax.jit(jp.geometry.rotation_distance)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 7), rank=st.integers(0, 7))
def test_cholesky_solve_matches_numpy_and_stays_finite(seed, n, rank):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, min(rank, n)))
    M = A @ A.T
    full = min(rank, n) == n
    if full:
        M += 1e-3 * np.eye(n)
    b = rng.normal(size=n)
    x = np.asarray(_cholesky_solve(M, b))
    assert np.all(np.isfinite(x))
    if full:
        np.testing.assert_allclose(x, np.linalg.solve(M, b), rtol=1e-7, atol=1e-9)


def test_cholesky_solve_rejects_bad_shapes():
    with pytest.raises(ValueError, match="cholesky_solve"):
        cholesky_solve(jax.device_put(np.eye(3)), jax.device_put(np.ones(2)))


def test_spread_triplets_takes_the_largest_image_triangles():
    bench = jp.default_bench(seed=0)
    candidates = jp.strategy.triplet_indices(len(bench.model_points))

    @jax.jit
    def spread(C, M, I):
        return jp.strategy.spread_triplets(jp.observations(C, M, I), candidates, 10)

    rows, chosen = spread(bench.camera, bench.model_points, bench.image_points)
    uv = np.asarray(bench.image_points)[candidates]
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    np.testing.assert_array_equal(np.sort(np.asarray(rows)), np.sort(np.argsort(-area)[:10]))
    np.testing.assert_array_equal(np.asarray(chosen), candidates[np.asarray(rows)])


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_triplet_budget_is_validated(bad):
    bench = jp.default_bench(seed=0)
    with pytest.raises(ValueError, match="triplet_budget"):
        jp.solve_pnp(bench.model_points, bench.image_points, bench.K, triplet_budget=bad)


def test_solve_many_equals_vmapped_solve():
    rng = np.random.default_rng(7)
    scenes = [jp.apps.random_scene(rng, 8, noise=1.0, world_camera=False) for _ in range(6)]
    C = scenes[0].camera
    M = np.stack([s.model_points for s in scenes])
    I = np.stack([s.image_points for s in scenes])
    # One problem with a match masked out, one with a non-finite pixel.
    mask = np.ones(M.shape[:2], bool)
    mask[1, 3] = False
    I[2, 0, 0] = np.nan
    # The best roots of `triplet_budget` triplets (`select_triplets`, not the spread
    # matches), values only: a small program to compile. (The fallback, the whole mixed
    # algorithm, is compared batch-first against `vmap(solve)` on hostile input in
    # `test_fuzz.py::test_vmapped_solve_equals_solve_many`.)
    kw = dict(triplet_budget=12, fallback=False, derivative=False)
    many = jax.jit(lambda M, I, m: jp.solve_many(C, M, I, m, **kw))(M, I, mask)
    one = jax.jit(jax.vmap(lambda M, I, m: jp.solve(C, M, I, m, **kw)))(M, I, mask)
    many, one = jax.tree.map(np.asarray, many), jax.tree.map(np.asarray, one)
    np.testing.assert_array_equal(many.status, one.status)
    np.testing.assert_array_equal(many.accepted, one.accepted)
    np.testing.assert_allclose(many.pose.R, one.pose.R, atol=1e-12)
    np.testing.assert_allclose(many.pose.t, one.pose.t, atol=1e-9)
    assert not bool(many.accepted[2])
    assert np.all(np.isfinite(many.pose.R))
    # The accepted poses are the truth up to the noise.
    for b in (0, 1, 3, 4, 5):
        assert bool(many.accepted[b])
        err = _rotation_distance(many.pose.R[b], scenes[b].R)
        assert float(err) < 0.05


@pytest.mark.parametrize(
    ("camera_shape", "match"),
    [((3, 3), "camera must be a 3x4"), ((5, 3, 4), "one per problem"), ((4, 3, 3), "3x4")],
)
def test_solve_many_checks_the_camera(camera_shape, match):
    M, I = jax.device_put(np.zeros((4, 6, 3))), jax.device_put(np.zeros((4, 6, 2)))
    with pytest.raises(ValueError, match=match):
        jp.solve_many(jax.device_put(np.ones(camera_shape)), M, I)
