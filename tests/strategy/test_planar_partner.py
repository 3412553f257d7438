"""The batch-first planar partner (component form) equals the single-problem reference,
and its coplanarity test is the reference's."""

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from jaxpose.geometry._pose import Observations, Pose, observations
from jaxpose.solvers._components import mat_from_array, mat_to_array, vec_from_array, vec_to_array
from jaxpose.strategy._planar import model_planes, planar_partner, planar_partner_batch


def _problems(rng, count: int, kind: str):
    scenes = [jp.apps.random_scene(rng, 8, noise=0.5, kind=kind) for _ in range(count)]
    C = np.stack([s.camera for s in scenes])
    M = np.stack([s.model_points for s in scenes])
    x = np.stack([s.image_points for s in scenes])
    return jax.vmap(observations)(C, M, x)


@jax.jit
def _both(obs: Observations, R, t):
    reference, flat = jax.vmap(planar_partner)(obs, Pose(R, t))
    centre, normal, coplanar = model_planes(obs.model, obs.mask)
    Rp, tp, finite = planar_partner_batch(
        obs.camera, mat_from_array(R), vec_from_array(t), centre, normal
    )
    return reference, flat, mat_to_array(Rp), vec_to_array(tp), coplanar, finite


def test_partner_batch_equals_the_reference(rng):
    for kind in ("planar", "ordinary"):
        obs = _problems(rng, 64, kind)
        # poses near the truth and far from it: any pose has a partner
        R = jax.vmap(jp.geometry.rotvec_to_matrix)(jnp.asarray(rng.normal(size=(64, 3))))
        t = jnp.asarray(rng.normal(size=(64, 3)) * 100 + [0, 0, 2000])
        (ref_R, ref_t), *rest = _both(obs, R, t)
        flat, Rp, tp, coplanar, finite = (np.asarray(a) for a in rest)
        ref_R, ref_t = np.asarray(ref_R), np.asarray(ref_t)
        np.testing.assert_array_equal(coplanar, flat)
        assert finite.all()
        assert flat.all() == (kind == "planar") and flat.any() == (kind == "planar")
        # where flat, the reference returns the partner (else the pose itself)
        np.testing.assert_allclose(Rp[flat], ref_R[flat], atol=1e-12)
        np.testing.assert_allclose(tp[flat], ref_t[flat], rtol=1e-12, atol=1e-9)
        # a rotation
        gram = np.einsum("bji,bjk->bik", Rp, Rp)
        np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-12)
