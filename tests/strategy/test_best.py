"""The answer from the best-scored roots (`Options.refine`) against the whole mixed
algorithm over every triplet (`refine=None`), and its fallback."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from jaxpose.solvers._components import mat_from_array
from jaxpose.strategy._answer import fallback_slots
from jaxpose.strategy._best import answer_triplets, escalation, rung_applies, spread_matches
from jaxpose.strategy._best_roots import DISTINCT_ANGLE, best_of_roots, distinct_best

# The helpers the tests call outside the solvers, jitted: one program each rather than
# one per eager operation.
_rotvec_to_matrix = jax.jit(jp.geometry.rotvec_to_matrix)
_rotvecs_to_matrices = jax.jit(jax.vmap(jp.geometry.rotvec_to_matrix))
_camera_matrix = jax.jit(jp.camera_matrix)
_project = jax.jit(jp.project)
_observations = jax.jit(jax.vmap(jp.observations))
_is_success = jax.jit(jp.Status.is_success)
_spread_matches = jax.jit(spread_matches, static_argnums=2)
_answer_triplets = jax.jit(answer_triplets, static_argnums=1)


def _problems(kind: str, n: int, B: int, noise: float, seed: int):
    rng = np.random.default_rng(seed)
    scenes = [jp.apps.random_scene(rng, n, noise=noise, kind=kind) for _ in range(B)]
    C = np.stack([s.camera for s in scenes])
    M = np.stack([s.model_points for s in scenes])
    I = np.stack([s.image_points for s in scenes])
    return C, M, I


# Every `solve_many` of this file runs on one shape, `SHAPE` = (problems, matches): fewer
# matches are padded (repeating the first, masked out), so that each program (the whole
# mixed algorithm above all, `_many(None)`) is compiled once for the file, not per shape.
SHAPE = (12, 13)


def _padded(C, M, I):
    """`(C, M, I, mask)` of `SHAPE`: `B = SHAPE[0]` problems of up to `SHAPE[1]` matches,
    the missing matches repeating the first, masked out."""
    B, n = M.shape[:2]
    assert (B, n) <= SHAPE and B == SHAPE[0], (B, n)
    pad = SHAPE[1] - n
    M, I = (np.concatenate([x, np.repeat(x[:, :1], pad, axis=1)], axis=1) for x in (M, I))
    mask = np.broadcast_to(np.arange(SHAPE[1]) < n, (B, SHAPE[1]))
    return C, M, I, mask


@functools.cache
def _many(refine, wider_spread=12):
    """`solve_many` with this `refine` and `wider_spread`, values only
    (`derivative=False`: the answers are compared, not their derivatives; a smaller
    program to compile), on problems of `SHAPE` (`_padded`)."""

    def run(C, M, I, mask):
        assert M.shape[:2] == SHAPE, M.shape
        return jp.solve_many(
            C, M, I, mask, refine=refine, wider_spread=wider_spread, derivative=False
        )

    return jax.jit(run)


def test_best_roots_reach_the_answer_of_every_triplet():
    """Same pose and error as the whole mixed algorithm, problem by problem (ordinary and
    planar scenes of 7 matches in one batch, padded to `SHAPE`)."""
    parts = [_problems(kind, 7, 6, noise=1.0, seed=3) for kind in ("ordinary", "planar")]
    C, M, I = (np.concatenate(x) for x in zip(*parts, strict=True))
    args = _padded(C, M, I)
    quick, full = _many(4)(*args), _many(None)(*args)
    assert np.all(np.asarray(quick.accepted) == np.asarray(full.accepted))
    np.testing.assert_allclose(quick.error, full.error, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(quick.pose.R, full.pose.R, atol=1e-7)
    np.testing.assert_allclose(quick.pose.t, full.pose.t, atol=1e-6)
    np.testing.assert_array_equal(_is_success(quick.status), _is_success(full.status))


def _collinear_spread(B: int, seed: int, noise: float = 0.5, inner: int = 0):
    """`B` problems of `7 + inner` matches (OpenCV's convention, `C = K [I | 0]`) whose
    four matches farthest apart in the image (`spread_matches`) lie on one line: four
    points on a 3D line, three off it near its ends, `inner` off it near its middle."""
    rng = np.random.default_rng(seed)
    C = np.asarray(_camera_matrix(np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])))
    M, I = [], []
    for _ in range(B):
        d = rng.normal(size=3) * [1, 1, 0.15]
        d *= 1.8 / np.linalg.norm(d)
        e = rng.normal(size=(3, 3))
        e -= np.outer(e @ d, d) / (d @ d)  # perpendicular to the line
        e *= 0.25 / np.linalg.norm(e, axis=1, keepdims=True)
        centre = np.array([0.0, 0.0, 6.0])
        line = [centre + u * d for u in (-1.0, 0.0, 0.5, 1.0)]
        off = [centre + 0.9 * d + e[0], centre - 0.9 * d + e[1], centre + 0.85 * d + e[2]]
        mid = [centre + rng.uniform(-0.4, 0.4) * d + e[k % 3] * 0.6 for k in range(inner)]
        pc = np.array(line + off + mid)  # camera frame
        R = _rotvec_to_matrix(rng.normal(size=3))
        t = rng.normal(size=3)
        M.append((pc - t) @ np.asarray(R))  # pc = R m + t
        uv = np.asarray(_project(C, pc))
        I.append(uv + rng.normal(scale=noise, size=uv.shape))
    return np.broadcast_to(C, (B, 3, 4)), np.stack(M), np.stack(I)


def test_escalation_rungs():
    """The ladder: spread roots, wider roots, the whole algorithm; each rung a single
    rung; no ladder without the fallback, for `refine=None` or another method."""
    rungs = escalation(jp.Options())
    assert [(r.spread_points, r.refine, r.refine_with, r.fallback) for r in rungs] == [
        (4, 1, "linear", False),
        (12, 8, "mixed", False),
        (4, None, "linear", True),
    ]
    assert all(escalation(r) == (r,) for r in rungs)
    assert len(escalation(jp.Options(wider_spread=None))) == 2
    assert len(escalation(jp.Options(spread_points=12))) == 2
    for options in (
        jp.Options(fallback=False),
        jp.Options(refine=None),
        jp.Options(method="linear"),
    ):
        assert escalation(options) == (options,)


def test_wider_rung_settles_what_the_spread_roots_leave():
    """Where the spread matches are collinear (every one of their triplets degenerate),
    the next rung, the mixed algorithm's steps 2-4 from the best roots of the triplets
    of 12 spread matches (of 13), accepts every problem at the whole mixed algorithm's
    optimum, from triplets the first rung never tried (one match off the line); on 7
    matches (no triplet left out) the problems skip it, to the whole algorithm."""
    opts = jp.Options(spread_points=12, refine=8, refine_with="mixed", fallback=False)
    assert escalation(jp.Options())[1] == dataclasses.replace(opts, derivative=True)
    assert list(rung_applies(opts, np.array([7, 12, 13, 16]))) == [False, False, True, True]
    args = _padded(*_collinear_spread(12, seed=4, inner=6))  # 13 matches: no padding
    wider = jax.jit(
        lambda C, M, I, mask: jp.solve_many(C, M, I, mask, options=opts, derivative=False)
    )
    wider, full = wider(*args), _many(None)(*args)
    assert np.all(np.asarray(wider.accepted)) and np.all(np.asarray(full.accepted))
    assert np.all(np.max(np.asarray(wider.triplet), axis=1) >= 4)
    assert np.all(np.asarray(_is_success(wider.status)))
    np.testing.assert_allclose(wider.error, full.error, rtol=1e-9)
    np.testing.assert_allclose(wider.pose.R, full.pose.R, atol=1e-9)
    np.testing.assert_allclose(wider.pose.t, full.pose.t, rtol=1e-6, atol=1e-6)


def test_a_plain_call_runs_each_later_rung_on_the_problems_it_needs():
    """A plain `solve_many` (concrete arrays: the stored programs) runs the first rung on
    every problem and each later rung only on the problems the rungs before it left,
    gathered into a program of their own size: here the problems whose spread matches
    are collinear climb to the middle rung, which settles them; the last rung's program
    is neither built nor run. The programs are the values-only ones (nothing
    differentiates a plain call). The answers are the whole mixed algorithm's."""
    from jaxpose.api._programs import program
    from jaxpose.api._stored import _stored_program, bucket_problems, values_only
    from jaxpose.strategy import split_values

    hard, easy = _collinear_spread(3, seed=4, inner=6), _problems("ordinary", 13, 9, 1.0, 3)
    C, M, I = (np.concatenate([e, h]) for e, h in zip(easy, hard, strict=True))
    left = ~np.asarray(jp.solve_many(C, M, I, fallback=False).accepted)  # the first rung
    assert 1 <= left.sum() and not left[:9].any()
    rungs = escalation(values_only(split_values(jp.Options())[0]))  # (what it runs)
    programs = [program(_stored_program, rung, False) for rung in rungs]
    before = [set(p._memo) for p in programs]
    out = jp.solve_many(C, M, I)
    new = [set(p._memo) - b for p, b in zip(programs, before, strict=True)]
    rows = [{signature[3][0][0] for signature in n} for n in new]  # (the model's shape)
    assert rows[1:] == [{bucket_problems(int(left.sum()))}, set()] and rows[0] <= {16}
    full = _many(None)(*_padded(C, M, I))
    assert np.all(np.asarray(out.accepted)) and np.all(np.asarray(full.accepted))
    assert np.all(np.max(np.asarray(out.triplet[left]), axis=1) >= 4)
    np.testing.assert_allclose(out.error, full.error, rtol=1e-9)
    np.testing.assert_allclose(out.pose.R, full.pose.R, atol=1e-9)
    np.testing.assert_allclose(out.pose.t, full.pose.t, rtol=1e-6, atol=1e-6)


def test_fallback_runs_the_whole_mixed_algorithm():
    """Where the best roots give nothing (the spread matches are collinear: every one of
    their triplets is degenerate) and the wider rung does not apply (7 matches, no more
    than its 12: it would leave no triplet out), every problem falls back, in passes of
    `fallback_slots(B)` problems: the outcome is the whole mixed algorithm's, which finds
    the pose from the other triplets. (The default ladder, `wider_spread=12`, whose
    program `test_best_roots_reach_the_answer_of_every_triplet` compiled: on these
    problems it is `wider_spread=None`'s, spread roots then the whole algorithm.)"""
    C, M, I = _collinear_spread(12, seed=4)
    chosen = np.asarray(_spread_matches(I, np.ones((12, 7), bool), 4))
    assert np.all(np.sort(chosen, axis=1) == [0, 1, 2, 3])  # the line's four
    assert fallback_slots(12) == 1  # twelve passes
    args = _padded(C, M, I)
    wider_rung = escalation(jp.Options(refine=4, wider_spread=12))[1]
    assert wider_rung.refine_with == "mixed"
    assert not np.any(rung_applies(wider_rung, np.sum(args[3], axis=1)))
    quick, full = _many(4)(*args), _many(None)(*args)
    assert np.all(np.asarray(full.accepted))
    # every answer comes from a triplet the best roots never tried (one off the line)
    assert np.all(np.max(np.asarray(quick.triplet), axis=1) >= 4)
    np.testing.assert_array_equal(quick.status, full.status)
    np.testing.assert_array_equal(quick.accepted, full.accepted)
    # (the same optimum; which of the triplets that reach it is reported may differ:
    # the Levenberg-Marquardt buffer of a pass of one problem is not a batch's)
    np.testing.assert_allclose(quick.error, full.error, rtol=1e-9)
    np.testing.assert_allclose(quick.pose.R, full.pose.R, atol=1e-9)
    np.testing.assert_allclose(quick.pose.t, full.pose.t, rtol=1e-6, atol=1e-6)


def test_best_of_roots_alone():
    """Without the fallback: the best roots are accepted on noisy ordinary problems and
    report the triplet their root came from."""
    C, M, I = _problems("ordinary", 8, 3, noise=1.0, seed=5)
    obs = _observations(C, M, I)
    triplets = jp.strategy.triplet_indices(8)
    best = jax.jit(jax.vmap(lambda o: best_of_roots(o, triplets, jp.Options())))(obs)
    assert np.all(np.asarray(best.accepted))
    assert np.all(np.asarray(best.status) == jp.Status.ACCEPTED_LINEAR)
    rows = [tuple(r) for r in triplets.tolist()]
    assert all(tuple(t) in rows for t in np.asarray(best.triplet).tolist())


def test_spread_matches_is_farthest_point_sampling():
    """Each choice is the used match farthest from those chosen before (the first: from
    the centroid of the used pixels); masked matches are never chosen while used ones
    remain."""
    rng = np.random.default_rng(6)
    image = rng.uniform(0, 500, size=(4, 11, 2))
    mask = rng.uniform(size=(4, 11)) > 0.3
    mask[:, :3] = True
    chosen = np.asarray(_spread_matches(image, mask, 3))
    for b in range(4):
        used = np.flatnonzero(mask[b])
        gap = np.sum((image[b] - image[b, used].mean(axis=0)) ** 2, axis=1)
        picked: list[int] = []
        for j in range(3):
            want = used[np.argmax(gap[used])]
            assert chosen[b, j] == want
            picked.append(int(want))
            away = np.sum((image[b] - image[b, want]) ** 2, axis=1)
            gap = away if j == 0 else np.minimum(gap, away)
        assert len(set(picked)) == 3


def test_answer_triplets_choices():
    """`n <= spread_points`: every triplet; more: the triplets of the spread matches;
    `spread_points=None`: those of `select_triplets`."""
    C, M, I = _problems("ordinary", 9, 2, noise=1.0, seed=7)
    obs = _observations(C, M, I)
    few = _answer_triplets(
        jax.tree.map(lambda a: np.asarray(a)[:, :5], obs), jp.Options(spread_points=6)
    )
    np.testing.assert_array_equal(np.asarray(few)[0], jp.strategy.triplet_indices(5))
    spread = np.asarray(_answer_triplets(obs, jp.Options(spread_points=6)))
    assert spread.shape == (2, 20, 3)
    for b in range(2):
        assert len(np.unique(spread[b])) == 6
    default = np.asarray(_answer_triplets(obs, jp.Options()))
    assert default.shape == (2, 4, 3)
    every = _answer_triplets(obs, jp.Options(spread_points=None))
    np.testing.assert_array_equal(np.asarray(every)[1], jp.strategy.triplet_indices(9))


def test_distinct_best_keeps_its_picks_apart():
    """The picks are in order of score, pairwise more than `DISTINCT_ANGLE` apart, and a
    slot with nothing left is marked not found."""
    rng = np.random.default_rng(8)
    R = np.stack([_rotvec_to_matrix(v) for v in 0.05 * rng.normal(size=(12, 3))])
    R[6:] = np.stack([_rotvec_to_matrix(v) for v in rng.normal(size=(6, 3))])
    score = rng.uniform(size=(1, 12))
    pick, found = jax.jit(lambda s, R: distinct_best(s, mat_from_array(R), 12))(score, R[None])
    pick, found = np.asarray(pick)[0], np.asarray(found)[0]
    kept = pick[found]
    assert np.all(np.diff(score[0][kept]) > 0)
    for a in range(len(kept)):
        for b in range(a):
            cos = (np.trace(R[kept[a]].T @ R[kept[b]]) - 1) / 2
            assert np.arccos(np.clip(cos, -1, 1)) > DISTINCT_ANGLE
    assert not found[-1]


def test_finish_linear_batch_finishes_at_opencvs_optimum():
    """From the optimum moved by about 1e-4 (the linear method's tolerance), two steps
    reach OpenCV's optimum again (SQPnP + RefineLM); a start it cannot improve is kept."""
    from helpers import opencv_optimum

    from jaxpose.strategy._best import Answer, finish_linear_batch

    rng = np.random.default_rng(12)
    scenes = [jp.apps.random_scene(rng, 9, noise=1.0) for _ in range(6)]
    C, M, I = (
        np.stack([getattr(s, a) for s in scenes])
        for a in ("camera", "model_points", "image_points")
    )
    obs = _observations(C, M, I)
    refs = [opencv_optimum(s) for s in scenes]
    R = np.stack([r for r, _ in refs])
    t = np.stack([t for _, t in refs])
    nudge = np.asarray(_rotvecs_to_matrices(rng.normal(scale=1e-4, size=(6, 3))))
    start = jp.geometry.Pose(np.einsum("bij,bjk->bik", nudge, R), t * (1 + 1e-4))

    @jax.jit
    def error(obs, pose):
        return jax.vmap(jp.geometry.reprojection_rms)(
            jnp.asarray(C), pose.R, pose.t, jnp.asarray(M), jnp.asarray(I)
        )

    found = Answer(
        np.zeros((6, 3), np.int32),
        start,
        error(obs, start),
        np.ones(6, np.int32),
        np.full(6, np.inf),
    )
    finish = jax.jit(finish_linear_batch)
    settled = finish(obs, found)
    best = np.asarray(error(obs, jp.geometry.Pose(R, t)))
    np.testing.assert_allclose(np.asarray(settled.error), best, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(settled.pose.R), R, atol=1e-6)  # RefineLM: ~1e-7
    assert np.all(np.asarray(settled.error) <= np.asarray(found.error))
    # an answer at the optimum stays there (Gauss-Newton converges linearly: within 1e-8)
    again = finish(obs, settled)
    np.testing.assert_allclose(np.asarray(again.pose.t), np.asarray(settled.pose.t), rtol=1e-8)
