"""The answer from the best-scored roots (`Options.refine`) against the whole mixed
algorithm over every triplet (`refine=None`), and its fallback."""

import functools

import jax
import numpy as np

import jaxpose as jp
from jaxpose.strategy._best import best_of_roots, fallback_slots


def _problems(kind: str, n: int, B: int, noise: float, seed: int):
    rng = np.random.default_rng(seed)
    scenes = [jp.apps.random_scene(rng, n, noise=noise, kind=kind) for _ in range(B)]
    C = np.stack([s.camera for s in scenes])
    M = np.stack([s.model_points for s in scenes])
    I = np.stack([s.image_points for s in scenes])
    return C, M, I


@functools.cache
def _many(refine, threshold=None):
    return jax.jit(lambda C, M, I: jp.solve_many(C, M, I, refine=refine, threshold=threshold))


def test_best_roots_reach_the_answer_of_every_triplet():
    """Same pose and error as the whole mixed algorithm, problem by problem (ordinary and
    planar scenes in one batch)."""
    parts = [_problems(kind, 7, 6, noise=1.0, seed=3) for kind in ("ordinary", "planar")]
    C, M, I = (np.concatenate(x) for x in zip(*parts, strict=True))
    quick, full = _many(4)(C, M, I), _many(None)(C, M, I)
    assert np.all(np.asarray(quick.accepted) == np.asarray(full.accepted))
    np.testing.assert_allclose(quick.error, full.error, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(quick.pose.R, full.pose.R, atol=1e-7)
    np.testing.assert_allclose(quick.pose.t, full.pose.t, atol=1e-6)
    for q, f in zip(np.asarray(quick.status), np.asarray(full.status), strict=True):
        assert jp.Status.is_success(q) == jp.Status.is_success(f)


def test_fallback_runs_the_whole_mixed_algorithm():
    """With a threshold no refined root meets, every problem falls back, in passes of
    `fallback_slots(B)` problems: the outcome is the whole mixed algorithm's."""
    C, M, I = _problems("ordinary", 6, 5, noise=2.0, seed=4)
    assert fallback_slots(5) == 1  # five passes
    quick, full = _many(4, 1e-3)(C, M, I), _many(None, 1e-3)(C, M, I)
    np.testing.assert_array_equal(quick.status, full.status)
    np.testing.assert_array_equal(quick.accepted, full.accepted)
    np.testing.assert_array_equal(quick.triplet, full.triplet)
    np.testing.assert_allclose(quick.error, full.error, rtol=1e-12)


def test_best_of_roots_alone():
    """Without the fallback: the best roots are accepted on noisy ordinary problems and
    report the triplet their root came from."""
    C, M, I = _problems("ordinary", 8, 3, noise=1.0, seed=5)
    obs = jax.vmap(jp.observations)(C, M, I)
    triplets = jp.strategy.triplet_indices(8)
    best = jax.jit(jax.vmap(lambda o: best_of_roots(o, triplets, jp.Options())))(obs)
    assert np.all(np.asarray(best.accepted))
    assert np.all(np.asarray(best.status) == jp.Status.ACCEPTED_LINEAR)
    assert np.all((np.asarray(best.triplet) >= 0) & (np.asarray(best.triplet) < len(triplets)))
