"""Triplets of matches: which ones (all, a seeded sample, or the best spread), step 1 of
the mixed algorithm on each (the best three-point root by Eq. 8), and the answer among
them."""

from __future__ import annotations

import itertools
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..geometry._pose import Observations, Pose
from ..solvers._components import image_spread, mat_from_array, vec_from_array
from ..solvers._kernel_linear import (
    Matches,
    in_chunks,
    matches_from_observations,
    pixel_error_kernel,
)
from ..solvers._kernel_p3p import three_point_batch
from ..solvers._p3p import ThreePointResult, three_point
from ..solvers._residuals import pose_error
from ..solvers._status import Status
from ._options import Options, resolve

__all__ = [
    "Initial",
    "area_threshold",
    "best_triplet",
    "initial_poses",
    "pose_errors",
    "select_triplets",
    "spread_triplets",
    "triplet_count",
    "triplet_indices",
]


@cache
def triplet_indices(n: int, max_triplets: int | None = None, seed: int = 0) -> np.ndarray:
    """Index triplets `i < j < k`, shape `(T, 3)` (static: numpy).

    All `C(n, 3)` of them when that is at most `max_triplets` (or `max_triplets` is
    `None`); otherwise a fixed, seeded uniform sample of `max_triplets` distinct triplets
    (the same for every call with the same `n` and `seed`), so that the work stays
    bounded as `n` grows: the exhaustive set grows as `n^3 / 6`. `seed` picks the
    sample (it changes nothing when every triplet is used)."""
    total = n * (n - 1) * (n - 2) // 6
    if max_triplets is None or total <= max_triplets:
        return np.array(list(itertools.combinations(range(n), 3)), dtype=np.int32).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    chosen: set[tuple[int, ...]] = set()
    while len(chosen) < max_triplets:
        draw = np.sort(rng.integers(0, n, size=(2 * max_triplets, 3)), axis=1)
        for row in draw[(draw[:, 0] < draw[:, 1]) & (draw[:, 1] < draw[:, 2])]:
            chosen.add(tuple(int(v) for v in row))
            if len(chosen) == max_triplets:
                break
    return np.array(sorted(chosen), dtype=np.int32)


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


def select_triplets(obs: Observations, options: Options):
    """The triplets that `options` select for one problem: `triplet_indices(n,
    max_triplets)`, or, with a `triplet_budget` below their number, the best spread of
    them (`spread_triplets`). Returns `(rows, triplets)`: their rows in
    `triplet_indices(n, max_triplets)` and the triplets (numpy when all are used)."""
    candidates = triplet_indices(obs.model.shape[0], options.max_triplets)
    budget = options.triplet_budget
    if budget is not None and budget < candidates.shape[0]:
        return spread_triplets(obs, candidates, budget)
    return jnp.arange(candidates.shape[0]), candidates


def triplet_count(n: int, options: Options) -> int:
    """How many triplets `select_triplets` gives for `n` matches (static)."""
    T = triplet_indices(n, options.max_triplets).shape[0]
    return T if options.triplet_budget is None else min(T, options.triplet_budget)


# Triplets per pass of step 1 (`initial_poses`): the three-point kernel's stages and the
# Eq. 8 error of the four roots of each over all matches stay in the cache.
STEP1_PASS = 2048


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


def pose_errors(poses: Pose, obs: Observations) -> Float[Array, " k"]:
    """Eq. 8 error of a batch of poses over all matches of one problem."""
    return jax.vmap(lambda R, t: pose_error(Pose(R, t), obs))(poses.R, poses.t)


def area_threshold(obs: Observations, options) -> Float[Array, "*B"]:
    """The image-triangle area below which a triplet of `obs` counts as aligned (the
    paper's Section 2.1), in the image's units: `options.min_area` (scale-free) times
    the spread of the problem's used image points (`image_spread`, `sqrt(det S)`), once
    per problem (`obs` one problem or a batch). See `Options.min_area`."""
    spread = image_spread(obs.image[..., 0], obs.image[..., 1], obs.mask)
    return options.min_area * spread


def triplet_roots(
    obs: Observations, ijk: Int[Array, " 3"], options, area: Array | None = None
) -> ThreePointResult:
    """Step 1 on the matches `ijk`: up to four poses, near-real roots included (a double
    root that noise made complex is a useful start), with the degeneracy tests of
    `options` (`min_area`, relative to the problem's spread: `area_threshold`, and
    `collinear_tol`). `area`: the aligned test's area when not `area_threshold`'s (robust
    mode caps it). Masked matches are not tested here."""
    return three_point(
        obs.camera,
        obs.model[ijk],
        obs.image[ijk],
        min_area=area_threshold(obs, options) if area is None else area,
        collinear_tol=options.collinear_tol,
        approximate=True,
    )


def _stable_ranks(err: Float[Array, "T 4"]) -> list[Array]:
    """The rank of each of the four slots in `jnp.argsort(err)` (stable: equal errors in
    slot order), as four `(T,)` integer arrays: slot `i` comes before slot `j` when its
    error is lower, or equal with `i < j`."""
    e = [err[:, i] for i in range(4)]
    ranks = []
    for i in range(4):
        before = [(e[j] <= e[i]) if j < i else (e[j] < e[i]) for j in range(4) if j != i]
        ranks.append(sum(b.astype(jnp.int32) for b in before))
    return ranks


def _step1(obs: Observations, matches: Matches, idx: Int[Array, "T 3"], options: Options, area):
    """Step 1 for the triplets `idx` of one problem, batch-first: the three-point kernel
    on every triplet (`area`: the problem's `area_threshold`), every root scored by the
    Eq. 8 kernel, the roots ranked by error. Returns the fields of `Initial` but
    `triplets`."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    sol = three_point_batch(
        obs.camera,
        obs.model[idx],
        obs.image[idx],
        min_area=area,
        collinear_tol=options.collinear_tol,
        approximate=True,
    )
    err = pixel_error_kernel(mat_from_array(sol.R), vec_from_array(sol.t), matches)  # (T, 4)
    err = jnp.where(sol.valid & jnp.isfinite(err), err, big)
    ranks = _stable_ranks(err)
    # order[:, k]: the slot of rank k (`jnp.argsort(err)`)
    order = jnp.stack(
        [sum(jnp.where(r == k, i, 0) for i, r in enumerate(ranks)) for k in range(4)], axis=1
    )
    R = jnp.take_along_axis(sol.R, order[:, :, None, None], axis=1)
    t = jnp.take_along_axis(sol.t, order[:, :, None], axis=1)
    err = jnp.take_along_axis(err, order, axis=1)
    used = jnp.all(obs.mask[idx], axis=1)
    status = jnp.where(used, sol.status, Status.TOO_FEW_POINTS).astype(jnp.int32)
    ok = status == Status.OK
    alt_ok = ok[:, None] & (err[:, 1:] < big)
    eye = jnp.eye(3, dtype=dtype)
    pose = Pose(jnp.where(ok[:, None, None], R[:, 0], eye), jnp.where(ok[:, None], t[:, 0], 0))
    alt = Pose(
        jnp.where(alt_ok[:, :, None, None], R[:, 1:], eye),
        jnp.where(alt_ok[:, :, None], t[:, 1:], 0),
    )
    return pose, jnp.where(ok, err[:, 0], big), status, alt, jnp.where(alt_ok, err[:, 1:], big)


def initial_poses(
    obs: Observations,
    *,
    options: Options | None = None,
    triplets: np.ndarray | Int[Array, "T 3"] | None = None,
    **changes,
) -> Initial:
    """Step 1 for every triplet of one problem, roots picked by Eq. 8 error.

    The batch-first kernels compute it (`three_point_batch`, `pixel_error_kernel`): the
    values of `triplet_roots` and `pose_errors` on every triplet, the roots in the order
    of `jnp.argsort` of their errors (ties: slot order), in passes of at most `STEP1_PASS`
    triplets. No derivative flows through it (the three-point kernel's inputs are
    constants to it).

    **Arguments:**
    - `obs`: the problem (`jaxpose.observations`).
    - `options`: an `Options` (`min_area` and `collinear_tol` are read here); keyword
      shorthands `**changes` replace its fields.
    - `triplets`: `(T, 3)` index triplets, possibly a traced array (default: those of
      `options`, `select_triplets`: all `C(n, 3)` for `n < 24`).

    **Returns:** an `Initial`.
    """
    options = resolve(options, changes)
    idx = select_triplets(obs, options)[1] if triplets is None else triplets
    idx = jnp.asarray(idx, dtype=jnp.int32)
    obs = jax.lax.stop_gradient(obs)
    matches = matches_from_observations(jax.tree.map(lambda x: x[None], obs))
    T = idx.shape[0]
    size = max(1, -(-T // -(-T // STEP1_PASS))) if T else 1  # near-equal passes
    area = area_threshold(obs, options)  # once per problem
    pose, error, status, alt, alt_error = in_chunks(
        lambda block: _step1(obs, matches, block, options, area), idx, size=size
    )
    return Initial(pose, error, status, idx, alt, alt_error)


def best_triplet(error: Float[Array, " T"], status: Int[Array, " T"]):
    """Index of the problem's answer: the accepted triplet of lowest error, or, when none
    was accepted, the lowest-error triplet overall. Returns `(index, accepted)`."""
    big = jnp.finfo(error.dtype).max
    ok = Status.is_success(status)
    any_ok = jnp.any(ok)
    index = jnp.where(any_ok, jnp.argmin(jnp.where(ok, error, big)), jnp.argmin(error))
    return index, any_ok
