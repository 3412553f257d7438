"""The answer alone: score every root of a few well-spread triplets, refine the best few.

`solve` and its batched forms ask for one pose per problem, not for every triplet's
outcome. The mixed algorithm (`jaxpose.strategy._mixed`) runs the linear method from
every triplet and Levenberg-Marquardt wherever it fails; to find the answer it is enough
to

1. choose the triplets: those of the `Options.spread_points` matches farthest apart in
   the image (`spread_matches`, farthest-point sampling: `C(k, 3)` triplets, 4 for
   `k = 4`; no `C(n, 3)` areas built or sorted), or, with `spread_points=None` or a
   `triplet_budget`, those of `select_triplets`;
2. solve them by the three-point method (up to four roots each) and score every root by
   its Eq. 8 error over all matches (one projection of the matches per root);
3. run the linear method (Gauss-Newton on Eq. 8) from the `refine` best *distinct* roots
   (`distinct_best`: a root within `DISTINCT_ANGLE` of one already chosen is the same
   start, many triplets give it);
4. accept as the mixed algorithm does: converged, with an error below the threshold
   (`Options.threshold`, or the adaptive one: within `rel_threshold` of the best
   converged error, never below the rounding level of exact data); the answer is the
   accepted pose of lowest error;
5. for a coplanar model, also refine the answer's planar-ambiguity partner and keep it
   when it converges to a lower error (as the mixed algorithm does).

A problem where none of the refined roots is accepted escalates (`escalation`): first
to the mixed algorithm's steps 2-4 from the best roots of more triplets (those of the
`Options.wider_spread` matches farthest apart, `WIDER_REFINE` of them; only for problems
with more matches than that), then to the whole mixed algorithm (every triplet of
`select_triplets`, Levenberg-Marquardt, the retries). On noisy problems the best-scored
roots lie in the basin of the optimum, so escalation is rare (about one problem in
10^4 of the synthetic protocol and of the bench's model at random poses), and each rung
costs what its problems cost: `answer_batch` gathers the problems that need it, a few
at a time. (Measured on an AMD EPYC: of 3 x 10^4 problems each of the bench's model at
random poses and of planar scenes, n = 16, the first rung left 3, and the wider rung
settled all three at the optimum the whole algorithm reaches; on 3,000 noisy problems
each of n = 13 and 16, ordinary and planar, the ladder's answer was nowhere above the
whole algorithm's.)

Steps 2-5 are `jaxpose.strategy._best_roots`'s: batch-first kernels in component form
(`jaxpose.solvers._kernel_p3p`, `_kernel_linear`) over a leading problem axis, in blocks
of problems sized for the cache.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry._pose import Observations, Pose
from ._answer import SETTLED_STEP, Answer, fallback_slots, finish_linear_batch, in_passes
from ._best_roots import Best, best_of_roots_batch
from ._jobs import CHUNK
from ._methods import per_triplet
from ._mixed import mixed_from_initial_batch
from ._options import Options
from ._triplets import (
    best_triplet,
    initial_poses,
    select_triplets,
    triplet_count,
    triplet_indices,
)

__all__ = [
    "Answer",
    "SETTLED_STEP",
    "WIDER_REFINE",
    "answer",
    "answer_batch",
    "answer_triplets",
    "escalation",
    "finish_linear_batch",
    "rung_applies",
    "spread_matches",
]

#: Roots refined by the second rung of `escalation` (at least; the best roots of the
#: triplets of `Options.wider_spread` matches).
WIDER_REFINE = 8


def spread_matches(
    image: Float[ArrayLike, "B n 2"], mask: Bool[ArrayLike, "B n"], k: int
) -> Int[Array, "B k"]:
    """The `k` used matches of each problem farthest apart in the image: the one farthest
    from the centroid of the used pixels, then, `k - 1` times, the one farthest from those
    already chosen (farthest-point sampling; `O(n k)`). With fewer than `k` used matches,
    some are chosen twice (their triplets are then degenerate and give no root)."""
    image, mask = jnp.asarray(image), jnp.asarray(mask)
    u, v = image[..., 0], image[..., 1]
    w = mask.astype(image.dtype)
    count = jnp.maximum(jnp.sum(w, axis=-1, keepdims=True), 1)
    cu = jnp.sum(u * w, axis=-1, keepdims=True) / count
    cv = jnp.sum(v * w, axis=-1, keepdims=True) / count
    gap = (u - cu) ** 2 + (v - cv) ** 2
    chosen = []
    for j in range(k):
        pick = jnp.argmax(jnp.where(mask, gap, -1), axis=-1)
        chosen.append(pick)
        pu = jnp.take_along_axis(u, pick[:, None], axis=-1)
        pv = jnp.take_along_axis(v, pick[:, None], axis=-1)
        away = (u - pu) ** 2 + (v - pv) ** 2
        gap = away if j == 0 else jnp.minimum(gap, away)
    return jnp.stack(chosen, axis=-1).astype(jnp.int32)


def answer_triplets(obs: Observations, options: Options) -> Int[Array, "B T 3"]:
    """Step 1 for a batch of problems (`obs` with a leading `B` axis): the triplets of
    `spread_matches` (all `C(n, 3)` when `n <= spread_points`), or, with
    `spread_points=None` or a `triplet_budget`, those of `select_triplets`."""
    B, n = obs.mask.shape
    k = options.spread_points
    if k is None or options.triplet_budget is not None:
        _, triplets = jax.vmap(lambda o: select_triplets(o, options))(obs)
        return jnp.broadcast_to(jnp.asarray(triplets, jnp.int32), (B, *triplets.shape[-2:]))
    if n <= k:
        return jnp.broadcast_to(jnp.asarray(triplet_indices(n)), (B, math.comb(n, 3), 3))
    chosen = spread_matches(obs.image, obs.mask, k)
    return chosen[:, triplet_indices(k)]


def _quick(best: Best) -> Answer:
    return Answer(best.triplet, best.pose, best.error, best.status, best.step)


def escalation(options: Options) -> tuple[Options, ...]:
    """The rungs a problem climbs until one accepts a pose (the mixed method with
    `refine`): the best roots of the spread triplets (`options` without fallback); where
    `spread_points` chose fewer than `wider_spread` matches, the mixed algorithm's steps
    2-4 (`refine_with="mixed"`) from the `max(refine, WIDER_REFINE)` best roots of the
    triplets of `wider_spread` matches (run only where `rung_applies`); the whole mixed
    algorithm (`refine=None`). Each rung is a single rung (`fallback=False`, or
    `refine=None`): `escalation` of it is itself. Other methods, `refine=None` or
    `fallback=False`: `(options,)`. A problem not accepted by one rung runs the next;
    the last rung's answer stands."""
    if options.method != "mixed" or options.refine is None or not options.fallback:
        return (options,)
    first = dataclasses.replace(options, fallback=False)
    rungs = [first]
    k, wide = options.spread_points, options.wider_spread
    if k is not None and wide is not None and k < wide and options.triplet_budget is None:
        refine = max(options.refine, WIDER_REFINE)
        rungs.append(
            dataclasses.replace(first, spread_points=wide, refine=refine, refine_with="mixed")
        )
    rungs.append(dataclasses.replace(options, refine=None))
    return tuple(rungs)


def initial_batch(obs: Observations, options: Options):
    """Step 1 of the mixed algorithm for a batch (`obs` with a leading `B` axis, no
    gradient): the triplets of `select_triplets` and their best three-point roots
    (`initial_poses`), in passes of about `CHUNK` triplets."""
    B, n = obs.mask.shape

    def one(o):
        _, triplets = select_triplets(o, options)
        return initial_poses(o, options=options, triplets=triplets)

    T = triplet_count(n, options)
    return jax.lax.map(one, obs, batch_size=max(1, min(B, CHUNK // max(T, 1))))


def _chosen(initial, pose: Pose, error, status) -> tuple[Answer, Bool[Array, " B"]]:
    """Each problem's answer among its triplets' outcomes (`best_triplet`)."""
    index, accepted = jax.vmap(best_triplet)(error, status)
    rows = jnp.arange(error.shape[0])
    found = Answer(
        initial.triplets[rows, index],
        Pose(pose.R[rows, index], pose.t[rows, index]),
        error[rows, index],
        status[rows, index],
        jnp.full(error.shape[:1], jnp.finfo(error.dtype).max, error.dtype),  # (not known)
    )
    return found, accepted


def rung_applies(options: Options, used):
    """Whether a rung of `escalation` runs for problems of `used` matches (numpy or JAX
    counts): the middle rung (`refine_with="mixed"`) only where it leaves triplets out
    (more than `spread_points` matches). On fewer it would be the whole mixed algorithm
    without its retries (the second chance, the planar partner's own steps 2-4): measured
    on 3,000 noisy problems of each n = 4, 5, 6 (ordinary and planar), it then stopped
    above the optimum on 50 of the 674 problems it ran; such problems go on to the whole
    algorithm."""
    if options.refine_with == "mixed" and options.spread_points is not None:
        return used > options.spread_points
    return used >= 0


def _rung(obs: Observations, options: Options) -> tuple[Answer, Bool[Array, " B"]]:
    """One rung for a batch: its answers and which are accepted. A single method
    (`Options.method` other than `"mixed"`): its run from every triplet, the best
    accepted; the mixed method with `refine=None`: the whole mixed algorithm; with
    `refine`: the best roots of the spread triplets."""
    if options.method != "mixed":
        initial = initial_batch(obs, options)
        return _chosen(initial, *per_triplet(obs, initial, options))
    if options.refine is None:
        initial = initial_batch(obs, options)
        res = mixed_from_initial_batch(obs, initial, options=options)
        return _chosen(initial, res.pose, res.error, res.status)
    best = best_of_roots_batch(obs, answer_triplets(obs, options), options)
    return _quick(best), best.accepted


def _rung_triplets(options: Options, n: int) -> int:
    """Triplets per problem of a rung (sizes its gathering passes)."""
    if options.refine is None or options.method != "mixed":
        return triplet_count(n, options)
    k = options.spread_points
    return math.comb(min(n, k), 3) if k is not None else len(triplet_indices(n))


def answer(obs: Observations, options: Options) -> Answer:
    """`answer_batch` for one problem (`obs` without a batch axis)."""
    one = jax.tree.map(lambda a: jnp.asarray(a)[None], obs)
    return jax.tree.map(lambda a: a[0], answer_batch(one, options))


def answer_batch(obs: Observations, options: Options) -> Answer:
    """The answer of each problem of a batch (`obs` with a leading `B` axis; no
    gradient) by `options.method`: for the mixed method with `refine`, the rungs of
    `escalation`; otherwise the one rung of the method (`_rung`).

    The first rung of `escalation` runs for every problem; the problems it leaves are
    gathered, `fallback_slots(B, T)` at a time, into the next rung (one batch of it per
    pass) until none is left, and so on: each rung costs what the problems that need it
    cost, not the batch size. `options.fallback=False`: the first rung alone (as in
    `answer`)."""
    B, n = obs.mask.shape
    rungs = escalation(options)
    out, accepted = _rung(obs, rungs[0])
    for k, rung in enumerate(rungs[1:], start=1):
        F = fallback_slots(B, _rung_triplets(rung, n))
        last = k + 1 == len(rungs)

        def run(obs_rows, state_rows, take, rung=rung, last=last):
            del state_rows  # (a rung starts afresh)
            found, ok = _rung(obs_rows, rung)
            # the last rung's answer stands; an earlier one's only where it accepts
            return (found, ok), (take if last else take & ok)

        def gather(state, run=run, F=F):
            return in_passes(state[0], F, run, obs, state[1])

        need = ~accepted & rung_applies(rung, jnp.sum(obs.mask, axis=1))
        # (The loop inside a `cond`: XLA hoists the loop-invariant part of a rung's work
        # out of a `while_loop` and would run it on every call, needed or not, 4 ms for
        # one problem; a branch not taken runs nothing.)
        carry = (need, (out, accepted))
        out, accepted = jax.lax.cond(jnp.any(need), gather, lambda c: c[1], carry)
    return out
