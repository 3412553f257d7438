"""The mixed algorithm (the paper's Section 3) over all triplets of a problem at once.

For every triplet of matches, as one fixed-shape batch:

1. three-point method: up to four poses; keep the one with the lowest Eq. 8 error over
   all matches;
2. linear method from it; converged with `e < threshold`: accepted (`ACCEPTED_LINEAR`);
3. otherwise Levenberg-Marquardt, started from the linear result when that lowered the
   error and from the three-point pose when it did not (a linear run stuck far away is
   a poor start); LM not converged: `NONLINEAR_NOT_CONVERGED`;
4. linear again from LM's pose; converged with `e < threshold`:
   `ACCEPTED_AFTER_NONLINEAR`, else `REJECTED`.

`threshold` is in pixels (the paper: given by the recognition system). With
`threshold=None` it adapts to the problem: `(1 + rel_threshold)` times the lowest error of
any triplet that converged at step 2, i.e. "reached the best pose found": that is what
a PnP user wants accepted (and never below the rounding level of exact data,
`jaxpose.solvers._residuals.rounding_level`). If no triplet converged at step 2, every
converged one is accepted at step 4.

Under `vmap`, `lax.cond` and `lax.while_loop` run every branch and iteration for every
element; so step 3 does not run on all triplets: the `nonlinear_budget` triplets most
in need of it (not accepted, lowest error first) are gathered into a fixed-size buffer,
refined, and scattered back (`jaxpose.strategy._jobs.run_jobs`). Triplets that needed LM
but did not fit are marked `NOT_ATTEMPTED`. `nonlinear_budget=None` refines every triplet
that needs it (the paper's experiment does).

Beyond the paper, a second chance: the best root by error can be a wrong root whose basin
is a local minimum (on the bench, one triplet's best root is 120 degrees from the truth and
every method ends at 18 px). Triplets that fail steps 2-4 run them again from their
other roots (`second_chance_budget` triplets, in a buffer); `MixedResult.root` says
which root an accepted pose came from.

Three more departures, for optima that are flat and carry a large residual (planar scenes
with few matches and noisy pixels: n = 4 leaves two residual degrees of freedom):
- Step 4: where the linear run from LM's converged pose does not converge, LM's pose
  stands (accepted if below the threshold). The linear method is Gauss-Newton on Eq. 8, and
  Gauss-Newton is repelled from a minimum whose residual term outweighs its curvature; LM's
  own convergence test (stationarity) holds there.
- Patience: LM converges only linearly at such an optimum and can run out of `max_steps`
  sitting on it. A triplet whose LM ran out of steps also restarts from where it stopped
  in the second chance, and the retries (second chance, planar partner) give LM
  `PATIENCE` times `max_steps`.
- Planar partner: a plane is imaged nearly alike in two attitudes, its normal `n` or `n`
  reflected about the line of sight to its centroid (IPPE's two solutions), so every
  triplet's best root can lie in the basin of the wrong one. For a coplanar model (within
  `FLAT_TOL`), the answer's partner pose (`planar_partner`) runs steps 2-4 once per
  problem and replaces it when accepted with a lower error (`root == PARTNER_ROOT`). A
  model that is not coplanar skips it (the buffer loop runs no pass).

On the synthetic protocol (planar, sigma = 2 px) these took the share of trials at the
ML optimum from 98.9% to 100% at n = 4 (2000 trials) and from 99.85% to 100% at n = 6.

The options named here are fields of `jaxpose.Options`, which every function of this
module takes (`options=`, or keyword shorthands for single fields). Triplet selection and
step 1 are in `jaxpose.strategy._triplets`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry._pose import Observations, Pose
from ..solvers._components import (
    mat_from_array,
    vec_from_array,
)
from ..solvers._kernel_linear import (
    matches_from_observations,
    pixel_error_kernel,
)
from ..solvers._linear import LinearResult
from ..solvers._nonlinear import nonlinear
from ..solvers._status import Status
from ._accept import accepts, threshold
from ._jobs import Jobs, default_chunk, ranked, run_jobs
from ._linear_runs import linear_all, linear_block
from ._options import Options, resolve
from ._planar import planar_partner
from ._triplets import Initial, best_triplet, initial_poses

__all__ = [
    "MixedResult",
    "mixed",
    "mixed_from_initial",
    "mixed_from_initial_batch",
]


class MixedResult(NamedTuple):
    """The mixed algorithm's outcome for every triplet (all arrays have a leading `T`).

    **Fields:**
    - `pose`, `error`, `status`: the final pose of each triplet, its Eq. 8 error and
      status (`ACCEPTED_LINEAR`, `ACCEPTED_AFTER_NONLINEAR`, `REJECTED`,
      `NONLINEAR_NOT_CONVERGED`, `NOT_ATTEMPTED`, or the three-point failure).
      A triplet that was not accepted reports the better (by Eq. 8) of the last pose it
      reached and its three-point start; never a pose with points behind the camera.
    - `initial`: step 1 (`Initial`).
    - `linear_pose`, `linear_error`, `linear_status`: step 2.
    - `threshold`: the acceptance threshold used (px).
    - `root`: which three-point root the pose came from, by rank of Eq. 8 error (0: the
      best; 1-3: another, after the best led to a local minimum; `PARTNER_ROOT` (4): the
      planar partner of the answer).
    """

    pose: Pose
    error: Float[Array, " T"]
    status: Int[Array, " T"]
    initial: Initial
    linear_pose: Pose
    linear_error: Float[Array, " T"]
    linear_status: Int[Array, " T"]
    threshold: Float[Array, ""]
    root: Int[Array, " T"]


# `MixedResult.root` of a pose that came from the planar partner start.
PARTNER_ROOT = 4

# Levenberg-Marquardt's iteration budget in the retries (second chance, planar partner),
# in units of `max_steps`.
PATIENCE = 4


def _where_pose(pred, a: Pose, b: Pose) -> Pose:
    return Pose(jnp.where(pred[:, None, None], a.R, b.R), jnp.where(pred[:, None], a.t, b.t))


class MixedState(NamedTuple):
    """The mixed algorithm's state for `B` problems of `T` triplets while
    Levenberg-Marquardt's phases run (the carry of `jaxpose.strategy._jobs.run_jobs`).

    Each phase's outcome updates it when the phase ends (`after_step3`,
    `after_second_chance`, `after_partner`); the job buffer's loop terminates after the
    last phase.

    **Fields:**
    - `pose`, `error`, `status`: every triplet's outcome so far (`(B, T)`): step 2's, then
      step 3-4's, then the second chance's where it won, then the planar partner's.
    - `root`: which three-point root each pose came from (`MixedResult.root`).
    - `best`: each problem's answer `(B,)` after the second chance (`best_triplet`), the
      triplet whose planar partner is tried.
    """

    pose: Pose
    error: Float[Array, "B T"]
    status: Int[Array, "B T"]
    root: Int[Array, "B T"]
    best: Int[Array, " B"]


class _Given(NamedTuple):
    """What the phases read and never change: the problems (`obs`, `B` leading), steps 1
    and 2 of every triplet (`initial`, `lin`), which triplets gave a pose (`usable`),
    which step 2 accepted (`accepted`) and which step 3 refines (`need`), all `(B, T)`."""

    obs: Observations
    initial: Initial
    lin: LinearResult
    usable: Bool[Array, "B T"]
    accepted: Bool[Array, "B T"]
    need: Bool[Array, "B T"]


class _Layout(NamedTuple):
    """Where each phase's jobs lie in the job list (static sizes): `step3` jobs (one per
    triplet), then `second` (four per triplet: its other roots, then its stalled pose;
    `0` without a second chance), then `partner` (one per problem; `0` without)."""

    B: int
    T: int
    step3: int
    second: int
    partner: int


def _ranked_batch(need: Bool[Array, "B T"], priority: Float[Array, "B T"], budget: int | None):
    """`ranked` of every problem (`(B, T)`). Where every problem needs at most `budget`
    elements, all of finite priority below the largest float, `ranked` keeps them all: the
    ranking (a sort) runs only when some problem needs more."""
    if budget is None or budget >= need.shape[1]:
        return need
    big = jnp.finfo(priority.dtype).max
    over = jnp.any(jnp.sum(need, axis=1) > budget) | jnp.any(need & ~(priority < big))
    return jax.lax.cond(
        over, lambda: jax.vmap(ranked, in_axes=(0, 0, None))(need, priority, budget), lambda: need
    )


def thresholds(obs: Observations, lin: LinearResult, lin_ok, options: Options):
    """Each problem's acceptance threshold `(B,)` (px): `options.threshold`, or the
    adaptive one from step 2's lowest converged error (see the module docstring)."""
    big = jnp.finfo(lin.error.dtype).max
    return threshold(obs, jnp.min(jnp.where(lin_ok, lin.error, big), axis=1), options)


def job(obs: Observations, thr, iterations: int, lm_bound: int, problem, start: Pose, steps):
    """Steps 2-4 for `K` jobs at once (`job_and_step2` without step 2's statuses)."""
    return job_and_step2(obs, thr, iterations, lm_bound, problem, start, steps)[:3]


def job_and_step2(
    obs: Observations,
    thr: Array | Callable[[LinearResult], Array],
    iterations: int,
    lm_bound: int,
    problem,
    start: Pose,
    steps,
):
    """Steps 2-4 for `K` jobs at once, batch-first: job `j` starts from `start[j]` on
    problem `problem[j]` of the batch `obs`, with threshold `thr[problem[j]]`,
    `iterations` linear steps per run, and Levenberg-Marquardt with `steps[j]`
    iterations at most (`lm_bound`: its static bound). Returns `(pose, error, status)`
    and the status of step 2's runs, each with the leading `K`. `thr` may be a function
    of step 2's runs (a `LinearResult` of `K`) giving the jobs' thresholds: it is read
    only at the end, so no step 2 need run before.

    The two linear runs (from the start, then from LM's pose) are the two trips of one
    loop over the batch, Levenberg-Marquardt (`vmap`-ed) running after the first: one
    linear kernel in the compiled program, and no `vmap` of the loops (which JAX would
    trace again until it knows which of their values are batched)."""
    o = jax.tree.map(lambda x: x[problem], obs)
    m = matches_from_observations(o)
    start_error = pixel_error_kernel(mat_from_array(start.R), vec_from_array(start.t), m)

    def lm(res: LinearResult):
        better = (res.error < start_error) & (res.status != Status.NOT_FINITE)
        lm_start = _where_pose(better, res.pose, start)
        nl = jax.vmap(lambda o, p, k: nonlinear(o, p, max_steps=lm_bound, step_limit=k))(
            o, lm_start, steps
        )
        return nl.pose, nl.error, nl.status.astype(jnp.int32)

    def trip(i, carry):
        runs, nl = carry
        pose = jax.tree.map(lambda a, b: jnp.where(i == 0, a, b), start, nl[0])
        run = linear_block(mat_from_array(pose.R), vec_from_array(pose.t), m, iterations)
        runs = jax.tree.map(lambda r, x: r.at[i].set(x), runs, run)
        return runs, jax.lax.cond(i == 0, lm, lambda _: nl, run)

    zero = jnp.zeros_like(start_error)
    none = zero.astype(jnp.int32)
    nl = (start, zero, none)
    runs = jax.tree.map(lambda x: jnp.stack([x, x]), LinearResult(start, zero, zero, none))
    runs, (nl_pose, nl_error, nl_status) = jax.lax.fori_loop(0, 2, trip, (runs, nl))
    res, again = (jax.tree.map(lambda x, i=i: x[i], runs) for i in (0, 1))
    th: Array = thr(res) if callable(thr) else thr[problem]
    accepted = accepts(res.status == Status.OK, res.error, th)
    lm_ok = nl_status == Status.OK
    # Step 4's linear run polishes LM's pose; where it does not converge, LM's own
    # converged (stationary) pose stands: Gauss-Newton can be repelled from an optimum
    # whose residual is large next to its curvature (few matches, planar scenes).
    use_nl = lm_ok & (again.status != Status.OK)
    pose4 = _where_pose(use_nl, nl_pose, again.pose)
    error4 = jnp.where(use_nl, nl_error, again.error)
    accepted4 = accepts(lm_ok, error4, th)
    status = jnp.select(
        [accepted, accepted4, ~lm_ok],
        [Status.ACCEPTED_LINEAR, Status.ACCEPTED_AFTER_NONLINEAR, Status.NONLINEAR_NOT_CONVERGED],
        Status.REJECTED,
    )
    # Not accepted: the lowest-error pose reached (linear run, LM, linear after LM).
    errors = jnp.stack([res.error, nl_error, again.error, error4])  # (4, K)
    last = jnp.argmin(errors[:3], axis=0)
    pick = jnp.where(accepted, 0, jnp.where(accepted4, 3, last))
    poses = jax.tree.map(lambda *q: jnp.stack(q), res.pose, nl_pose, again.pose, pose4)
    rows = jnp.arange(pick.shape[0])
    pose = jax.tree.map(lambda x: x[pick, rows], poses)
    return pose, errors[pick, rows], status.astype(jnp.int32), res.status


def set_jobs(jobs: Jobs, lo: int, need, priority, start: Pose) -> Jobs:
    """`jobs` with the rows from `lo` on set to new jobs: `need`, `priority`, `start`."""
    problem, starts, steps = jobs.args
    hi = lo + need.shape[0]
    starts = jax.tree.map(lambda a, x: a.at[lo:hi].set(x), starts, start)
    return jobs._replace(
        need=jobs.need.at[lo:hi].set(need),
        priority=jobs.priority.at[lo:hi].set(priority),
        args=(problem, starts, steps),
    )


def after_step3(
    jobs: Jobs, state: MixedState, given: _Given, layout: _Layout, budget: int
) -> tuple[Jobs, MixedState]:
    """Step 3's outcome; the second chance's jobs: a triplet whose best root led to a
    local minimum (rejected, or LM failed) starts over from each of its other roots,
    and one whose LM ran out of steps also carries on from where it stopped (at most
    `budget` triplets per problem, lowest error first)."""
    B, T, N0, N1 = layout.B, layout.T, layout.step3, layout.second
    initial, usable, need3 = given.initial, given.usable, given.need
    big = jnp.finfo(given.lin.error.dtype).max
    pose3, error3, status3 = jax.tree.map(
        lambda x: x[:N0].reshape(B, T, *x.shape[1:]), jobs.results
    )
    status = jnp.select(
        [~usable, given.accepted, need3, usable & ~given.accepted],
        [initial.status, Status.ACCEPTED_LINEAR, status3, Status.NOT_ATTEMPTED],
        Status.OK,
    ).astype(jnp.int32)
    pose = jax.vmap(_where_pose)(need3, pose3, given.lin.pose)
    error = jnp.where(need3, error3, given.lin.error)
    if N1:
        failed = need3 & ~Status.is_success(status)
        failed = _ranked_batch(failed, error, budget)
        stalled = failed & (status == Status.NONLINEAR_NOT_CONVERGED) & (error < big)
        alt_need = jnp.concatenate(
            [failed[:, :, None] & (initial.alt_error < big), stalled[:, :, None]], axis=2
        )  # (B, T, 4): the three other roots, then the stalled pose
        start = Pose(
            jnp.concatenate([initial.alt_pose.R, pose.R[:, :, None]], axis=2),
            jnp.concatenate([initial.alt_pose.t, pose.t[:, :, None]], axis=2),
        )
        start_error = jnp.concatenate([initial.alt_error, error[:, :, None]], axis=2)
        start = jax.tree.map(lambda x: x.reshape(N1, *x.shape[3:]), start)
        jobs = set_jobs(jobs, N0, alt_need.reshape(-1), start_error.reshape(-1), start)
    return jobs, state._replace(pose=pose, error=error, status=status)


def after_second_chance(
    jobs: Jobs, state: MixedState, given: _Given, layout: _Layout
) -> tuple[Jobs, MixedState]:
    """The second chance's outcome; the planar partner's job: for a coplanar model, the
    answer (best triplet) may sit in the wrong one of the two minima of the planar
    ambiguity; its partner pose starts steps 2-4 once."""
    B, T, N0, N1, N2 = layout
    pose, error, status, root, best = state
    big = jnp.finfo(error.dtype).max
    if N1:
        alt_need = jobs.need[N0 : N0 + N1].reshape(B, T, 4)
        pose_b, error_b, status_b = jax.tree.map(lambda x: x[N0 : N0 + N1], jobs.results)
        won = alt_need & Status.is_success(status_b).reshape(B, T, 4)
        error_b = jnp.where(won, error_b.reshape(B, T, 4), big)
        pick = jnp.argmin(error_b, axis=2)
        won_any = jnp.any(won, axis=2)
        rows = (jnp.arange(B * T) * 4 + pick.reshape(-1)).reshape(B, T)
        status = jnp.where(won_any, status_b[rows], status)
        pose = jax.vmap(_where_pose)(won_any, jax.tree.map(lambda x: x[rows], pose_b), pose)
        chosen = jnp.take_along_axis(error_b, pick[..., None], 2)[..., 0]
        error = jnp.where(won_any, chosen, error)
        root = jnp.where(won_any & (pick < 3), 1 + pick, root).astype(jnp.int32)
    if N2:
        b = jnp.arange(B)
        best, _ = jax.vmap(best_triplet)(jnp.where(given.usable, error, big), status)  # (B,)
        best = best.astype(jnp.int32)
        partner, coplanar = jax.vmap(planar_partner)(
            given.obs, jax.tree.map(lambda x: x[b, best], pose)
        )
        p_need = coplanar & given.usable[b, best]
        jobs = set_jobs(jobs, N0 + N1, p_need, error[b, best], partner)
    return jobs, MixedState(pose, error, status, root, best)


def after_partner(
    jobs: Jobs, state: MixedState, given: _Given, layout: _Layout
) -> tuple[Jobs, MixedState]:
    """The planar partner's outcome: it replaces the answer when accepted with a lower
    error (or when the answer was not accepted)."""
    B, _, N0, N1, N2 = layout
    pose, error, status, root, best = state
    if N2:
        b = jnp.arange(B)
        pose_p, error_p, status_p = jax.tree.map(lambda x: x[N0 + N1 :], jobs.results)
        won = (
            jobs.need[N0 + N1 :]
            & Status.is_success(status_p)
            & (~Status.is_success(status[b, best]) | (error_p < error[b, best]))
        )
        status = status.at[b, best].set(jnp.where(won, status_p, status[b, best]))
        error = error.at[b, best].set(jnp.where(won, error_p, error[b, best]))
        pose = Pose(
            pose.R.at[b, best].set(jnp.where(won[:, None, None], pose_p.R, pose.R[b, best])),
            pose.t.at[b, best].set(jnp.where(won[:, None], pose_p.t, pose.t[b, best])),
        )
        root = root.at[b, best].set(jnp.where(won, PARTNER_ROOT, root[b, best]))
    return jobs, MixedState(pose, error, status, root, best)


def _first_jobs(given: _Given, layout: _Layout, priority, max_steps: int) -> Jobs:
    """The job list for `job` with step 3's jobs set: a job per triplet, from its best
    root, for those in `given.need`, lowest `priority` first. Levenberg-Marquardt gets
    `max_steps` iterations in step 3, `PATIENCE` times as many in the retries. The result
    slots have `job`'s output layout, `(pose, error, status)`, written out rather than
    found by tracing `job` (that would trace it, Levenberg-Marquardt and all, twice)."""
    B, T, N0, N1, N2 = layout
    b = jnp.arange(B)
    problem = jnp.concatenate([jnp.repeat(b, T), jnp.repeat(b, 4 * T)[:N1], b[:N2]])
    steps = jnp.where(jnp.arange(N0 + N1 + N2) < N0, max_steps, PATIENCE * max_steps)

    def flat(x):
        return x.reshape(-1, *x.shape[2:])

    def fill(x, n):
        return jnp.concatenate([x, jnp.zeros((n, *x.shape[1:]), x.dtype)])

    starts = jax.tree.map(lambda x: fill(flat(x), N1 + N2), given.initial.pose)
    N, dtype = N0 + N1 + N2, given.lin.error.dtype
    results = (
        Pose(jnp.zeros((N, 3, 3), dtype), jnp.zeros((N, 3), dtype)),
        jnp.zeros(N, dtype),
        jnp.zeros(N, jnp.int32),
    )
    return Jobs(
        need=fill(flat(given.need), N1 + N2),
        priority=fill(flat(priority), N1 + N2),
        args=(problem, starts, steps),
        results=results,
        done=jnp.zeros(N, bool),
    )


def _in_front_all(obs: Observations, pose: Pose) -> Bool[Array, "B T"]:
    """`in_front(transform(pose[b, k], model[b]), obs[b])` of every pose, batch-first:
    whether every used match lies at positive depth `c3 . (R m + t) + c34`."""
    R, t = mat_from_array(pose.R), vec_from_array(pose.t)  # (B, T)
    c = obs.camera[:, 2]  # (B, 4)
    m = [obs.model[:, None, :, i] for i in range(3)]  # (B, 1, n)

    def world(a, b, d, e):
        return a[..., None] * m[0] + b[..., None] * m[1] + d[..., None] * m[2] + e[..., None]

    X, Y, Z = (
        world(R.xx, R.xy, R.xz, t.x),
        world(R.yx, R.yy, R.yz, t.y),
        world(R.zx, R.zy, R.zz, t.z),
    )
    depth = X * c[:, None, None, 0] + Y * c[:, None, None, 1] + Z * c[:, None, None, 2]
    depth = depth + c[:, None, None, 3]
    return jnp.all(jnp.where(obs.mask[:, None, :], depth > 0, True), axis=-1)


def _final_poses(given: _Given, state: MixedState):
    """The final poses and errors: a triplet that was not accepted reports the better of
    its last pose and its three-point start, never a pose with points behind the camera."""
    obs, initial, usable = given.obs, given.initial, given.usable
    big = jnp.finfo(state.error.dtype).max

    front = _in_front_all(obs, state.pose)
    keep = Status.is_success(state.status) | (front & (state.error <= initial.error))
    pose = jax.vmap(_where_pose)(keep & usable, state.pose, initial.pose)
    error = jnp.where(usable, jnp.where(keep, state.error, initial.error), big)
    return pose, error


def mixed_from_initial_batch(
    obs: Observations, initial: Initial, *, options: Options | None = None, **changes
) -> MixedResult:
    """Steps 2-4 for a batch of `B` problems at once (`obs` and `initial` with a leading
    `B` axis; the result too).

    The cheap steps run on every triplet of every problem. The expensive one,
    Levenberg-Marquardt, runs only where it is needed: those triplets of the whole batch
    (at most `nonlinear_budget` per problem) pass through a buffer of `chunk` slots, lowest
    error first, in as many passes as they need (`None`: a size that grows with the batch).
    So its cost follows the number of triplets that need it, not the batch size: under a
    plain `vmap` of the one-problem version every problem would pay for a full buffer.

    **Arguments:** `obs`, `initial` (step 1, `initial_poses`, batched); `options` (an
    `Options`) and keyword shorthands `**changes` for its fields.
    """
    options = resolve(options, changes)
    B, T = initial.error.shape
    usable = initial.status == Status.OK
    k = default_chunk(B, T) if options.chunk is None else int(options.chunk)

    lin = linear_all(obs, initial.pose, options.linear_iterations)
    lin_ok = usable & (lin.status == Status.OK)
    thr = thresholds(obs, lin, lin_ok, options)

    # Levenberg-Marquardt's static bound: the retries get `PATIENCE` times the budget.
    retries = options.second_chance_budget > 0 or options.planar_partner
    lm_bound = PATIENCE * options.max_steps if retries else options.max_steps

    # Step 3 and the retries are jobs of one buffer loop (`run_jobs`, so one
    # Levenberg-Marquardt in the compiled program), in phases, since each phase's starts
    # come from the one before: step 3 (a job per triplet: its best root), the second
    # chance (four per triplet: its other roots, then its stalled pose), the planar
    # partner (one per problem).
    layout = _Layout(
        B,
        T,
        step3=B * T,
        second=4 * B * T if options.second_chance_budget > 0 else 0,
        partner=B if options.planar_partner else 0,
    )
    accepted2 = lin_ok & (lin.error < thr[:, None])
    priority = jnp.minimum(lin.error, initial.error)
    need3 = _ranked_batch(usable & ~accepted2, priority, options.nonlinear_budget)
    given = _Given(obs, initial, lin, usable, accepted2, need3)
    fn = functools.partial(job, obs, thr, options.linear_iterations, lm_bound)
    jobs = _first_jobs(given, layout, priority, options.max_steps)
    phases = [
        functools.partial(
            after_step3, given=given, layout=layout, budget=options.second_chance_budget
        ),
        functools.partial(after_second_chance, given=given, layout=layout),
        functools.partial(after_partner, given=given, layout=layout),
    ]

    def advance(phase, jobs, state):
        return jax.lax.switch(phase, phases, jobs, state)

    state = MixedState(
        lin.pose,
        lin.error,
        lin.status.astype(jnp.int32),
        jnp.zeros((B, T), jnp.int32),
        jnp.zeros(B, jnp.int32),
    )
    _, state = run_jobs(fn, jobs, k, len(phases), advance, state)
    pose, error = _final_poses(given, state)
    return MixedResult(
        pose, error, state.status, initial, lin.pose, lin.error, lin.status, thr, state.root
    )


def mixed_from_initial(
    obs: Observations, initial: Initial, *, options: Options | None = None, **changes
) -> MixedResult:
    """Steps 2-4 of the mixed algorithm for every triplet, from step 1's poses (one
    problem; `options.chunk`: Levenberg-Marquardt buffer size, see
    `mixed_from_initial_batch`). `options` and `**changes` as `mixed`."""
    options = resolve(options, changes)
    batch = jax.tree.map(lambda x: x[None], (obs, initial))
    out = mixed_from_initial_batch(*batch, options=options)
    return jax.tree.map(lambda x: x[0], out)


def mixed(
    obs: Observations,
    *,
    options: Options | None = None,
    triplets: np.ndarray | None = None,
    **changes,
) -> MixedResult:
    """The mixed algorithm for every triplet of one problem (see the module docstring).

    **Arguments:**
    - `obs`: the problem (`jaxpose.observations`).
    - `options`: an `Options` (default: `Options()`); read here: `threshold`,
      `rel_threshold`, `min_area`, `collinear_tol`, `linear_iterations`,
      `nonlinear_budget`, `second_chance_budget`, `planar_partner`, `max_steps`, `chunk`,
      and, when `triplets` is not given, `max_triplets` and `triplet_budget`.
    - `triplets`: `(T, 3)` index triplets to use (default: those of `options`, all
      `C(n, 3)` for `n < 24`).
    - `**changes`: keyword shorthands for fields of `options`
      (`mixed(obs, nonlinear_budget=None)`); an unknown one raises `ValueError`.

    **Returns:** a `MixedResult` with one entry per triplet.
    """
    options = resolve(options, changes)
    initial = initial_poses(obs, options=options, triplets=triplets)
    return mixed_from_initial(obs, initial, options=options)
