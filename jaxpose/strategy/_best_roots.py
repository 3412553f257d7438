"""Steps 2-5 of the best roots (`jaxpose.strategy._best`'s module docstring) for a block
of problems: every three-point root of the chosen triplets scored by its Eq. 8 error, the
linear method from the best distinct few, the mixed algorithm's acceptance, the planar
partner of a coplanar model's answer. Batch-first kernels in component form
(`jaxpose.solvers._kernel_p3p`, `_kernel_linear`) over a leading problem axis, in blocks
of problems sized for the cache (`block_size`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry._pose import Observations, Pose
from ..solvers._components import (
    Mat3,
    Vec3,
    degeneracy,
    mat_to_array,
    stacked,
    take_along,
    transpose_matvec,
    vec_to_array,
)
from ..solvers._kernel_linear import (
    Matches,
    in_chunks,
    linear_kernel,
    matches_from_observations,
    pixel_error_kernel,
)
from ..solvers._kernel_p3p import p3p_components
from ..solvers._status import Status
from ._accept import accepts, threshold
from ._mixed import job_and_step2
from ._options import Options
from ._planar import model_planes, planar_partner_batch
from ._triplets import area_threshold

__all__ = [
    "BLOCK_TRIPLETS",
    "DISTINCT_ANGLE",
    "Best",
    "best_of_roots",
    "best_of_roots_batch",
    "block_size",
    "distinct_best",
    "refine_count",
]

#: Two roots whose rotations differ by less than this angle (rad) are one start.
DISTINCT_ANGLE = 0.1

# Triplets per block of problems of the kernels (a block's roots, scores and linear runs
# stay in the processor's cache: the scores of 64 problems of 16 matches from their 16
# roots are 128 KiB a value). Measured on an AMD EPYC (512 KiB of L2 cache a core), one
# thread, the first rung over 2,048 problems of 16 matches, process time per problem with
# blocks of 256 / 512 / 2048 triplets: 10.2 / 10.6 / 13.1 us (ordinary), 17.2 / 18.8 /
# 23.6 us (planar).
BLOCK_TRIPLETS = 256


class Best(NamedTuple):
    """The answer of each problem from its best-scored roots (leading problem axis `B`,
    or none for one problem).

    **Fields:** `pose`; `error` (Eq. 8, px; the largest float when not accepted);
    `status` (`ACCEPTED_LINEAR` when accepted, else the reason the best candidate
    failed); `triplet` (the three matches of the triplet whose root led to the answer);
    `accepted`; `step` (the last step of the linear method that gave the pose, see
    `Answer`).
    """

    pose: Pose
    error: Float[Array, "*B"]
    status: Int[Array, "*B"]
    triplet: Int[Array, "*B 3"]
    accepted: Bool[Array, "*B"]
    step: Float[Array, "*B"]


def refine_count(options: Options, roots: int) -> int:
    """How many roots are refined: `options.refine` (`None`: 4), at most the number of
    roots."""
    return max(1, min(4 if options.refine is None else options.refine, roots))


def _roots(obs: Observations, m: Matches, triplets: Int[Array, "B T 3"], options: Options):
    """Every root of every triplet, as `Mat3` / `Vec3` of `(B, 4 T)` and a validity mask:
    the three-point kernel on the world bearings of the matches (`frame^T (x, y, 1)` from
    the camera centre `-frame^T offset`), with `three_point`'s degeneracy tests and the
    near-real roots (a double root that noise made complex)."""
    B, T = triplets.shape[:2]
    one = jnp.ones_like(m.x)
    f = transpose_matvec(Mat3(*(a[:, None] for a in m.frame)), Vec3(m.x, m.y, one))
    centre = transpose_matvec(m.frame, m.offset)
    # the matches of every triplet: one gather of every per-match quantity
    fields = [*f, *(obs.model[..., i] for i in range(3)), obs.image[..., 0], obs.image[..., 1]]
    index = triplets.reshape(B, 3 * T)
    got = [a.reshape(B, T, 3) for a in take_along([*fields, obs.mask], index, axis=1)]

    def corners(a: Array) -> tuple[Array, Array, Array]:
        return a[..., 0], a[..., 1], a[..., 2]

    fx, fy, fz, mx, my, mz, u, v, used = map(corners, got)
    bearings = (Vec3(fx[0], fy[0], fz[0]), Vec3(fx[1], fy[1], fz[1]), Vec3(fx[2], fy[2], fz[2]))
    points = (Vec3(mx[0], my[0], mz[0]), Vec3(mx[1], my[1], mz[1]), Vec3(mx[2], my[2], mz[2]))
    c = p3p_components(bearings, points)
    area = area_threshold(obs, options)[:, None]  # (B, 1): once per problem
    bad_image, bad_model = degeneracy(u, v, points, area, options.collinear_tol)
    ok = used[0] & used[1] & used[2] & ~bad_image & ~bad_model
    valid = (c.real | c.near) & c.positive & ok[..., None]
    t = Vec3(*(a - o[:, None, None] for a, o in zip(c.t, centre, strict=True)))

    def flat(a):
        return a.reshape(B, 4 * T)

    return Mat3(*map(flat, c.R)), Vec3(*map(flat, t)), flat(valid)


def distinct_best(
    score: Float[Array, "B C"], R: Mat3, K: int, angle: float = DISTINCT_ANGLE
) -> tuple[Int[Array, "B K"], Bool[Array, "B K"]]:
    """The `K` lowest-scored candidates of each problem, each more than `angle` (rad)
    from those chosen before it (greedy). Returns `(index, found)`: a slot with no
    candidate left repeats the last one, `found` False."""
    big = jnp.finfo(score.dtype).max
    near = 1 + 2 * math.cos(angle)  # trace(Ra^T Rb) above this: closer than `angle`
    picks, found = [], []
    for _ in range(K):
        i = jnp.argmin(score, axis=-1)
        picks.append(i)
        si, *Ri = take_along([score, *R], i[:, None], axis=1)
        found.append(si[:, 0] < big)
        Ri = Mat3(*Ri)
        # trace(Ri^T R): the sum of the products of corresponding entries
        cos_sum = sum(a * b for a, b in zip(Ri, R, strict=True))
        score = jnp.where(cos_sum > near, big, score)
    return jnp.stack(picks, axis=-1), jnp.stack(found, axis=-1)


def _linear_starts(R: Mat3, t: Vec3, m: Matches, iterations: int):
    """The linear method from `K` starts of each problem (`R`, `t` of `(B, K)`), run as
    one flat batch of `B K` poses (each start beside a copy of its problem's matches: the
    kernel's loops run over one long axis, faster than over `(B, K)` with `K` small; one
    problem's matches broadcast to its starts, no copy made). Returns
    `(R, t, error, status, step)` of `(B, K)`."""
    B, K = R.xx.shape
    if K == 1:
        R, t = Mat3(*(a[:, 0] for a in R)), Vec3(*(a[:, 0] for a in t))
    elif B == 1:
        R, t = Mat3(*(a[0] for a in R)), Vec3(*(a[0] for a in t))
    else:
        R, t = Mat3(*(a.reshape(B * K) for a in R)), Vec3(*(a.reshape(B * K) for a in t))
        leaves, tree = jax.tree.flatten(m)
        m = jax.tree.unflatten(tree, stacked(lambda a: jnp.repeat(a, K, axis=0), leaves))
    R1, t1, error, step, status = linear_kernel(R, t, m, iterations)
    R1, t1 = Mat3(*(a.reshape(B, K) for a in R1)), Vec3(*(a.reshape(B, K) for a in t1))
    return R1, t1, error.reshape(B, K), status.reshape(B, K), step.reshape(B, K)


def _mixed_starts(obs: Observations, R0: Mat3, t0: Vec3, started, options: Options):
    """The mixed algorithm's steps 2-4 (`jaxpose.strategy._mixed.job_and_step2`: the linear method,
    Levenberg-Marquardt where it does not reach an accepted pose, the linear method
    again) from the `K` starts of each problem (`(B, K)`), each problem's threshold
    taken from its started runs of step 2 (the acceptance of step 4). Returns the poses
    (`Mat3`, `Vec3` of `(B, K)`), their errors, whether each is accepted (a start that
    exists, accepted by the steps' rule), the statuses and the statuses of step 2's
    runs."""
    B, K = R0.xx.shape
    big = jnp.finfo(obs.camera.dtype).max
    starts = Pose(mat_to_array(R0).reshape(B * K, 3, 3), vec_to_array(t0).reshape(B * K, 3))
    problem = jnp.repeat(jnp.arange(B), K)
    steps = jnp.full((B * K,), options.max_steps, jnp.int32)

    def thresholds(first):  # each problem's, from its started runs of step 2
        converged = started & (first.status.reshape(B, K) == Status.OK)
        lowest = jnp.min(jnp.where(converged, first.error.reshape(B, K), big), axis=-1)
        return threshold(obs, lowest, options)[problem]

    its, bound = options.linear_iterations, options.max_steps
    pose, error, status, first = job_and_step2(obs, thresholds, its, bound, problem, starts, steps)
    R = Mat3(*(pose.R[:, i, j].reshape(B, K) for i in range(3) for j in range(3)))
    t = Vec3(*(pose.t[:, i].reshape(B, K) for i in range(3)))
    status = status.reshape(B, K)
    ok = started & Status.is_success(status)
    return R, t, error.reshape(B, K), ok, status, first.reshape(B, K)


def _best_block(obs: Observations, triplets: Int[Array, "B T 3"], options: Options) -> Best:
    """Steps 2-5 for a block of problems."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    m = matches_from_observations(obs)
    lifted = jax.tree.map(lambda a: a[:, None], m)

    # 2. every root, scored over all matches
    R, t, valid = _roots(obs, m, triplets, options)
    score = pixel_error_kernel(R, t, lifted)
    score = jnp.where(valid & jnp.isfinite(score), score, big)

    # 3. the linear method from the best distinct few (a coplanar model: at least two,
    # its two attitudes; their second run only in a block that has one)
    K = refine_count(options, score.shape[1])
    plane = model_planes(obs.model, obs.mask) if options.planar_partner else None
    two = plane is not None and K == 1 and score.shape[1] > 1
    pick, started = distinct_best(score, R, 2 if two else K)
    picked = take_along([*R, *t], pick, axis=1)
    R0, t0 = Mat3(*picked[:9]), Vec3(*picked[9:])
    its = options.linear_iterations
    if two:
        assert plane is not None
        started = jnp.stack([started[:, 0], started[:, 1] & plane[2]], axis=1)
    if options.refine_with == "mixed":
        # steps 2-4 from every start, its step 2 giving the threshold (one linear kernel)
        R1, t1, lin_error, converged, status_k, lin_status = _mixed_starts(
            obs, R0, t0, started, options
        )
        lin_step = jnp.full_like(lin_error, big)  # (from Levenberg-Marquardt: unknown)
        error = jnp.where(converged, lin_error, big)
        thr = None  # (the steps 2-4 accept by their own rule, the same)
    elif two:
        # (the default: one linear-kernel program for both columns and the partner)
        assert plane is not None
        return _two_attitudes(obs, m, triplets, R0, t0, started, pick, plane, options)
    else:
        R1, t1, lin_error, lin_status, lin_step = _linear_starts(R0, t0, m, its)
        converged = started & (lin_status == Status.OK)
        error = jnp.where(converged, lin_error, big)
        # 4. acceptance, as the mixed algorithm's
        thr = threshold(obs, jnp.min(error, axis=-1), options)
        status_k = jnp.full_like(lin_status, Status.ACCEPTED_LINEAR)
    k = jnp.argmin(error, axis=-1)[:, None]
    chosen = [
        a[:, 0]
        for a in take_along([*R1, *t1, lin_error, converged, pick, status_k, lin_step], k, axis=1)
    ]
    R1, t1, error = Mat3(*chosen[:9]), Vec3(*chosen[9:12]), chosen[12]
    converged_k, root, accepted_status, step = chosen[13], chosen[14], chosen[15], chosen[16]
    accepted = converged_k if thr is None else accepts(converged_k, error, thr)
    pose = Pose(mat_to_array(R1), vec_to_array(t1))

    # 5. the planar partner of the answer (built and refined only in a block that has a
    # coplanar model: the test alone costs a few sums per problem)
    if plane is not None:
        centre, normal, flat = plane
        flat = flat & accepted

        def refine_partner(R1: Mat3, t1: Vec3):
            Rp, tp, finite = planar_partner_batch(obs.camera, R1, t1, centre, normal)
            Rp, tp, other, step_p, status_p = linear_kernel(
                Rp, tp, m, iterations=options.linear_iterations
            )
            refined = Pose(mat_to_array(Rp), vec_to_array(tp))
            return refined, other, finite & (status_p == Status.OK), step_p

        def no_partner(R1: Mat3, t1: Vec3):
            return pose, jnp.full_like(error, big), jnp.zeros_like(accepted), step

        refined, other, ok, step_p = jax.lax.cond(jnp.any(flat), refine_partner, no_partner, R1, t1)
        better = flat & ok & (other < error)
        pose = Pose(
            jnp.where(better[:, None, None], refined.R, pose.R),
            jnp.where(better[:, None], refined.t, pose.t),
        )
        error = jnp.where(better, other, error)
        step = jnp.where(better, step_p, step)

    first = jnp.where(started[:, 0], lin_status[:, 0], Status.NO_SOLUTION)
    return _best(pose, error, accepted, accepted_status, converged_k, first, triplets, root, step)


def _best(pose, error, accepted, accepted_status, converged, first, triplets, root, step) -> Best:
    """The block's `Best`: the chosen candidate's `error` (a converged one), whether it
    is `accepted` (its status then `accepted_status`, else `REJECTED` if `converged`,
    else `first`, the status of the best root's run), the triplet of its `root`."""
    big = jnp.finfo(error.dtype).max
    status = jnp.where(accepted, accepted_status, jnp.where(converged, Status.REJECTED, first))
    triplet = jnp.take_along_axis(triplets, (root // 4)[:, None, None], axis=1)[:, 0]
    return Best(
        pose=pose,
        error=jnp.where(accepted, error, big),
        status=status.astype(jnp.int32),
        triplet=triplet.astype(jnp.int32),
        accepted=accepted,
        step=step,
    )


#: The rows of `_two_attitudes`'s table of rounds: a linear run's pose, error, last step,
#: status, and whether its start was finite (statuses and flags as floats: one array).
_R, _T, _ERROR, _STEP, _STATUS, _FINITE, _ROWS = 0, 9, 12, 13, 14, 15, 16


def _two_attitudes(obs, m, triplets, R0, t0, started, pick, plane, options: Options) -> Best:
    """Steps 3-5 with one start per attitude (the default: `refine=1`, the planar
    partner on): the linear method from the best root (column 0 of `R0`, `t0`), from the
    best distinct root of the other attitude (column 1, `started` only for a flat model;
    run only in a block that has one) and from the planar partner of the answer of those
    two (only in a block where one is flat and accepted). The three are rounds of one
    loop around one linear kernel, so that the program holds the kernel once, not three
    times; the loop's body is only the round's start, the kernel and one write of its
    results into a table of the three rounds (`_ROWS` x `B` each), and the choice among
    them is made once, after the loop (each copy of a kernel, and each value carried
    through the loop, is compiled code: with the programs' compiler options the first
    rung of 64 problems compiles in 2.6-2.7 s of CPU time against 3.0-3.1 s choosing
    inside the loop, AMD EPYC with AVX-512). The same answers as `_best_block`'s general
    steps."""
    dtype = obs.camera.dtype
    big = jnp.finfo(dtype).max
    centre, normal, flat_model = plane
    ok = jnp.asarray(Status.OK, dtype)

    def lower_column(res):
        """Whether column 1 has the lower converged error of rounds 0 and 1 (where
        equal: column 0, as `argmin`), and that error."""
        e0, e1 = (
            jnp.where(started[:, k] & (res[k, _STATUS] == ok), res[k, _ERROR], big) for k in (0, 1)
        )
        return e1 < e0, jnp.minimum(e0, e1)

    def accepted_by(best):
        """Whether that error (the largest float where neither converged) is accepted."""
        return accepts(best < big, best, threshold(obs, best, options))

    def body(state):
        j, res = state
        # the partner of the answer of rounds 0 and 1 (used in round 2 only)
        second = lower_column(res)[0]
        Rc = Mat3(*(jnp.where(second, res[1, _R + i], res[0, _R + i]) for i in range(9)))
        tc = Vec3(*(jnp.where(second, res[1, _T + i], res[0, _T + i]) for i in range(3)))
        Rp, tp, finite = planar_partner_batch(obs.camera, Rc, tc, centre, normal)

        def start(a, p):  # round 0: column 0, round 1: column 1, round 2: the partner
            return jnp.where(j == 0, a[:, 0], jnp.where(j == 1, a[:, 1], p))

        R, t, error, step, status = linear_kernel(
            Mat3(*map(start, R0, Rp)), Vec3(*map(start, t0, tp)), m, options.linear_iterations
        )
        row = jnp.stack([*R, *t, error, step, status.astype(dtype), finite.astype(dtype)])
        zero = jnp.zeros((), j.dtype)
        return j + 1, jax.lax.dynamic_update_slice(res, row[None], (j, zero, zero))

    def more(state):
        j, res = state
        partner = jnp.any(flat_model & accepted_by(lower_column(res)[1]))
        return (j == 0) | ((j == 1) & jnp.any(flat_model)) | ((j == 2) & partner)

    table = jnp.zeros((3, _ROWS, started.shape[0]), dtype)
    rounds, table = jax.lax.while_loop(more, body, (jnp.int32(0), table))

    # 4. the lower converged error of the two columns (column 1 is one only where it was
    # started: a flat model, whose block ran round 1), accepted as the mixed algorithm
    second, best = lower_column(table)
    got = [jnp.where(second, table[1, i], table[0, i]) for i in range(_ROWS)]
    converged_k, accepted = best < big, accepted_by(best)
    error, step = got[_ERROR], got[_STEP]
    root = jnp.where(second, pick[:, 1], pick[:, 0])

    # 5. the partner kept where it converges to a lower error
    partner = table[2]
    found = (rounds > 2) & (partner[_FINITE] > 0) & (partner[_STATUS] == ok)
    better = flat_model & accepted & found & (partner[_ERROR] < error)
    R = Mat3(*(jnp.where(better, partner[_R + i], got[i]) for i in range(9)))
    t = Vec3(*(jnp.where(better, partner[_T + i], got[9 + i]) for i in range(3)))
    error = jnp.where(better, partner[_ERROR], error)
    step = jnp.where(better, partner[_STEP], step)
    pose = Pose(mat_to_array(R), vec_to_array(t))
    first = jnp.where(started[:, 0], table[0, _STATUS].astype(jnp.int32), Status.NO_SOLUTION)
    return _best(
        pose, error, accepted, Status.ACCEPTED_LINEAR, converged_k, first, triplets, root, step
    )


def block_size(triplets: int) -> int:
    """Problems per block of `best_of_roots_batch`: about `BLOCK_TRIPLETS` triplets."""
    return max(1, BLOCK_TRIPLETS // max(triplets, 1))


def best_of_roots_batch(
    obs: Observations, triplets: Int[ArrayLike, "B T 3"], options: Options
) -> Best:
    """Steps 2-5 of the module docstring for a batch of problems (no fallback), in blocks
    of `block_size(T)` problems.

    **Arguments:** `obs` (a leading `B` axis; without gradient: the answer's derivative
    is attached afterwards by `jaxpose.strategy._implicit.polish`); `triplets`
    `(B, T, 3)`; `options` (read: `min_area`, `collinear_tol`, `linear_iterations`,
    `threshold`, `rel_threshold`, `planar_partner`, `refine`).
    """
    triplets = jnp.asarray(triplets, jnp.int32)
    return in_chunks(
        lambda o, tr: _best_block(o, tr, options),
        obs,
        triplets,
        size=block_size(triplets.shape[1]),
    )


def best_of_roots(obs: Observations, triplets: Int[ArrayLike, "T 3"], options: Options) -> Best:
    """`best_of_roots_batch` for one problem (`triplets` `(T, 3)`)."""
    one = jax.tree.map(lambda a: jnp.asarray(a)[None], obs)
    best = best_of_roots_batch(one, jnp.asarray(triplets)[None], options)
    return jax.tree.map(lambda a: a[0], best)
