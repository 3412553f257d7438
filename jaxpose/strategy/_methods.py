"""The paper's single methods over every triplet of a batch of problems, batch-first: the
three-point method (Section 2.1), the small-movement linear method (Section 2.2) and
Levenberg-Marquardt (Section 2.3), each started, as in the paper's experiment (Section 4),
from every triplet's best three-point root (`jaxpose.strategy._triplets.initial_poses`).

`run_method` gives every triplet's raw outcome (the experiment reports it as it is);
`per_triplet` applies the acceptance rule of `jaxpose.strategy._accept` to it (the answer
of `jaxpose.solve` with `method` other than `"mixed"`). The linear method runs the
batch-first kernel (`linear_all`, the mixed algorithm's own), Levenberg-Marquardt the
optimistix solver of `jaxpose.solvers._nonlinear`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..geometry._pose import Observations, Pose, transform
from ..solvers._nonlinear import nonlinear
from ..solvers._residuals import in_front
from ..solvers._status import Status
from ._accept import accepts, threshold
from ._linear_runs import linear_all
from ._options import Options
from ._triplets import Initial

__all__ = ["SINGLE_METHODS", "per_triplet", "run_method"]

#: The methods run from every triplet on their own (the mixed algorithm is
#: `jaxpose.strategy._mixed`).
SINGLE_METHODS = ("three_point", "linear", "nonlinear")


def run_method(
    method: str, obs: Observations, initial: Initial, options: Options
) -> tuple[Pose, Float[Array, "B T"], Int[Array, "B T"]]:
    """Every triplet's outcome of `method` (`obs`, `initial` with a leading problem axis
    `B`; no gradient): `(pose, error, status)` of `(B, T)`. A triplet without a usable
    three-point pose keeps its three-point status; `"three_point"` reports a pose that
    puts a used match behind the camera (the three-point solver checks only its own
    triplet's depths) as `BEHIND_CAMERA`. Not converged: the run's status, its pose and
    error as the run left them."""
    usable = initial.status == Status.OK
    if method == "three_point":

        def front(o, R, t):
            return in_front(transform(Pose(R, t), o.model), o)

        ok = jax.vmap(jax.vmap(front, in_axes=(None, 0, 0)))(obs, initial.pose.R, initial.pose.t)
        status = jnp.where(usable & ~ok, Status.BEHIND_CAMERA, initial.status)
        return initial.pose, initial.error, status
    if method == "linear":
        out = linear_all(obs, initial.pose, options.linear_iterations)
    elif method == "nonlinear":
        steps = options.max_steps

        def one(o, R, t):
            return nonlinear(o, Pose(R, t), max_steps=steps)

        out = jax.vmap(jax.vmap(one, in_axes=(None, 0, 0)))(obs, initial.pose.R, initial.pose.t)
    else:
        raise ValueError(f"method must be one of {SINGLE_METHODS}, got {method!r}")
    status = jnp.where(usable, out.status, initial.status)
    return out.pose, out.error, status.astype(jnp.int32)


def per_triplet(
    obs: Observations, initial: Initial, options: Options
) -> tuple[Pose, Float[Array, "B T"], Int[Array, "B T"]]:
    """`run_method(options.method, ...)` with the acceptance rule applied: a converged
    triplet whose error is not below its problem's threshold is `REJECTED` (for
    `"three_point"` only with a given `Options.threshold`: its poses are not optimised,
    so the adaptive rule has no converged optimum to measure them against). Triplets
    with no usable pose get the largest float as error."""
    pose, error, status = run_method(options.method, obs, initial, options)
    big = jnp.finfo(error.dtype).max
    usable = initial.status == Status.OK
    converged = status == Status.OK
    if options.method == "three_point":
        if options.threshold is None:
            return pose, error, status
        thr = jnp.full_like(error, options.threshold)
    else:
        error = jnp.where(usable, error, big)
        best = jnp.min(jnp.where(converged, error, big), axis=1)
        thr = threshold(obs, best, options)[:, None]
    rejected = converged & ~accepts(converged, error, thr)
    return pose, error, jnp.where(rejected, Status.REJECTED, status).astype(jnp.int32)
