"""The linear method in production: `jaxpose.solvers._kernel_linear.linear_kernel` (the
small-movement method of the paper's Section 2.2, in component form) run from given poses, as
`LinearResult`s of arrays; its reference is `jaxpose.solvers.linear`. Step 2 of the mixed
algorithm (`linear_all`), its steps 2 and 4 (`jaxpose.strategy._mixed.job`), the paper's
single linear method (`jaxpose.strategy._methods`) and robust mode's refinement
(`linear_from`) run it."""

from __future__ import annotations

import jax

from ..geometry._pose import Observations, Pose
from ..solvers._components import (
    Mat3,
    Vec3,
    mat_from_array,
    mat_to_array,
    vec_from_array,
    vec_to_array,
)
from ..solvers._kernel_linear import Matches, in_chunks, linear_kernel, matches_from_observations
from ..solvers._linear import LinearResult

__all__ = ["LINEAR_PASS", "linear_all", "linear_block", "linear_from"]

# Linear runs per pass of step 2 (`linear_all`): the kernel's intermediates stay in the
# cache.
LINEAR_PASS = 4096


def linear_block(R: Mat3, t: Vec3, matches: Matches, iterations: int) -> LinearResult:
    """`linear_kernel` from poses of batch shape `S` against `matches` broadcast to it,
    as a `LinearResult` of arrays (`pose.R` `S + (3, 3)`)."""
    R, t, error, step, status = linear_kernel(R, t, matches, iterations)
    return LinearResult(Pose(mat_to_array(R), vec_to_array(t)), error, step, status)


def linear_from(obs: Observations, pose: Pose, iterations: int) -> LinearResult:
    """The linear method in production (`linear_kernel`) from `pose` on `obs`, one
    problem or a batch (the same leading axes): the values of
    `jaxpose.solvers.linear(obs, pose, iterations=iterations)`, its reference."""
    m = matches_from_observations(obs)
    return linear_block(mat_from_array(pose.R), vec_from_array(pose.t), m, iterations)


def linear_all(obs: Observations, poses: Pose, iterations: int) -> LinearResult:
    """Step 2: the linear method from every triplet's pose of every problem (`(B, T)`),
    the values of `linear(obs[b], poses[b, k], iterations=iterations)` computed by the
    batch-first kernel (`linear_kernel`), in cache-sized passes of about `LINEAR_PASS`
    runs: whole problems at a time, or, for a problem with more triplets than a pass, its
    triplets in passes."""
    B, T = poses.t.shape[:2]
    matches = matches_from_observations(jax.tree.map(lambda x: x[:, None], obs))  # (B, 1)
    R, t = mat_from_array(poses.R), vec_from_array(poses.t)  # (B, T)

    def run(R, t, m):
        return linear_block(R, t, m, iterations)

    if T <= LINEAR_PASS:
        return in_chunks(run, R, t, matches, size=max(1, LINEAR_PASS // max(T, 1)))
    size = -(-T // -(-T // LINEAR_PASS))  # near-equal passes

    def one_problem(a):
        R, t, m = a
        m = jax.tree.map(lambda x: x[0], m)  # (1,): broadcast to the triplets
        return in_chunks(lambda R, t: run(R, t, m), R, t, size=size)

    return jax.lax.map(one_problem, (R, t, matches))
