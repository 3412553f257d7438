"""Start from a given pose: the paper's small-movement linear method (Section 2.2) from a
pose the caller already has (the previous frame of a video, a robot's odometry,
`cv2.solvePnP`'s `useExtrinsicGuess`), instead of the three-point roots of step 1.

The given pose takes the place of step 1's outcome, as one "triplet" per problem
(`start_initial`), and the mixed algorithm's steps 2-4 run from it unchanged
(`mixed_from_initial_batch`: the linear method, accepted by the rule of
`jaxpose.strategy._accept`; Levenberg-Marquardt where it does not reach an accepted
pose; the linear method again), or the single method of `Options.method` (`"linear"`,
`"nonlinear"`: `per_triplet`; `"three_point"`: the given pose as it is). The retries
that leave the start (other three-point roots, the planar partner) are off: the answer
is the local one, near the given pose. The pipeline's finish (the polish to the Eq. 8
optimum, the derivative, the statuses) follows as for any answer.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ..geometry._pose import Observations, Pose
from ..solvers._residuals import pose_error
from ..solvers._status import Status
from ._answer import Answer
from ._best import _chosen
from ._methods import per_triplet
from ._mixed import mixed_from_initial_batch
from ._options import Options
from ._triplets import Initial

__all__ = ["answer_from_start", "start_initial"]


def start_initial(obs: Observations, start: Pose) -> Initial:
    """Step 1's outcome for a batch whose start is given (`obs` and `start` with a
    leading `B` axis): one candidate per problem, the given pose with its Eq. 8 error,
    status `OK`, no other roots; its `triplets` are `(0, 1, 2)` (no triplet led to it)."""
    B = obs.mask.shape[0]
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    R = jnp.asarray(start.R, dtype).reshape(B, 1, 3, 3)
    t = jnp.asarray(start.t, dtype).reshape(B, 1, 3)
    error = jax.vmap(lambda R, t, o: pose_error(Pose(R, t), o))(R[:, 0], t[:, 0], obs)
    error = jnp.where(jnp.isfinite(error), error, big)[:, None]
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (B, 1, 3, 3, 3))
    return Initial(
        pose=Pose(R, t),
        error=error,
        status=jnp.full((B, 1), Status.OK, jnp.int32),
        triplets=jnp.broadcast_to(jnp.arange(3, dtype=jnp.int32), (B, 1, 3)),
        alt_pose=Pose(eye, jnp.zeros((B, 1, 3, 3), dtype)),
        alt_error=jnp.full((B, 1, 3), big, dtype),
    )


def answer_from_start(obs: Observations, start: Pose, options: Options) -> Answer:
    """Each problem's answer from its given pose (`obs`, `start` with a leading `B`
    axis; no gradient): see the module docstring."""
    initial = start_initial(obs, start)
    if options.method == "mixed":
        local = dataclasses.replace(options, second_chance_budget=0, planar_partner=False)
        res = mixed_from_initial_batch(obs, initial, options=local)
        pose, error, status = res.pose, res.error, res.status
    else:
        pose, error, status = per_triplet(obs, initial, options)
    return _chosen(initial, pose, error, status)[0]
