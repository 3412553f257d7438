"""A fixed-size buffer of jobs under `vmap`, and the sizes of vectorised passes.

Under `vmap`, `lax.cond` and `lax.while_loop` run every branch and iteration for every
element, so an expensive step that only some elements need would cost as if all needed
it. `run_jobs` instead gathers the elements that need it into a buffer of `chunk` slots,
runs the step on the buffer, scatters the results back, and repeats until none is left:
the cost follows the number of jobs, not the batch size.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

__all__ = ["CHUNK", "JobLoop", "Jobs", "default_chunk", "pass_size", "ranked", "run_jobs"]


# Elements per vectorised pass. XLA's CPU backend evaluates a vmapped batch one fused
# operation at a time over the whole batch; past a few hundred triplets the intermediates
# leave the cache and the time per triplet grows about 3x (measured: 560 triplets 2.9 us
# each, 11200 at once 7.5 us, 11200 in passes of 256-512 2.3 us). `lax.map` with this
# batch size keeps each pass in the cache.
CHUNK = 512


def pass_size(T: int) -> int:
    """Batch size of `lax.map` over `T` elements: all at once up to `2 * CHUNK`."""
    return T if T <= 2 * CHUNK else CHUNK


def default_chunk(B: int, T: int) -> int:
    """Levenberg-Marquardt buffer size for `B` problems of `T` triplets: 8 for one
    problem, growing with the batch so that few passes serve many problems (only a small
    share of triplets ever needs LM)."""
    return int(min(B * T, max(8, (B * T) // 32)))


def ranked(need: Bool[Array, " T"], priority: Float[Array, " T"], budget: int | None):
    """`need`, restricted to the `budget` elements of lowest `priority` (one problem)."""
    if budget is None or budget >= need.shape[0]:
        return need
    big = jnp.finfo(priority.dtype).max
    rank = jnp.argsort(jnp.argsort(jnp.where(need, priority, big)))
    return need & (rank < budget)


class Jobs(NamedTuple):
    """A fixed-size list of jobs for `run_jobs`: which to run (`need`), in what order
    (`priority`, lowest first), their arguments and results (pytrees with a leading job
    axis), and which have run (`done`)."""

    need: Bool[Array, " N"]
    priority: Float[Array, " N"]
    args: tuple
    results: tuple
    done: Bool[Array, " N"]


class JobLoop(NamedTuple):
    """The state of `run_jobs`'s loop.

    **Fields:**
    - `phase`: the phase running (the loop ends after the last one).
    - `jobs`: the job list; a pass runs the remaining jobs of lowest priority and marks
      them `done`; the phase ends when none of its jobs is left.
    - `carry`: the caller's state, read and updated only between phases (`advance`).
    """

    phase: Int[Array, ""]
    jobs: Jobs
    carry: Any


def _work(fn: Callable, k: int, state: JobLoop) -> JobLoop:
    """One pass: the `k` remaining jobs of lowest priority run as one batch."""
    jobs = state.jobs
    big = jnp.finfo(jobs.priority.dtype).max
    remaining = jobs.need & ~jobs.done
    # Selection key: remaining jobs by priority (non-finite ones last among them), all of
    # them strictly before every other job, so that each pass takes only remaining ones
    # while any is left and the loop always ends.
    key = -jnp.clip(jnp.where(jnp.isnan(jobs.priority), big, jobs.priority), -big, big)
    _, slots = jax.lax.top_k(jnp.where(remaining, key, -jnp.inf), k)
    take = remaining[slots]
    out = fn(*jax.tree.map(lambda x: x[slots], jobs.args))

    def put(r, o):
        keep = take.reshape(-1, *([1] * (o.ndim - 1)))
        return r.at[slots].set(jnp.where(keep, o, r[slots]))

    results = jax.tree.map(put, jobs.results, out)
    done = jobs.done.at[slots].set(jobs.done[slots] | take)
    return state._replace(jobs=jobs._replace(results=results, done=done))


def _next_phase(advance: Callable, state: JobLoop) -> JobLoop:
    jobs, carry = advance(state.phase, state.jobs, state.carry)
    return JobLoop(state.phase + 1, jobs, carry)


def run_jobs(fn: Callable, jobs: Jobs, chunk: int, phases: int, advance: Callable, carry):
    """Run `fn` (a batch of jobs' arguments -> their results, batch-first: every leaf
    with the jobs' leading axis) on every job that `need`s it, lowest `priority` first,
    `chunk` jobs at a time in a fixed-size buffer, in `phases` phases.

    When no job of the current phase is left, `advance(phase, jobs, carry) -> (jobs,
    carry)` reads the results and sets the next phase's jobs (it runs once per phase, the
    last time after the last phase, to read its results). One `lax.while_loop`, so `fn`
    appears once in the compiled program however many phases use it; a phase with
    nothing to do costs one trip. Under `vmap` the loop runs for as long as the element
    that needs most passes.

    Returns `(jobs, carry)`."""
    N = jobs.need.shape[0]
    k = max(1, min(int(chunk), N))

    def body(state: JobLoop) -> JobLoop:
        pending = jnp.any(state.jobs.need & ~state.jobs.done)
        return jax.lax.cond(
            pending, lambda s: _work(fn, k, s), lambda s: _next_phase(advance, s), state
        )

    state = JobLoop(jnp.array(0, jnp.int32), jobs, carry)
    state = jax.lax.while_loop(lambda state: state.phase <= phases - 1, body, state)
    return state.jobs, state.carry
