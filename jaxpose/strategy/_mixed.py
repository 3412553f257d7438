"""The mixed algorithm (SPEC 4; the paper's Section 3) over all triplets of a problem at once.

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
`jaxpose._residuals.rounding_level`). If no triplet converged at step 2, every converged one is
accepted at step 4.

Under `vmap`, `lax.cond` and `lax.while_loop` run every branch and iteration for every
element; so step 3 does not run on all triplets: the `nonlinear_budget` triplets most
in need of it (not accepted, lowest error first) are gathered into a fixed-size buffer,
refined, and scattered back. Triplets that needed LM but did not fit are marked
`NOT_ATTEMPTED`. `nonlinear_budget=None` refines every triplet that needs it (the
paper's experiment does).

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
  `FLAT_TOL`), the answer's partner pose (`_planar_partner`) runs steps 2-4 once per
  problem and replaces it when accepted with a lower error (`root == PARTNER_ROOT`). A
  model that is not coplanar skips it (the buffer loop runs no pass).

On the synthetic protocol (planar, sigma = 2 px) these took the share of trials at the
ML optimum from 98.9% to 100% at n = 4 (2000 trials) and from 99.85% to 100% at n = 6.
"""

from __future__ import annotations

import itertools
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry._pose import Observations, Pose, transform
from ..geometry._rotation import rotvec_to_matrix
from ..solvers._linear import linear
from ..solvers._nonlinear import nonlinear
from ..solvers._p3p import three_point
from ..solvers._residuals import in_front, pixel_residuals, rms, rounding_level
from ..solvers._status import Status

__all__ = [
    "Initial",
    "MixedResult",
    "best_triplet",
    "initial_poses",
    "mixed",
    "mixed_from_initial",
    "mixed_from_initial_batch",
    "spread_triplets",
    "triplet_indices",
]


# Triplets per vectorised pass. XLA's CPU backend evaluates a vmapped batch one fused
# operation at a time over the whole batch; past a few hundred triplets the intermediates
# leave the cache and the time per triplet grows about 3x (measured: 560 triplets 2.9 us
# each, 11200 at once 7.5 us, 11200 in passes of 256-512 2.3 us). `lax.map` with this
# batch size keeps each pass in the cache.
CHUNK = 512


def _pass_size(T: int) -> int:
    """Batch size of `lax.map` over `T` elements: all at once up to `2 * CHUNK`."""
    return T if T <= 2 * CHUNK else CHUNK


@cache
def triplet_indices(n: int, max_triplets: int | None = None) -> np.ndarray:
    """Index triplets `i < j < k`, shape `(T, 3)` (static: numpy).

    All `C(n, 3)` of them when that is at most `max_triplets` (or `max_triplets` is
    `None`); otherwise a fixed, seeded uniform sample of `max_triplets` distinct triplets
    (the same for every call with the same `n`), so that the work stays bounded as `n`
    grows: the exhaustive set grows as `n^3 / 6`."""
    total = n * (n - 1) * (n - 2) // 6
    if max_triplets is None or total <= max_triplets:
        return np.array(list(itertools.combinations(range(n), 3)), dtype=np.int32).reshape(-1, 3)
    rng = np.random.default_rng(0)
    chosen: set[tuple[int, ...]] = set()
    while len(chosen) < max_triplets:
        draw = np.sort(rng.integers(0, n, size=(2 * max_triplets, 3)), axis=1)
        for row in draw[(draw[:, 0] < draw[:, 1]) & (draw[:, 1] < draw[:, 2])]:
            chosen.add(tuple(int(v) for v in row))
            if len(chosen) == max_triplets:
                break
    return np.array(sorted(chosen), dtype=np.int32)


class Initial(NamedTuple):
    """Step 1 for every triplet: the best three-point root by Eq. 8 over all matches.

    **Fields:** `pose` (batched `(T,)`), `error` `(T,)` px, `status` `(T,)`
    (`OK` or why the triplet gave no pose), `triplets` `(T, 3)`; `alt_pose`, `alt_error`:
    the other three roots, `(T, 3)`, best first (error `finfo.max` where there is none)."""

    pose: Pose
    error: Float[Array, " T"]
    status: Int[Array, " T"]
    triplets: Int[Array, "T 3"]
    alt_pose: Pose
    alt_error: Float[Array, " T"]


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


def _errors(poses: Pose, obs: Observations):
    """Eq. 8 error of a batch of poses over all matches of one problem."""

    def one(R, t):
        return rms(pixel_residuals(transform(Pose(R, t), obs.model), obs), obs.mask)

    return jax.vmap(one)(poses.R, poses.t)


def initial_poses(
    obs: Observations,
    *,
    min_area: float = 40.0,
    collinear_tol: float = 5e-3,
    triplets: np.ndarray | Int[Array, "T 3"] | None = None,
) -> Initial:
    """Step 1 for every triplet (default: all `C(n, 3)`; `triplets` may be a traced
    array, e.g. from `spread_triplets`), roots picked by Eq. 8 error."""
    n = obs.model.shape[0]
    idx = triplet_indices(n) if triplets is None else triplets
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max

    def one(ijk):
        sol = three_point(
            obs.camera,
            obs.model[ijk],
            obs.image[ijk],
            min_area=min_area,
            collinear_tol=collinear_tol,
            approximate=True,
        )
        err = _errors(Pose(sol.R, sol.t), obs)
        err = jnp.where(sol.valid & jnp.isfinite(err), err, big)
        order = jnp.argsort(err)
        best, others = order[0], order[1:]
        used = jnp.all(obs.mask[ijk])
        status = jnp.where(used, sol.status, Status.TOO_FEW_POINTS).astype(jnp.int32)
        ok = status == Status.OK
        alt_ok = ok & (err[others] < big)
        eye = jnp.eye(3, dtype=dtype)
        pose = Pose(jnp.where(ok, sol.R[best], eye), jnp.where(ok, sol.t[best], 0))
        alt = Pose(
            jnp.where(alt_ok[:, None, None], sol.R[others], eye[None]),
            jnp.where(alt_ok[:, None], sol.t[others], 0),
        )
        return pose, jnp.where(ok, err[best], big), status, alt, jnp.where(alt_ok, err[others], big)

    idx = jnp.asarray(idx, dtype=jnp.int32)
    pose, error, status, alt, alt_error = jax.lax.map(one, idx, batch_size=_pass_size(idx.shape[0]))
    return Initial(pose, error, status, idx, alt, alt_error)


def spread_triplets(
    obs: Observations, candidates: np.ndarray, budget: int
) -> tuple[Int[Array, " k"], Int[Array, "k 3"]]:
    """The `budget` candidate triplets whose image triangles are largest (well spread,
    far from the aligned case; a data-dependent choice, fixed in size).

    Triplets with a masked match come last. Returns `(rows, triplets)`: the rows of
    `candidates` chosen, and the triplets themselves, `(budget, 3)`."""
    cand = jnp.asarray(candidates, dtype=jnp.int32)
    uv = obs.image[cand]  # (T, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * jnp.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    used = jnp.all(obs.mask[cand], axis=1)
    area = jnp.where(used & jnp.isfinite(area), area, -1)
    _, rows = jax.lax.top_k(area, min(int(budget), cand.shape[0]))
    return rows, cand[rows]


# Flatness below which a model counts as coplanar (planar partner start): RMS distance to
# its best-fit plane over its RMS extent along the plane's narrower direction.
FLAT_TOL = 1e-2

# `MixedResult.root` of a pose that came from the planar partner start.
PARTNER_ROOT = 4

# Levenberg-Marquardt's iteration budget in the retries (second chance, planar partner),
# in units of `max_steps`.
PATIENCE = 4


def _planar_partner(obs: Observations, pose: Pose) -> tuple[Pose, Array]:
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
    centre = jnp.sum(obs.model * w[:, None], axis=0) / count
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


def _where_pose(pred, a: Pose, b: Pose) -> Pose:
    return Pose(jnp.where(pred[:, None, None], a.R, b.R), jnp.where(pred[:, None], a.t, b.t))


def _ranked(need, priority, budget: int | None):
    """`need`, restricted to the `budget` elements of lowest `priority` (one problem)."""
    if budget is None or budget >= need.shape[0]:
        return need
    big = jnp.finfo(priority.dtype).max
    rank = jnp.argsort(jnp.argsort(jnp.where(need, priority, big)))
    return need & (rank < budget)


class _Jobs(NamedTuple):
    """A fixed-size list of jobs for `_run_jobs`: which to run (`need`), in what order
    (`priority`, lowest first), their arguments and results (pytrees with a leading job
    axis), and which have run (`done`)."""

    need: Bool[Array, " N"]
    priority: Float[Array, " N"]
    args: tuple
    results: tuple
    done: Bool[Array, " N"]


def _run_jobs(fn, jobs: _Jobs, chunk: int, phases: int, advance, carry):
    """Run `fn` (one job's arguments -> results) on every job that `need`s it, lowest
    `priority` first, `chunk` jobs at a time in a fixed-size buffer, in `phases` phases.

    When no job of the current phase is left, `advance(phase, jobs, carry) -> (jobs,
    carry)` reads the results and sets the next phase's jobs (it runs once per phase, the
    last time after the last phase, to read its results). One `lax.while_loop`, so `fn`
    appears once in the compiled program however many phases use it; a phase with
    nothing to do costs one trip. Under `vmap` the loop runs for as long as the element
    that needs most passes.

    Returns `(jobs, carry)`."""
    N = jobs.need.shape[0]
    k = max(1, min(int(chunk), N))

    def work(state):
        phase, jobs, carry = state
        big = jnp.finfo(jobs.priority.dtype).max
        remaining = jobs.need & ~jobs.done
        # Selection key: remaining jobs by priority (non-finite ones last among them), all
        # of them strictly before every other job, so that each pass takes only remaining
        # ones while any is left and the loop always ends.
        key = -jnp.clip(jnp.where(jnp.isnan(jobs.priority), big, jobs.priority), -big, big)
        _, slots = jax.lax.top_k(jnp.where(remaining, key, -jnp.inf), k)
        take = remaining[slots]
        out = jax.vmap(fn)(*jax.tree.map(lambda x: x[slots], jobs.args))

        def put(r, o):
            keep = take.reshape(-1, *([1] * (o.ndim - 1)))
            return r.at[slots].set(jnp.where(keep, o, r[slots]))

        results = jax.tree.map(put, jobs.results, out)
        done = jobs.done.at[slots].set(jobs.done[slots] | take)
        return phase, jobs._replace(results=results, done=done), carry

    def next_phase(state):
        phase, jobs, carry = state
        jobs, carry = advance(phase, jobs, carry)
        return phase + 1, jobs, carry

    def body(state):
        _, jobs, _ = state
        return jax.lax.cond(jnp.any(jobs.need & ~jobs.done), work, next_phase, state)

    state = (jnp.array(0, jnp.int32), jobs, carry)
    _, jobs, carry = jax.lax.while_loop(lambda state: state[0] <= phases - 1, body, state)
    return jobs, carry


def _default_chunk(B: int, T: int) -> int:
    """Levenberg-Marquardt buffer size: 8 for one problem, growing with the batch so that
    few passes serve many problems (only a small share of triplets ever needs LM)."""
    return int(min(B * T, max(8, (B * T) // 32)))


def mixed_from_initial(
    obs: Observations,
    initial: Initial,
    *,
    threshold: float | None = None,
    rel_threshold: float = 0.01,
    linear_iterations: int = 5,
    nonlinear_budget: int | None = None,
    second_chance_budget: int = 8,
    planar_partner: bool = True,
    max_steps: int = 50,
    chunk: int | None = None,
) -> MixedResult:
    """Steps 2-4 of the mixed algorithm for every triplet, from step 1's poses (one
    problem; `chunk`: Levenberg-Marquardt buffer size, see `mixed_from_initial_batch`)."""
    batch = jax.tree.map(lambda x: x[None], (obs, initial))
    out = mixed_from_initial_batch(
        *batch,
        threshold=threshold,
        rel_threshold=rel_threshold,
        linear_iterations=linear_iterations,
        nonlinear_budget=nonlinear_budget,
        second_chance_budget=second_chance_budget,
        planar_partner=planar_partner,
        max_steps=max_steps,
        chunk=chunk,
    )
    return jax.tree.map(lambda x: x[0], out)


def mixed_from_initial_batch(
    obs: Observations,
    initial: Initial,
    *,
    threshold: float | None = None,
    rel_threshold: float = 0.01,
    linear_iterations: int = 5,
    nonlinear_budget: int | None = None,
    second_chance_budget: int = 8,
    planar_partner: bool = True,
    max_steps: int = 50,
    chunk: int | None = None,
) -> MixedResult:
    """Steps 2-4 for a batch of `B` problems at once (`obs` and `initial` with a leading
    `B` axis; the result too).

    The cheap steps run on every triplet of every problem. The expensive one,
    Levenberg-Marquardt, runs only where it is needed: those triplets of the whole batch
    (at most `nonlinear_budget` per problem) pass through a buffer of `chunk` slots, lowest
    error first, in as many passes as they need (`None`: a size that grows with the batch).
    So its cost follows the number of triplets that need it, not the batch size: under a
    plain `vmap` of the one-problem version every problem would pay for a full buffer."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    B, T = initial.error.shape
    usable = initial.status == Status.OK
    k = _default_chunk(B, T) if chunk is None else int(chunk)

    def run_linear(o, pose):
        return linear(o, pose, iterations=linear_iterations)

    # Step 2 for every triplet of every problem, in cache-sized passes: whole problems
    # at a time, or, for a problem with more triplets than a pass, its triplets in passes.
    if T <= _pass_size(T):
        lin = jax.lax.map(
            lambda a: jax.vmap(run_linear, in_axes=(None, 0))(*a),
            (obs, initial.pose),
            batch_size=max(1, _pass_size(B * T) // T),
        )
    else:

        def one_problem(a):
            o, poses = a
            return jax.lax.map(lambda p: run_linear(o, p), poses, batch_size=_pass_size(T))

        lin = jax.lax.map(one_problem, (obs, initial.pose))
    lin_ok = usable & (lin.status == Status.OK)
    if threshold is None:
        best = jnp.min(jnp.where(lin_ok, lin.error, big), axis=1)
        floor = jax.vmap(rounding_level)(obs)
        thr = jnp.where(best < big, jnp.maximum(best * (1 + rel_threshold), floor), big)
    else:
        thr = jnp.full((B,), threshold, dtype)

    # Levenberg-Marquardt's static bound: the retries get `PATIENCE` times the budget.
    retries = second_chance_budget > 0 or planar_partner
    lm_bound = PATIENCE * max_steps if retries else max_steps

    def job(problem, start: Pose, steps):
        """Steps 2-4 from `start` for one problem, Levenberg-Marquardt with `steps`
        iterations at most: (pose, error, status)."""
        o = jax.tree.map(lambda x: x[problem], obs)
        th = thr[problem]
        res = run_linear(o, start)
        accepted = (res.status == Status.OK) & (res.error < th)
        better = (res.error < _errors(Pose(start.R[None], start.t[None]), o)[0]) & (
            res.status != Status.NOT_FINITE
        )
        lm_start = jax.tree.map(lambda a, b: jnp.where(better, a, b), res.pose, start)
        nl = nonlinear(o, lm_start, max_steps=lm_bound, step_limit=steps)
        again = run_linear(o, nl.pose)
        lm_ok = nl.status == Status.OK
        # Step 4's linear run polishes LM's pose; where it does not converge, LM's own
        # converged (stationary) pose stands: Gauss-Newton can be repelled from an optimum
        # whose residual is large next to its curvature (few matches, planar scenes).
        use_nl = lm_ok & (again.status != Status.OK)
        pose4 = jax.tree.map(lambda a, b: jnp.where(use_nl, a, b), nl.pose, again.pose)
        error4 = jnp.where(use_nl, nl.error, again.error)
        accepted4 = lm_ok & (error4 < th)
        status = jnp.select(
            [accepted, accepted4, ~lm_ok],
            [
                Status.ACCEPTED_LINEAR,
                Status.ACCEPTED_AFTER_NONLINEAR,
                Status.NONLINEAR_NOT_CONVERGED,
            ],
            Status.REJECTED,
        )
        # Not accepted: the lowest-error pose reached (linear run, LM, linear after LM).
        errors = jnp.stack([res.error, nl.error, again.error])
        last = jnp.argmin(errors)
        pick = jnp.where(accepted, 0, jnp.where(accepted4, 3, last))
        poses = [res.pose, nl.pose, again.pose, pose4]
        pose = Pose(jnp.stack([q.R for q in poses])[pick], jnp.stack([q.t for q in poses])[pick])
        error = jnp.concatenate([errors, error4[None]])[pick]
        return pose, error, status.astype(jnp.int32)

    # Step 3 and the retries are jobs of one buffer loop (`_run_jobs`, so one
    # Levenberg-Marquardt in the compiled program), in phases, since each phase's starts
    # come from the one before: step 3 (a job per triplet: its best root), the second
    # chance (four per triplet: its other roots, then its stalled pose), the planar
    # partner (one per problem).
    N0 = B * T
    N1 = 4 * B * T if second_chance_budget > 0 else 0
    N2 = B if planar_partner else 0
    b = jnp.arange(B)
    problem = jnp.concatenate([jnp.repeat(b, T), jnp.repeat(b, 4 * T)[:N1], b[:N2]])
    steps = jnp.where(jnp.arange(N0 + N1 + N2) < N0, max_steps, PATIENCE * max_steps)

    def flat(x):
        return x.reshape(-1, *x.shape[2:])

    def fill(x, n):
        return jnp.concatenate([x, jnp.zeros((n, *x.shape[1:]), x.dtype)])

    accepted2 = lin_ok & (lin.error < thr[:, None])
    priority = jnp.minimum(lin.error, initial.error)
    need3 = jax.vmap(_ranked, in_axes=(0, 0, None))(usable & ~accepted2, priority, nonlinear_budget)
    starts = jax.tree.map(lambda x: fill(flat(x), N1 + N2), initial.pose)
    shapes = jax.eval_shape(job, problem[0], jax.tree.map(lambda x: x[0], starts), steps[0])
    jobs = _Jobs(
        need=fill(flat(need3), N1 + N2),
        priority=fill(flat(priority), N1 + N2),
        args=(problem, starts, steps),
        results=jax.tree.map(lambda s: jnp.zeros((N0 + N1 + N2, *s.shape), s.dtype), shapes),
        done=jnp.zeros(N0 + N1 + N2, bool),
    )

    def set_jobs(jobs: _Jobs, lo: int, need, priority, start: Pose) -> _Jobs:
        problem, starts, steps = jobs.args
        hi = lo + need.shape[0]
        starts = jax.tree.map(lambda a, x: a.at[lo:hi].set(x), starts, start)
        return jobs._replace(
            need=jobs.need.at[lo:hi].set(need),
            priority=jobs.priority.at[lo:hi].set(priority),
            args=(problem, starts, steps),
        )

    def after_step3(jobs: _Jobs, carry):
        """Step 3's outcome; the second chance's jobs: a triplet whose best root led to a
        local minimum (rejected, or LM failed) starts over from each of its other roots,
        and one whose LM ran out of steps also carries on from where it stopped (at most
        `second_chance_budget` triplets per problem, lowest error first)."""
        pose3, error3, status3 = jax.tree.map(
            lambda x: x[:N0].reshape(B, T, *x.shape[1:]), jobs.results
        )
        status = jnp.select(
            [~usable, accepted2, need3, usable & ~accepted2],
            [initial.status, Status.ACCEPTED_LINEAR, status3, Status.NOT_ATTEMPTED],
            Status.OK,
        ).astype(jnp.int32)
        pose = jax.vmap(_where_pose)(need3, pose3, lin.pose)
        error = jnp.where(need3, error3, lin.error)
        if N1:
            failed = need3 & ~Status.is_success(status)
            failed = jax.vmap(_ranked, in_axes=(0, 0, None))(failed, error, second_chance_budget)
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
        return jobs, (pose, error, status, carry[3], carry[4])

    def after_second_chance(jobs: _Jobs, carry):
        """The second chance's outcome; the planar partner's job: for a coplanar model,
        the answer (best triplet) may sit in the wrong one of the two minima of the
        planar ambiguity; its partner pose starts steps 2-4 once."""
        pose, error, status, root, best = carry
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
            best, _ = jax.vmap(best_triplet)(jnp.where(usable, error, big), status)  # (B,)
            best = best.astype(jnp.int32)
            partner, coplanar = jax.vmap(_planar_partner)(
                obs, jax.tree.map(lambda x: x[b, best], pose)
            )
            p_need = coplanar & usable[b, best]
            jobs = set_jobs(jobs, N0 + N1, p_need, error[b, best], partner)
        return jobs, (pose, error, status, root, best)

    def after_partner(jobs: _Jobs, carry):
        """The planar partner's outcome: it replaces the answer when accepted with a lower
        error (or when the answer was not accepted)."""
        pose, error, status, root, best = carry
        if N2:
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
        return jobs, (pose, error, status, root, best)

    def advance(phase, jobs, carry):
        return jax.lax.switch(phase, [after_step3, after_second_chance, after_partner], jobs, carry)

    carry = (
        lin.pose,
        lin.error,
        lin.status.astype(jnp.int32),
        jnp.zeros((B, T), jnp.int32),
        jnp.zeros(B, jnp.int32),
    )
    _, (pose, error, status, root, _) = _run_jobs(job, jobs, k, 3, advance, carry)

    # A triplet that was not accepted reports the better of its last pose and its
    # three-point start, never a pose with points behind the camera.
    def front_of(o, pose):
        return jax.vmap(lambda R, t: in_front(transform(Pose(R, t), o.model), o))(pose.R, pose.t)

    front = jax.vmap(front_of)(obs, pose)
    keep = Status.is_success(status) | (front & (error <= initial.error))
    pose = jax.vmap(_where_pose)(keep & usable, pose, initial.pose)
    error = jnp.where(usable, jnp.where(keep, error, initial.error), big)
    return MixedResult(pose, error, status, initial, lin.pose, lin.error, lin.status, thr, root)


def mixed(
    obs: Observations,
    *,
    threshold: float | None = None,
    rel_threshold: float = 0.01,
    min_area: float = 40.0,
    collinear_tol: float = 5e-3,
    linear_iterations: int = 5,
    nonlinear_budget: int | None = None,
    second_chance_budget: int = 8,
    planar_partner: bool = True,
    max_steps: int = 50,
    triplets: np.ndarray | None = None,
) -> MixedResult:
    """The mixed algorithm for every triplet of one problem (see the module docstring).

    **Arguments:**
    - `obs`: the problem (`jaxpose._pose.observations`).
    - `threshold`: acceptance threshold on Eq. 8 (px), or `None` for the adaptive one.
    - `rel_threshold`: the adaptive threshold's margin over the best error.
    - `min_area`: the image-triangle area (px^2) below which a triplet is aligned.
    - `collinear_tol`: model-triangle collinearity tolerance (scale-free).
    - `linear_iterations`: steps of each linear run.
    - `nonlinear_budget`: most triplets sent to Levenberg-Marquardt (`None`: all).
    - `second_chance_budget`: most failed triplets retried from their other roots.
    - `planar_partner`: for a coplanar model, also start from the planar-ambiguity partner
      of the best pose.
    - `max_steps`: Levenberg-Marquardt's iteration budget.
    - `triplets`: `(T, 3)` index triplets to use (default: all `C(n, 3)`).

    **Returns:** a `MixedResult` with one entry per triplet.
    """
    initial = initial_poses(obs, min_area=min_area, collinear_tol=collinear_tol, triplets=triplets)
    return mixed_from_initial(
        obs,
        initial,
        threshold=threshold,
        rel_threshold=rel_threshold,
        linear_iterations=linear_iterations,
        nonlinear_budget=nonlinear_budget,
        second_chance_budget=second_chance_budget,
        planar_partner=planar_partner,
        max_steps=max_steps,
    )


def best_triplet(error: Float[Array, " T"], status: Int[Array, " T"]):
    """Index of the problem's answer: the accepted triplet of lowest error, or, when none
    was accepted, the lowest-error triplet overall. Returns `(index, accepted)`."""
    big = jnp.finfo(error.dtype).max
    ok = Status.is_success(status)
    any_ok = jnp.any(ok)
    index = jnp.where(any_ok, jnp.argmin(jnp.where(ok, error, big)), jnp.argmin(error))
    return index, any_ok
