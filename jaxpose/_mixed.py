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
a PnP user wants accepted. If no triplet converged at step 2, every converged one is
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
"""

from __future__ import annotations

import itertools
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._pose import Observations, Pose, transform
from ._residuals import in_front, pixel_residuals, rms
from ._solver.linear import linear
from ._solver.nonlinear import nonlinear
from ._solver.p3p import three_point
from ._status import Status

__all__ = [
    "Initial",
    "MixedResult",
    "best_triplet",
    "initial_poses",
    "mixed",
    "mixed_from_initial",
    "triplet_indices",
]


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
      best; 1-3: another, after the best led to a local minimum).
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
    triplets: np.ndarray | None = None,
) -> Initial:
    """Step 1 for every triplet (default: all `C(n, 3)`), roots picked by Eq. 8 error."""
    n = obs.model.shape[0]
    idx = triplet_indices(n) if triplets is None else np.asarray(triplets, dtype=np.int32)
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
        err = jnp.where(sol.valid, _errors(Pose(sol.R, sol.t), obs), big)
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

    pose, error, status, alt, alt_error = jax.vmap(one)(jnp.asarray(idx))
    return Initial(pose, error, status, jnp.asarray(idx), alt, alt_error)


def _where_pose(pred, a: Pose, b: Pose) -> Pose:
    return Pose(jnp.where(pred[:, None, None], a.R, b.R), jnp.where(pred[:, None], a.t, b.t))


def _buffered(fn, need, priority, k, *args):
    """Run `fn` (one element -> pytree) on at most `k` elements where `need` holds, the
    lowest `priority` first, in a fixed-size buffer; scatter the results back.

    Returns `(results, in_buffer)`; rows outside the buffer hold the results of element 0
    of the buffer (callers mask them with `in_buffer`)."""
    T = need.shape[0]
    big = jnp.finfo(priority.dtype).max
    if k >= T:
        slots = jnp.arange(T)
    else:
        _, slots = jax.lax.top_k(-jnp.where(need, priority, big), k)
    gathered = [jax.tree.map(lambda x: x[slots], a) for a in args]

    def run(gathered):
        return jax.vmap(fn)(*gathered)

    def skip(gathered):
        shapes = jax.eval_shape(run, gathered)
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    # Nothing needs it (the common case on good data): skip the buffer altogether. (Under
    # an outer `vmap` over problems this becomes a select and both branches run.)
    out = jax.lax.cond(jnp.any(need), run, skip, gathered)
    where = jnp.zeros(T, jnp.int32).at[slots].set(jnp.arange(slots.shape[0], dtype=jnp.int32))
    in_buffer = jnp.zeros(T, dtype=bool).at[slots].set(True) & need
    return jax.tree.map(lambda x: x[where], out), in_buffer


def mixed_from_initial(
    obs: Observations,
    initial: Initial,
    *,
    threshold: float | None = None,
    rel_threshold: float = 0.01,
    linear_iterations: int = 5,
    nonlinear_budget: int | None = None,
    second_chance_budget: int = 8,
    max_steps: int = 50,
) -> MixedResult:
    """Steps 2-4 of the mixed algorithm for every triplet, from step 1's poses."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    T = initial.error.shape[0]
    usable = initial.status == Status.OK

    def run_linear(pose):
        return linear(obs, pose, iterations=linear_iterations)

    # Step 2 for every triplet.
    lin = jax.vmap(run_linear)(initial.pose)
    lin_ok = usable & (lin.status == Status.OK)
    if threshold is None:
        best = jnp.min(jnp.where(lin_ok, lin.error, big))
        thr = jnp.where(best < big, best * (1 + rel_threshold), big)
    else:
        thr = jnp.asarray(threshold, dtype)

    def after_linear(start: Pose, res):
        """Steps 3-4 after a linear run `res` from `start`: (pose, error, status)."""
        accepted = (res.status == Status.OK) & (res.error < thr)
        better = (res.error < _errors(Pose(start.R[None], start.t[None]), obs)[0]) & (
            res.status != Status.NOT_FINITE
        )
        lm_start = jax.tree.map(lambda a, b: jnp.where(better, a, b), res.pose, start)
        nl = nonlinear(obs, lm_start, max_steps=max_steps)
        again = run_linear(nl.pose)
        accepted4 = (nl.status == Status.OK) & (again.status == Status.OK) & (again.error < thr)
        status = jnp.select(
            [accepted, accepted4, nl.status != Status.OK],
            [
                Status.ACCEPTED_LINEAR,
                Status.ACCEPTED_AFTER_NONLINEAR,
                Status.NONLINEAR_NOT_CONVERGED,
            ],
            Status.REJECTED,
        )
        use_again = ~accepted & (again.error < res.error)
        pose = jax.tree.map(lambda a, b: jnp.where(use_again, a, b), again.pose, res.pose)
        return pose, jnp.where(use_again, again.error, res.error), status.astype(jnp.int32)

    accepted2 = lin_ok & (lin.error < thr)
    need = usable & ~accepted2
    k = T if nonlinear_budget is None else max(1, min(int(nonlinear_budget), T))
    (pose3, error3, status3), in_buffer = _buffered(
        after_linear, need, jnp.minimum(lin.error, initial.error), k, initial.pose, lin
    )
    status = jnp.select(
        [~usable, accepted2, in_buffer, need],
        [initial.status, Status.ACCEPTED_LINEAR, status3, Status.NOT_ATTEMPTED],
        Status.OK,
    ).astype(jnp.int32)
    pose = _where_pose(in_buffer, pose3, lin.pose)
    error = jnp.where(in_buffer, error3, lin.error)

    # Second chance: a triplet whose best root led to a local minimum (rejected, or LM
    # failed) starts over from each of its other roots, in a small buffer.
    root = jnp.zeros(T, jnp.int32)
    if second_chance_budget > 0:
        failed = in_buffer & ~Status.is_success(status)
        alt_need = failed[:, None] & (initial.alt_error < big)  # (T, 3)

        def from_root(start: Pose):
            return after_linear(start, run_linear(start))

        flat = jax.tree.map(lambda x: x.reshape(3 * T, *x.shape[2:]), initial.alt_pose)
        k2 = max(1, min(3 * int(second_chance_budget), 3 * T))
        (pose_b, error_b, status_b), retried = _buffered(
            from_root, alt_need.reshape(-1), initial.alt_error.reshape(-1), k2, flat
        )
        won = (retried & Status.is_success(status_b)).reshape(T, 3)
        error_b = jnp.where(won, error_b.reshape(T, 3), big)
        pick = jnp.argmin(error_b, axis=1)
        won_any = jnp.any(won, axis=1)
        rows = jnp.arange(T) * 3 + pick
        status = jnp.where(won_any, status_b[rows], status)
        pose = _where_pose(won_any, jax.tree.map(lambda x: x[rows], pose_b), pose)
        error = jnp.where(won_any, error_b[jnp.arange(T), pick], error)
        root = jnp.where(won_any, 1 + pick, root)

    # A triplet that was not accepted reports the better of its last pose and its
    # three-point start, never a pose with points behind the camera.
    front = jax.vmap(lambda R, t: in_front(transform(Pose(R, t), obs.model), obs))(pose.R, pose.t)
    keep = Status.is_success(status) | (front & (error <= initial.error))
    pose = _where_pose(keep & usable, pose, initial.pose)
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
    - `second_chance_budget`: most failed triplets retried from their second root.
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
