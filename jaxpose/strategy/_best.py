"""The answer alone: score every root of every triplet, refine the best few.

`solve` and its batched forms ask for one pose per problem, not for every triplet's
outcome. The mixed algorithm (`jaxpose.strategy._mixed`) runs the linear method from
every triplet and Levenberg-Marquardt wherever it fails; to find the answer it is enough
to

1. solve every selected triplet by the three-point method (up to four roots each) and
   score every root by its Eq. 8 error over all matches (cheap: one projection of the
   matches per root);
2. run the linear method (Gauss-Newton on Eq. 8) from the `refine` best roots;
3. accept as the mixed algorithm does: converged, with an error below the threshold
   (`Options.threshold`, or the adaptive one: within `rel_threshold` of the best
   converged error, never below the rounding level of exact data); the answer is the
   accepted pose of lowest error, from the triplet its root came from;
4. for a coplanar model, also refine the answer's planar-ambiguity partner and keep it
   when it converges to a lower error (as the mixed algorithm does).

A problem where none of the refined roots is accepted falls back to the whole mixed
algorithm (`fallback` below; every triplet, Levenberg-Marquardt, the retries). On the
noisy bench and the accuracy protocol's problems the best-scored roots lie in the basin
of the optimum, so the fallback is rare; its cost is paid only where it runs (a batch
gathers the problems that need it, `jaxpose.api` does).

Everything here is for one problem and fixed in shape; batches `vmap` it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry._pose import Observations, Pose
from ..solvers._components import mat_from_array, vec_from_array
from ..solvers._kernel_linear import matches_from_observations, pixel_error_kernel
from ..solvers._linear import linear
from ..solvers._residuals import rounding_level
from ..solvers._status import Status
from ._mixed import _planar_partner, mixed_from_initial, mixed_from_initial_batch
from ._options import Options
from ._triplets import best_triplet, initial_poses, select_triplets, triplet_roots

__all__ = ["Answer", "Best", "answer", "answer_batch", "best_of_roots"]


class Best(NamedTuple):
    """The answer of one problem from its best-scored roots.

    **Fields:** `pose`; `error` (Eq. 8, px); `status` (`ACCEPTED_LINEAR` when accepted,
    else the reason the best candidate failed); `triplet` (the position, in the triplets
    given, of the triplet whose root led to the answer); `accepted`.
    """

    pose: Pose
    error: Float[Array, ""]
    status: Int[Array, ""]
    triplet: Int[Array, ""]
    accepted: Bool[Array, ""]


def refine_count(options: Options, roots: int) -> int:
    """How many roots are refined: `options.refine` (`None`: 4), at most the number of
    roots."""
    return max(1, min(4 if options.refine is None else options.refine, roots))


def best_of_roots(obs: Observations, triplets: Int[ArrayLike, "T 3"], options: Options) -> Best:
    """Steps 1-4 of the module docstring for one problem (no fallback).

    **Arguments:** `obs` (one problem, without gradient: the answer's derivative is
    attached afterwards by `jaxpose.strategy._implicit.polish`); `triplets` `(T, 3)`;
    `options` (read: `min_area`, `collinear_tol`, `linear_iterations`, `threshold`,
    `rel_threshold`, `planar_partner`, `refine`).
    """
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    triplets = jnp.asarray(triplets, jnp.int32)
    T = triplets.shape[0]

    # 1. every root of every triplet, scored over all matches
    roots = jax.vmap(lambda ijk: triplet_roots(obs, ijk, options))(triplets)
    valid = roots.valid & jnp.all(obs.mask[triplets], axis=1)[:, None]  # (T, 4)
    R, t = roots.R.reshape(4 * T, 3, 3), roots.t.reshape(4 * T, 3)
    matches = matches_from_observations(jax.tree.map(lambda x: x[None], obs))
    score = pixel_error_kernel(mat_from_array(R), vec_from_array(t), matches)
    score = jnp.where(valid.reshape(-1) & jnp.isfinite(score), score, big)

    # 2. the linear method from the best few
    K = refine_count(options, 4 * T)
    _, pick = jax.lax.top_k(-score, K)
    started = score[pick] < big
    iterations = options.linear_iterations
    lin = jax.vmap(lambda R, t: linear(obs, Pose(R, t), iterations=iterations))(R[pick], t[pick])
    converged = started & (lin.status == Status.OK)
    error = jnp.where(converged, lin.error, big)

    # 3. acceptance, as the mixed algorithm's
    best = jnp.min(error)
    if options.threshold is None:
        floor = rounding_level(obs)
        thr = jnp.where(best < big, jnp.maximum(best * (1 + options.rel_threshold), floor), big)
    else:
        thr = jnp.asarray(options.threshold, dtype)
    k = jnp.argmin(error)
    accepted = converged[k] & (error[k] < thr)
    pose = Pose(lin.pose.R[k], lin.pose.t[k])
    error = lin.error[k]

    # 4. the planar partner of the answer
    if options.planar_partner:
        partner, flat = _planar_partner(obs, pose)
        other = linear(obs, partner, iterations=iterations)
        better = flat & accepted & (other.status == Status.OK) & (other.error < error)
        pose = jax.tree.map(lambda a, b: jnp.where(better, a, b), other.pose, pose)
        error = jnp.where(better, other.error, error)

    first = jnp.where(started[0], lin.status[0], Status.NO_SOLUTION)
    status = jnp.where(
        accepted, Status.ACCEPTED_LINEAR, jnp.where(converged[k], Status.REJECTED, first)
    )
    return Best(
        pose=pose,
        error=jnp.where(accepted, error, big),
        status=status.astype(jnp.int32),
        triplet=(pick[k] // 4).astype(jnp.int32),
        accepted=accepted,
    )


class Answer(NamedTuple):
    """One problem's answer before its derivative is attached: `row` (the triplet's row
    in `triplet_indices(n, max_triplets)`), `pose`, `error`, `status`."""

    row: Int[Array, ""]
    pose: Pose
    error: Float[Array, ""]
    status: Int[Array, ""]


def _exhaustive(obs: Observations, rows, triplets, options: Options) -> Answer:
    """The whole mixed algorithm over every triplet, reduced to its answer."""
    initial = initial_poses(obs, options=options, triplets=triplets)
    res = mixed_from_initial(obs, initial, options=options)
    index, _ = best_triplet(res.error, res.status)
    pose = Pose(res.pose.R[index], res.pose.t[index])
    return Answer(rows[index], pose, res.error[index], res.status[index])


def answer(obs: Observations, options: Options) -> Answer:
    """The answer of one problem: `best_of_roots`, else (none accepted) the whole mixed
    algorithm. Under `vmap` both branches run for every problem: batches use
    `answer_batch`, which runs the fallback only for the problems that need it."""
    rows, triplets = select_triplets(obs, options)
    rows = jnp.asarray(rows, jnp.int32)
    best = best_of_roots(obs, triplets, options)
    quick = Answer(rows[best.triplet], best.pose, best.error, best.status)
    return jax.lax.cond(
        best.accepted,
        lambda: quick,
        lambda: _exhaustive(obs, rows, triplets, options),
    )


def fallback_slots(B: int) -> int:
    """Problems per pass of the batch fallback: about one in sixteen, at least one."""
    return max(1, min(B, -(-B // 16)))


def answer_batch(obs: Observations, options: Options) -> Answer:
    """`answer` for a batch of problems (`obs` with a leading `B` axis).

    `best_of_roots` runs for every problem; those with no accepted root are gathered,
    `fallback_slots(B)` at a time, into the whole mixed algorithm (one batch of it per
    pass, `mixed_from_initial_batch`), until none is left: the fallback costs what the
    problems that need it cost, not the batch size."""
    B = obs.model.shape[0]
    rows, triplets = jax.vmap(lambda o: select_triplets(o, options))(obs)
    rows = jnp.broadcast_to(jnp.asarray(rows, jnp.int32), triplets.shape[:2])
    triplets = jnp.broadcast_to(jnp.asarray(triplets, jnp.int32), (B, *triplets.shape[-2:]))
    best = jax.vmap(lambda o, tr: best_of_roots(o, tr, options))(obs, triplets)
    rows_best = jnp.take_along_axis(rows, best.triplet[:, None], axis=1)[:, 0]
    start = Answer(rows_best, best.pose, best.error, best.status)
    F = fallback_slots(B)

    def pending(carry):
        need, _ = carry
        return jnp.any(need)

    def one_pass(carry):
        need, out = carry
        _, idx = jax.lax.top_k(need.astype(jnp.int32), F)
        take = need[idx]
        sub = jax.tree.map(lambda x: x[idx], obs)
        initial = jax.vmap(lambda o, tr: initial_poses(o, options=options, triplets=tr))(
            sub, triplets[idx]
        )
        res = mixed_from_initial_batch(sub, initial, options=options)
        index, _ = jax.vmap(best_triplet)(res.error, res.status)
        found = Answer(
            jnp.take_along_axis(rows[idx], index[:, None], axis=1)[:, 0],
            Pose(res.pose.R[jnp.arange(F), index], res.pose.t[jnp.arange(F), index]),
            jnp.take_along_axis(res.error, index[:, None], axis=1)[:, 0],
            jnp.take_along_axis(res.status, index[:, None], axis=1)[:, 0],
        )

        def scatter(old, new):
            keep = take.reshape((F,) + (1,) * (new.ndim - 1))
            return old.at[idx].set(jnp.where(keep, new, old[idx]))

        return need.at[idx].set(False), jax.tree.map(scatter, out, found)

    _, out = jax.lax.while_loop(pending, one_pass, (~best.accepted, start))
    return out
