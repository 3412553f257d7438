"""The planar ambiguity: a coplanar model seen from afar has two poses that image it
nearly alike; `planar_partner` gives the other one (the mixed algorithm and the answer
from the best roots refine it and keep the better)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..geometry._numerics import masked_centroid
from ..geometry._pose import Observations, Pose
from ..geometry._rotation import rotvec_to_matrix

__all__ = ["FLAT_TOL", "planar_partner"]

# Flatness below which a model counts as coplanar (planar partner start): RMS distance to
# its best-fit plane over its RMS extent along the plane's narrower direction.
FLAT_TOL = 1e-2


def planar_partner(obs: Observations, pose: Pose) -> tuple[Pose, Array]:
    """The planar-ambiguity partner of `pose` (one problem), and whether the model is
    coplanar (within `FLAT_TOL`).

    A plane seen from afar is imaged nearly alike in two attitudes: its normal `n` and the
    normal reflected about the line of sight `v` to its centroid `p_c`,
    `n' = 2 (n . v) v - n` (IPPE's two solutions). The partner is `pose` rotated about
    `p_c` by the rotation `Q` taking `n` to `n'` (about `n x v`, twice their angle):
    `R' = Q R`, `t' = Q (t - p_c) + p_c`. On the plane `Q` acts as the mirror through
    the plane normal to `v` at `p_c`, which an orthographic view along `v` cannot tell
    apart from the identity."""
    dtype = pose.R.dtype
    w = obs.mask.astype(dtype)
    count = jnp.maximum(jnp.sum(w), 1)
    centre = masked_centroid(obs.model, w)
    X = (obs.model - centre[None, :]) * w[:, None]
    evals, evecs = jnp.linalg.eigh(X.T @ X / count)  # ascending
    flat = (evals[0] <= FLAT_TOL**2 * evals[1]) & (evals[1] > 0) & (jnp.sum(w) >= 4)
    n = pose.R @ evecs[:, 0]
    p_c = pose.R @ centre + pose.t
    eye = jnp.finfo(dtype).eps ** 0.5
    # Camera centre `o`: `C [o 1]^T = 0`.
    o = -jnp.linalg.solve(obs.camera[:, :3], obs.camera[:, 3])
    sight = p_c - o
    v = sight / jnp.maximum(jnp.linalg.norm(sight), jnp.finfo(dtype).tiny)
    n = jnp.where(jnp.dot(n, v) < 0, -n, n)  # angle to v in [0, pi/2]
    axis = jnp.cross(n, v)
    s = jnp.linalg.norm(axis)
    angle = jnp.arctan2(s, jnp.dot(n, v))
    big = s > eye
    rotvec = jnp.where(big, 2 * angle * axis / jnp.where(big, s, 1), 2 * axis)
    Q = rotvec_to_matrix(rotvec)
    partner = Pose(Q @ pose.R, Q @ (pose.t - p_c) + p_c)
    ok = flat & jnp.all(jnp.isfinite(partner.R)) & jnp.all(jnp.isfinite(partner.t))
    return jax.tree.map(lambda a, b: jnp.where(ok, a, b), partner, pose), ok
