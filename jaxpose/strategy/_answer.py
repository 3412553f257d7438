"""A problem's answer before its finish, and the values-only finish of a batch of them.

The rungs of the pipeline (`jaxpose.strategy._best`) each give an `Answer`; for callers
that take no derivative the pipeline finishes it here (`finish_linear_batch`): a few more
steps of the paper's small-movement linear method (Section 2.2) to the stationary point of
Eq. 8, run only for the answers that are not there yet.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..geometry._pose import Observations, Pose
from ..solvers._components import Mat3, Vec3, mat_to_array, vec_to_array
from ..solvers._kernel_linear import linear_kernel, matches_from_observations
from ..solvers._status import Status

__all__ = ["SETTLED_STEP", "Answer", "fallback_slots", "finish_linear_batch", "in_passes"]


class Answer(NamedTuple):
    """One problem's answer before its derivative is attached: `triplet` (the three
    matches its start came from), `pose`, `error`, `status`, and `step`: the last step of
    the linear method that gave the pose, the largest float where unknown (a pose from
    Levenberg-Marquardt). Below `SETTLED_STEP` the pose is at the stationary point of
    Eq. 8 up to rounding, and `finish_linear_batch` leaves it as it is."""

    triplet: Int[Array, "*B 3"]
    pose: Pose
    error: Float[Array, "*B"]
    status: Int[Array, "*B"]
    step: Float[Array, "*B"]


#: An answer whose last linear step was below this is finished: the linear method
#: converges linearly, each step at most a few hundredths of the one before on the
#: accuracy protocol's problems, so the pose is then within about `1e-12` of the
#: stationary point of Eq. 8 and its error there to rounding (measured: 2048 ordinary,
#: quasi-singular and planar problems, 16 matches, 1 px noise).
SETTLED_STEP = 1e-10


def finish_linear_batch(obs: Observations, found: Answer, steps: int = 2) -> Answer:
    """The values-only finish of a batch of answers (`obs` and `found` with a leading `B`
    axis): `steps` more Gauss-Newton steps of the linear kernel from each answer not yet
    settled (`found.step` above `SETTLED_STEP`), kept where they converge and do not
    raise the Eq. 8 error beyond rounding. An answer left within a solver's tolerance
    (the linear method's `1e-4`, Levenberg-Marquardt's) goes on to the stationary point of
    Eq. 8, the optimum that `jaxpose.strategy._implicit.polish` reaches by Newton steps.
    For callers that take no derivative (`Options.derivative=False`): batch-first, no
    Hessian.

    The cost follows the answers that need it: none, nothing runs; otherwise they are
    gathered `fallback_slots(B)` at a time and finished, pass after pass, until none is
    left (on ordinary problems the first rung's five linear steps leave about one answer
    in five hundred unsettled: one pass). One linear kernel in the program, whatever
    `B`."""
    B = found.error.shape[0]
    need = ~(found.step <= SETTLED_STEP)  # (a NaN step: not settled)
    F = fallback_slots(B)
    if F >= B:
        every = functools.partial(_finish_linear, obs, steps=steps)
        return jax.lax.cond(jnp.any(need), every, lambda f: f, found)

    def run(obs, found, take):
        return _finish_linear(obs, found, steps), take

    return in_passes(need, F, run, obs, found)


def in_passes(need, F: int, run, obs: Observations, state):
    """The rows of a batch that `need` it (`(B,)` bool) through `run`, gathered `F` at a
    time, pass after pass until none is left: the one fallback mechanism of the pipeline
    (its later rungs, the values-only finish), whose cost follows the rows that need it.
    `run(obs_rows, state_rows, take)` (`take`: which of the `F` gathered rows need it;
    the others fill the pass) returns the rows' new `state` and where to keep it; `state`
    is a pytree of arrays with a leading `B` axis."""

    def pending(carry):
        return jnp.any(carry[0])

    def one_pass(carry):
        need, state = carry
        _, idx = jax.lax.top_k(need.astype(jnp.int32), F)
        take = need[idx]
        part = jax.tree.map(lambda x: x[idx], state)
        new, keep = run(jax.tree.map(lambda x: x[idx], obs), part, take)

        def scatter(old, new):
            mask = keep.reshape((F,) + (1,) * (new.ndim - 1))
            return old.at[idx].set(jnp.where(mask, new, old[idx]))

        return need.at[idx].set(False), jax.tree.map(scatter, state, new)

    return jax.lax.while_loop(pending, one_pass, (need, state))[1]


def _finish_linear(obs: Observations, found: Answer, steps: int) -> Answer:
    """`steps` linear steps from every answer of `found` (see `finish_linear_batch`)."""
    m = matches_from_observations(obs)
    R = Mat3(*(found.pose.R[..., i, j] for i in range(3) for j in range(3)))
    t = Vec3(*(found.pose.t[..., i] for i in range(3)))
    R1, t1, error, step, status = linear_kernel(R, t, m, iterations=steps)
    keep = (status == Status.OK) & (error <= found.error * (1 + 1e-9))
    pose = Pose(
        jnp.where(keep[:, None, None], mat_to_array(R1), found.pose.R),
        jnp.where(keep[:, None], vec_to_array(t1), found.pose.t),
    )
    error = jnp.where(keep, error, found.error)
    return Answer(found.triplet, pose, error, found.status, jnp.where(keep, step, found.step))


def fallback_slots(B: int, triplets: int = 1) -> int:
    """Problems per pass of a batch's later rungs: about one in sixteen, at least one,
    and at most about 8,192 triplets' worth (bounded memory whatever `B`)."""
    return max(1, min(B, -(-B // 16), max(1, 8192 // max(triplets, 1))))
