"""The values-only finish of a batch (`jaxpose.strategy._answer.finish_linear_batch`)."""

import jax
import numpy as np

import jaxpose as jp
from jaxpose.geometry import Pose
from jaxpose.strategy._answer import (
    SETTLED_STEP,
    Answer,
    _finish_linear,
    fallback_slots,
    finish_linear_batch,
)


def test_every_unsettled_answer_is_finished_whatever_their_number():
    """Far more unsettled answers than a pass holds (`fallback_slots`): each is finished
    exactly as the whole batch's `steps` would finish it, the settled ones left as
    they are."""
    rng = np.random.default_rng(3)
    B = 40
    scenes = [jp.apps.random_scene(rng, 9, noise=1.0, kind="ordinary") for _ in range(B)]
    obs = jax.jit(jax.vmap(jp.observations))(
        np.stack([s.camera for s in scenes]),
        np.stack([s.model_points for s in scenes]),
        np.stack([s.image_points for s in scenes]),
        np.ones((B, 9), bool),
    )
    # answers near the truth (about 1e-5 rad off), none with an error yet
    turn = np.stack([np.asarray(jp.rotvec_to_matrix(rng.normal(0, 1e-5, 3))) for _ in range(B)])
    R = np.einsum("bij,bjk->bik", turn, np.stack([s.R for s in scenes]))
    t = np.stack([s.t for s in scenes]) + rng.normal(0, 1e-3, (B, 3))
    settled = rng.random(B) < 0.3
    found = Answer(
        triplet=np.zeros((B, 3), np.int32),
        pose=Pose(R, t),
        error=np.full(B, 1e3),
        status=np.zeros(B, np.int32),
        step=np.where(settled, SETTLED_STEP / 2, 1.0),
    )
    assert (~settled).sum() > 3 * fallback_slots(B)  # several passes
    out = jax.jit(finish_linear_batch)(obs, found)
    every = jax.jit(_finish_linear, static_argnums=2)(obs, found, 2)
    for got, want, kept in zip(
        jax.tree.leaves(out), jax.tree.leaves(every), jax.tree.leaves(found)
    ):
        got, want, kept = map(np.asarray, (got, want, kept))
        np.testing.assert_array_equal(got[~settled], want[~settled])
        np.testing.assert_array_equal(got[settled], kept[settled])
    # (the pose moves from the truth to the optimum of its noisy image: most converge)
    assert np.mean(np.asarray(out.error)[~settled] < 1e3) > 0.8
