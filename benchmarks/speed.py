"""Speed of jaxpose against its targets, beside OpenCV and PoseLib timed in the same run.

Every target of `TARGETS` is measured by one section and compared in `targets(res)`:

- `peers`: the paper's bench (`jaxpose.apps.default_bench(seed=0)`, 16 matches, 560
  triplets) through the lean loops the protocol is compared with: OpenCV (`solveP3P` on
  every usable triplet, the best root over all matches, `solvePnPRefineLM` once), PoseLib
  (`p3p`, the best root, `refine_absolute_pose` once), and `cv2.solvePnP(SQPNP)` +
  `solvePnPRefineLM`.
- `paper`: the paper protocol, every triplet's statistics: `jax.jit(jaxpose.strategy.mixed)`
  on the bench (`paper_ms`).
- `paper_phases`: what that protocol's time is made of, each phase compiled alone.
- `latency`: one `jaxpose.solve_pnp` call with its defaults, Python included, on the bench
  (`latency_bench_ms`, and `latency_vs_lean_opencv` against the lean OpenCV loop timed
  side by side with it, in alternating rounds), on a
  9 x 6 planar chessboard grid (n = 54, `latency_n54_ms`) and on 200 random non-planar
  points (`latency_n200_ms`), each beside SQPnP + RefineLM on the same problem.
- `batch`: `jaxpose.solve_pnp_batch` with its defaults over B problems (n = 16, 1 px,
  `_harness.batch_problems`) against a loop of `cv2.solvePnP(SQPNP)` +
  `cv2.solvePnPRefineLM` over the same problems (`batch_vs_loop` at the largest B), the
  share of problems at the ML optimum (`batch_at_optimum`), and the peak resident memory
  of a fresh process making that call (`batch_peak_mb`, `_speed_workers.py`).
- `classes`: the same call and loop on each problem class of the accuracy protocol
  (`ordinary`, `quasi_singular`, `planar`: `jaxpose.apps.random_scene`, n = 16, 1 px)
  and on the bench's own model at random poses (`bench_model`: its 16 matched vertices,
  a uniform random attitude 1.5-2.5 m in front of its camera, 0.7 px), at two batch
  sizes: the least ratio over the classes at the larger (`classes_vs_loop`), the least
  share at the ML optimum (`classes_at_optimum`), and the largest growth of the time per
  problem from the smaller batch to the larger (`classes_growth`): a batch costs what
  its problems cost, not what its rarest problem costs.
- `p3p`: the component-form three-point kernel
  (`jaxpose.solvers._kernel_p3p.three_point_batch`), amortised per triplet (`p3p_ns`),
  beside `cv2.solveP3P` and `poselib.p3p` called per triplet.
- `linear_step`: one depth-weighted Gauss-Newton step in component form, n = 16, float64,
  per start (`benchmarks.kernels.step`, `linear_step_ns`).

Every jaxpose time is the least wall time over repeats of a call after warm-up calls;
its compile time (the first call less the best one) is reported apart. Run through
`benchmarks/run.py`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from benchmarks._harness import (
    K_PIXELS,
    batch_problems,
    bench_problem,
    opencv_block,
    random_rotations,
    side_by_side,
    spawn,
    timeit,
    verdict,
)


@dataclasses.dataclass(frozen=True)
class Target:
    """A speed target: `bound` in `unit`, `higher_is_better` (a ratio or a share) or not
    (a time or a memory). `unit` `"%"`: a share in [0, 1], shown in percent."""

    bound: float
    higher_is_better: bool
    unit: str
    what: str


TARGETS = {
    "batch_vs_loop": Target(
        8.0, True, "x", "solve_pnp_batch (defaults), n = 16, vs an OpenCV loop"
    ),
    "batch_at_optimum": Target(0.999, True, "%", "those problems at the ML optimum"),
    "batch_peak_mb": Target(1024.0, False, "MB", "peak RSS of a process making that call"),
    "classes_vs_loop": Target(
        8.0, True, "x", "the same on every problem class (the least), B = 10^4"
    ),
    "classes_at_optimum": Target(0.999, True, "%", "those problems at the ML optimum (least)"),
    "classes_growth": Target(
        1.2, False, "x", "time per problem, B = 10^4 over B = 2,000 (the largest)"
    ),
    "latency_bench_ms": Target(1.5, False, "ms", "solve_pnp (defaults), the bench, n = 16"),
    "latency_vs_lean_opencv": Target(60.0, True, "x", "the same vs the lean OpenCV loop"),
    "latency_n54_ms": Target(2.0, False, "ms", "solve_pnp, n = 54, planar 9 x 6 grid"),
    "latency_n200_ms": Target(5.0, False, "ms", "solve_pnp, n = 200, non-planar"),
    "paper_ms": Target(3.0, False, "ms", "paper protocol, jit(strategy.mixed)"),
    "p3p_ns": Target(400.0, False, "ns", "three-point kernel, per triplet"),
    "linear_step_ns": Target(500.0, False, "ns", "linear step, n = 16, float64, per start"),
}

# Untimed calls before a compiled function is timed: the first (compile included, its
# time reported) and three more (the first few calls after a compile run up to 1.5x
# slower).
WARMUP = 4


@dataclasses.dataclass(frozen=True)
class Sizes:
    """The sizes and repeats of one run (`FULL` for `make bench`, `QUICK` for `--quick`)."""

    repeat: int
    batch: tuple[int, ...]
    batch_repeat: int
    p3p: int
    linear: int
    classes: tuple[int, int] = (2000, 10_000)
    memory: bool = True


FULL = Sizes(repeat=50, batch=(1, 10, 100, 1000, 10_000), batch_repeat=7, p3p=100_000, linear=8000)
QUICK = Sizes(
    repeat=20, batch=(100, 1000), batch_repeat=3, p3p=20_000, linear=8000, classes=(200, 1000)
)


# --------------------------------------------------------------------------- helpers


def _rms(obj, img, K, rvec, tvec) -> float:
    proj, _ = cv2.projectPoints(obj, np.asarray(rvec, float), np.asarray(tvec, float), K, None)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))


def _compile(timing) -> float | None:
    """The compile time of a timed call: its first call less its best one."""
    return None if timing.first is None else max(timing.first - timing.best, 0.0)


def sqpnp_lm(obj, img, K) -> tuple[np.ndarray, np.ndarray]:
    """The OpenCV answer: `cv2.solvePnP(SQPNP)` refined by `cv2.solvePnPRefineLM`."""
    _, rv, tv = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
    return cv2.solvePnPRefineLM(obj, img, K, None, rv, tv)


def _bench_loops(bench):
    """The lean loops of the bench: OpenCV's and PoseLib's (P3P on every usable triplet,
    the best root by its RMS over all matches, one refinement of it)."""
    import poselib

    K = np.asarray(bench.K, float)
    obj, img = np.asarray(bench.model_points, float), np.asarray(bench.image_points, float)
    trip = jp.strategy.triplet_indices(len(obj))

    def opencv_loop():
        best = None
        for ijk in trip:
            try:
                n, rvecs, tvecs = cv2.solveP3P(obj[ijk], img[ijk], K, None, flags=cv2.SOLVEPNP_P3P)
            except cv2.error:  # a degenerate triplet
                continue
            for rv, tv in zip(rvecs[:n], tvecs[:n], strict=False):
                e = _rms(obj, img, K, rv, tv)
                if np.isfinite(e) and (best is None or e < best[0]):
                    best = (e, rv, tv)
        assert best is not None
        return cv2.solvePnPRefineLM(obj, img, K, None, best[1].copy(), best[2].copy())

    rays = np.column_stack([img, np.ones(len(img))]) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    width, height = bench.image_size
    camera = {
        "model": "PINHOLE",
        "width": int(width),
        "height": int(height),
        "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
    }

    def poselib_loop():
        best = None
        for ijk in trip:
            for pose in poselib.p3p(rays[ijk], obj[ijk]):
                p = obj @ pose.R.T + pose.t
                uv = p[:, :2] / p[:, 2:] * K[0, 0] + K[:2, 2]
                e = float(np.sqrt(np.mean(np.sum((uv - img) ** 2, axis=1))))
                if np.isfinite(e) and (best is None or e < best[0]):
                    best = (e, pose)
        assert best is not None
        return poselib.refine_absolute_pose(img, obj, best[1], camera, {})

    return len(trip), opencv_loop, poselib_loop


# --------------------------------------------------------------------------- sections


def peers(repeat: int) -> dict:
    """The bench's lean OpenCV and PoseLib loops and SQPnP + RefineLM (best of repeats)."""
    bench = jp.apps.default_bench(seed=0)
    count, opencv_loop, poselib_loop = _bench_loops(bench)
    loops = max(3, repeat // 5)
    cv = timeit(opencv_loop, warmup=1, repeat=loops, block=False).best
    pl = timeit(poselib_loop, warmup=1, repeat=loops, block=False).best
    obj, img, K = bench.model_points, bench.image_points, bench.K
    sq = timeit(sqpnp_lm, obj, img, K, warmup=1, repeat=max(repeat, 50), block=False).best
    return {
        "triplets": count,
        "opencv_loop_ms": 1e3 * cv,
        "poselib_loop_ms": 1e3 * pl,
        "sqpnp_lm_us": 1e6 * sq,
    }


def paper(repeat: int) -> dict:
    """`jax.jit(jaxpose.strategy.mixed)` on the bench: every triplet's statistics."""
    _, (C, M, I) = bench_problem(seed=0)
    obs = jp.geometry.observations(C, M, I)
    t = timeit(jax.jit(jp.strategy.mixed), obs, warmup=WARMUP, repeat=repeat)
    return {
        "triplets": int(jp.strategy.triplet_indices(M.shape[0]).shape[0]),
        "jaxpose_ms": 1e3 * t.best,
        "first_call_s": t.first,
        "compile_s": _compile(t),
    }


def paper_phases(repeat: int, mixed_ms: float | None = None) -> dict:
    """What the paper protocol's time is made of (each phase compiled alone, best of
    `repeat`, ms): three-point roots alone; step 1 (roots and their Eq. 8 errors over all
    matches); step 2 (the linear method from every triplet's pose); the mixed algorithm
    (steps 1-4 and the retries; `mixed_ms` when `paper` has timed it); `solve` (the
    mixed algorithm, the answer's polish and its derivative)."""
    initial_poses, mixed = jp.strategy.initial_poses, jp.strategy.mixed
    _, (C, M, I) = bench_problem(seed=0)
    obs = jp.geometry.observations(C, M, I)
    trip = jnp.asarray(jp.strategy.triplet_indices(M.shape[0]))
    start = jax.jit(initial_poses)(obs).pose

    def roots(o):
        three_point = jp.solvers.three_point
        return jax.vmap(lambda ijk: three_point(o.camera, o.model[ijk], o.image[ijk]))(trip)

    def step2(o, p):
        return jax.vmap(lambda q: jp.solvers.linear(o, q))(p)

    phases = {
        "three_point_ms": (roots, (obs,)),
        "step1_ms": (initial_poses, (obs,)),
        "step2_linear_ms": (step2, (obs, start)),
        "mixed_ms": (mixed, (obs,)),
        "solve_ms": (jp.solve, (C, M, I)),
    }
    out: dict = {"triplets": int(trip.shape[0]), "mixed_ms": mixed_ms}
    for name, (fn, args) in phases.items():
        if out.get(name) is None:
            out[name] = 1e3 * timeit(jax.jit(fn), *args, warmup=WARMUP, repeat=repeat).best
    return out


def chessboard_problem(seed: int = 0, noise: float = 0.5):
    """A 9 x 6 grid of a chessboard's inner corners (25 mm squares) at a random pose in
    front of the `K_PIXELS` camera (0.35-0.6 m away, tilted up to ~35 degrees), `noise` px:
    `(object points (54, 3), pixels (54, 2))` in OpenCV's convention."""
    rng = np.random.default_rng(seed)
    model, inner = jp.apps.chessboard((9, 6), 0.025)
    grid = model.vertices[inner]
    grid = grid - grid.mean(axis=0)
    rvec = rng.normal(size=3)
    rvec *= rng.uniform(0.2, 0.6) / np.linalg.norm(rvec)
    t = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.35, 0.6)])
    proj, _ = cv2.projectPoints(grid, rvec, t, K_PIXELS, None)
    img = proj.reshape(-1, 2) + rng.normal(scale=noise, size=(len(grid), 2))
    return np.ascontiguousarray(grid), img


def _latency_row(obj, img, K, repeat: int) -> dict:
    ours = timeit(jp.solve_pnp, obj, img, K, warmup=WARMUP, repeat=repeat, block=False)
    sq = timeit(sqpnp_lm, obj, img, K, warmup=1, repeat=max(repeat, 20), block=False)
    ok, rvec, tvec = ours.result
    rv, tv = sq.result
    return {
        "n": len(obj),
        "ms": 1e3 * ours.best,
        "first_call_s": ours.first,
        "compile_s": _compile(ours),
        "sqpnp_lm_us": 1e6 * sq.best,
        "ok": bool(ok),
        "rms_px": _rms(obj, img, K, rvec, tvec),
        "sqpnp_lm_rms_px": _rms(obj, img, K, rv, tv),
    }


def latency(repeat: int) -> dict:
    """One `solve_pnp` call with its defaults (Python included): the bench, n = 54, n = 200.

    On the bench, `solve_pnp` and the lean OpenCV loop are also timed side by side
    (`side_by_side`: `max(3, repeat // 5)` rounds of `repeat` calls and one loop): the
    ratio of the target is theirs (`vs_lean_opencv`)."""
    bench = jp.apps.default_bench(seed=0)
    obj54, img54 = chessboard_problem(seed=0)
    obj200, img200 = batch_problems(1, 200, seed=5)
    obj, img, K = bench.model_points, bench.image_points, bench.K
    row = _latency_row(obj, img, K, repeat)
    _, opencv_loop, _ = _bench_loops(bench)
    opencv_loop()
    pair = side_by_side(lambda: jp.solve_pnp(obj, img, K), opencv_loop, max(3, repeat // 5), repeat)
    row.update(
        ms=min(row["ms"], pair["ms"]),
        lean_opencv_loop_ms=pair["peer_ms"],
        vs_lean_opencv=pair["peer_ms"] / pair["ms"],
        after_loop_ms=pair["after_peer_ms"],
    )
    return {
        "bench": row,
        "n54": _latency_row(obj54, img54, K_PIXELS, repeat),
        "n200": _latency_row(obj200[0], img200[0], K_PIXELS, repeat),
    }


def at_optimum(err: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Whether each RMS error `err` is at the ML optimum: within 1e-6 relative (or 1e-9 px
    absolute) of the refined OpenCV answer's `ref`, or lower."""
    return err - ref <= np.maximum(1e-6 * ref, 1e-9)


def batch(sizes: Sequence[int], repeat: int, seed: int = 1) -> list[dict]:
    """`solve_pnp_batch` with its defaults over each `B` of `sizes` (the first problems of
    one draw), against the SQPnP + RefineLM loop over the same problems."""
    K = K_PIXELS
    largest = max(sizes)
    obj_all, img_all = batch_problems(largest, 16, seed=seed, pool=largest)
    ref = np.empty(largest)
    for i in range(largest):
        ref[i] = _rms(obj_all[i], img_all[i], K, *sqpnp_lm(obj_all[i], img_all[i], K))

    # OpenCV per-problem time: the best of loops over 100 problems (each block of the
    # batch once, then the first block again), so that it is measured like jaxpose's
    # (best of repeated calls; one long loop on a loaded machine absorbs every stall).
    count = min(100, largest)
    starts = range(0, largest - count + 1, count)
    each = iter(starts)
    blocks = timeit(
        lambda: opencv_block(obj_all, img_all, K, next(each), count),
        warmup=0,
        repeat=len(starts),
        block=False,
    )
    again = timeit(
        opencv_block, obj_all, img_all, K, 0, count, warmup=0, repeat=max(repeat, 5), block=False
    )
    per_cv = min(blocks.best, again.best) / count
    rows = []
    for B in sizes:
        obj, img = obj_all[:B], img_all[:B]
        call = timeit(jp.solve_pnp_batch, obj, img, K, warmup=2, repeat=repeat)
        ok, rvecs, tvecs = call.result
        err = np.array([_rms(obj[i], img[i], K, rvecs[i], tvecs[i]) for i in range(B)])
        rows.append(
            {
                "B": B,
                "jaxpose_s": call.best,
                "first_call_s": call.first,
                "compile_s": _compile(call),
                "opencv_s": per_cv * B,
                "vs_opencv": per_cv * B / call.best,
                "per_problem_us": 1e6 * call.best / B,
                "at_optimum": float(np.mean(at_optimum(err, ref[:B]))),
                "ok": float(np.mean(ok)),
            }
        )
    return rows


#: The problem classes of `classes`: the accuracy protocol's and the bench's own model.
CLASSES = ("ordinary", "quasi_singular", "planar", "bench_model")


def class_problems(kind: str, count: int, seed: int = 1):
    """`count` problems of class `kind` (see `CLASSES` and the module docstring), OpenCV's
    convention: `(K, obj (B, 16, 3), img (B, 16, 2))`."""
    rng = np.random.default_rng(seed)
    if kind != "bench_model":
        scenes = [
            jp.apps.random_scene(rng, 16, noise=1.0, kind=kind, world_camera=False)
            for _ in range(count)
        ]
        obj = np.stack([sc.model_points for sc in scenes])
        return K_PIXELS, obj, np.stack([sc.image_points for sc in scenes])
    bench = jp.apps.default_bench()
    K, M = bench.K, bench.model_points - bench.model_points.mean(axis=0)
    R = random_rotations(rng, count)
    t = np.column_stack(
        [
            rng.uniform(-200, 200, count),
            rng.uniform(-150, 150, count),
            rng.uniform(1500, 2500, count),
        ]
    )
    pc = np.einsum("bij,nj->bni", R, M) + t[:, None]
    uv = pc[..., :2] / pc[..., 2:] * K[0, 0] + K[:2, 2]
    img = uv + rng.normal(scale=bench.noise, size=uv.shape)
    return K, np.broadcast_to(M, (count, *M.shape)).copy(), img


def classes(sizes: tuple[int, int], repeat: int, seed: int = 1) -> dict:
    """`solve_pnp_batch` with its defaults on each class of `CLASSES` at the two batch
    sizes (the first problems of one draw), beside the SQPnP + RefineLM loop (its time
    per problem: the best of loops over blocks of 100 problems, as in `batch`)."""
    small, large = sizes
    out = {}
    for kind in CLASSES:
        K, obj, img = class_problems(kind, large, seed=seed)
        ref = np.array(
            [_rms(obj[i], img[i], K, *sqpnp_lm(obj[i], img[i], K)) for i in range(large)]
        )
        count = min(100, large)
        starts = iter(range(0, large - count + 1, count))
        blocks = timeit(
            lambda: opencv_block(obj, img, K, next(starts), count),
            warmup=0,
            repeat=min(20, large // count),
            block=False,
        )
        per_cv = blocks.best / count
        row: dict = {"opencv_us": 1e6 * per_cv}
        for B in (small, large):
            call = timeit(jp.solve_pnp_batch, obj[:B], img[:B], K, warmup=2, repeat=repeat)
            ok, rvecs, tvecs = call.result
            err = np.array([_rms(obj[i], img[i], K, rvecs[i], tvecs[i]) for i in range(B)])
            row[str(B)] = {
                "jaxpose_s": call.best,
                "compile_s": _compile(call),
                "per_problem_us": 1e6 * call.best / B,
                "vs_opencv": per_cv * B / call.best,
                "at_optimum": float(np.mean(at_optimum(err, ref[:B]))),
                "ok": float(np.mean(ok)),
            }
        row["growth"] = row[str(large)]["per_problem_us"] / row[str(small)]["per_problem_us"]
        out[kind] = row
        print(
            f"  {kind}: {row[str(large)]['vs_opencv']:.1f}x the loop at B = {large}, "
            f"{100 * row[str(large)]['at_optimum']:.2f}% at the optimum, "
            f"{row['growth']:.2f}x per problem from B = {small}",
            flush=True,
        )
    return {"sizes": [small, large], "classes": out}


def batch_memory(B: int, seed: int = 1, timeout: float = 1800) -> dict:
    """The peak resident memory of a fresh process making the `batch` call over `B`
    problems (`benchmarks/_speed_workers.py`); `{"failed": why}` when it did not finish."""
    spec = {"kind": "batch", "B": B, "n": 16, "seed": seed}
    return spawn("benchmarks._speed_workers", spec, timeout=timeout)


def _triplets(count: int, seed: int):
    """`count` random triplets seen by one camera `C = K [R0 | t0]`: pixels uniform in the
    640 x 480 image, depths in [2, 10]; `(C, model (count, 3, 3), pixels (count, 3, 2))`."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [640, 480], size=(count, 3, 2))
    rays = np.concatenate([uv, np.ones((count, 3, 1))], -1) @ np.linalg.inv(K_PIXELS).T
    pc = rays * rng.uniform(2, 10, size=(count, 3, 1))
    R0 = random_rotations(rng, 1)[0]
    t0 = rng.normal(size=3)
    model = (pc - t0) @ R0  # pc = R0 m + t0
    return K_PIXELS @ np.column_stack([R0, t0]), model, uv


def p3p(count: int, repeat: int, peer_count: int = 2000, seed: int = 2) -> dict:
    """`three_point_batch` over `count` triplets in one call (per triplet), beside
    `cv2.solveP3P` and `poselib.p3p` called on `peer_count` of them one by one."""
    import poselib

    from jaxpose.solvers._kernel_p3p import three_point_batch

    C, model, uv = _triplets(count, seed)
    args = tuple(jnp.asarray(a, jnp.float64) for a in (C, model, uv))
    t = timeit(jax.jit(three_point_batch), *args, warmup=WARMUP, repeat=repeat)
    valid = np.asarray(t.result.valid)
    k = min(peer_count, count)
    K = K_PIXELS

    def opencv():
        for i in range(k):
            cv2.solveP3P(model[i], uv[i], K, None, flags=cv2.SOLVEPNP_P3P)

    rays = np.concatenate([uv[:k], np.ones((k, 3, 1))], -1) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)

    def poselib_loop():
        for i in range(k):
            poselib.p3p(rays[i], model[i])

    cv = timeit(opencv, warmup=0, repeat=3, block=False).best
    pl = timeit(poselib_loop, warmup=0, repeat=3, block=False).best
    return {
        "triplets": count,
        "ns_per_triplet": 1e9 * t.best / count,
        "first_call_s": t.first,
        "compile_s": _compile(t),
        "solved": float(np.mean(valid.any(axis=-1))),
        "peer_triplets": k,
        "opencv_ns_per_triplet": 1e9 * cv / k,
        "poselib_ns_per_triplet": 1e9 * pl / k,
    }


def linear_step(problems: int, repeat: int, reference: bool = True) -> dict:
    """One linear step in component form (`benchmarks.kernels.step`, n = 16, float64),
    per problem and step, beside the vmapped reference step when `reference`."""
    from benchmarks import kernels

    row = kernels.step(problems, jnp.float64, repeat, reference=reference)
    k = row["kernel"]
    out = {
        "problems": problems,
        "n": kernels.N,
        "steps_per_call": kernels.STEPS,
        "ns": k["ns"],
        "cpu_ns": k["cpu_ns"],
        "first_call_s": k["first_s"],
        # The first call runs `STEPS` steps over every problem once, the compile aside.
        "compile_s": None
        if k["first_s"] is None
        else max(k["first_s"] - 1e-9 * k["ns"] * problems * kernels.STEPS, 0.0),
    }
    if reference:
        out["reference_ns"] = row["reference"]["ns"]
    return out


# --------------------------------------------------------------------------- targets


def _get(res: dict, *path) -> Any:
    """`res[path[0]][path[1]]...`, or `None` where a section is missing or failed."""
    x = res
    for key in path:
        try:
            x = x[key]
        except (KeyError, IndexError, TypeError):
            return None
    return x


def _ratio(a, b):
    return None if a is None or b is None or b <= 0 else a / b


def _figures(res: dict) -> dict:
    """For each target: `(figure, peer description or None, peer figure, peer unit,
    compile s)`."""
    bt = _get(res, "batch", -1) or {}
    mem = res.get("batch_memory") or {}
    pe = res.get("peers") or {}
    lat = res.get("latency") or {}
    bench = lat.get("bench") or {}
    p, q, ls = res.get("paper") or {}, res.get("p3p") or {}, res.get("linear_step") or {}
    loop = f"SQPnP + RefineLM loop, B = {bt.get('B')}"
    cl = res.get("classes") or {}
    rows = cl.get("classes") or {}
    large = str(max(cl.get("sizes") or [0]))

    def least(key):
        values = [r[large][key] for r in rows.values() if large in r]
        if not values:
            return None, None
        kind = min(rows, key=lambda k: rows[k][large][key])
        return min(values), kind

    vs, vs_kind = least("vs_opencv")
    opt, _ = least("at_optimum")
    growth = max((r["growth"] for r in rows.values()), default=None)
    # (the first class's first call compiles the programs; the others load them)
    compiled = max((r[large].get("compile_s") or 0.0 for r in rows.values()), default=None)
    sqlm = "SQPnP + RefineLM"
    cv_ms = pe.get("opencv_loop_ms")
    return {
        "batch_vs_loop": (bt.get("vs_opencv"), loop, bt.get("opencv_s"), "s", bt.get("compile_s")),
        "batch_at_optimum": (bt.get("at_optimum"), None, None, None, bt.get("compile_s")),
        "batch_peak_mb": (mem.get("peak_mb"), None, None, None, mem.get("compile_s")),
        "classes_vs_loop": (
            vs,
            f"SQPnP + RefineLM loop on {vs_kind}",
            rows[vs_kind]["opencv_us"] if vs_kind else None,
            "us",
            compiled,
        ),
        "classes_at_optimum": (opt, None, None, None, compiled),
        "classes_growth": (growth, None, None, None, compiled),
        "latency_bench_ms": (
            bench.get("ms"),
            sqlm,
            bench.get("sqpnp_lm_us"),
            "us",
            bench.get("compile_s"),
        ),
        "latency_vs_lean_opencv": (
            bench.get("vs_lean_opencv", _ratio(cv_ms, bench.get("ms"))),
            "lean OpenCV loop",
            bench.get("lean_opencv_loop_ms", cv_ms),
            "ms",
            bench.get("compile_s"),
        ),
        **{
            f"latency_{k}_ms": (
                _get(lat, k, "ms"),
                sqlm,
                _get(lat, k, "sqpnp_lm_us"),
                "us",
                _get(lat, k, "compile_s"),
            )
            for k in ("n54", "n200")
        },
        "paper_ms": (
            p.get("jaxpose_ms"),
            "lean OpenCV loop" + (f"; PoseLib's {pe['poselib_loop_ms']:.1f} ms" if pe else ""),
            cv_ms,
            "ms",
            p.get("compile_s"),
        ),
        "p3p_ns": (
            q.get("ns_per_triplet"),
            "cv2.solveP3P" + (f"; poselib.p3p {q['poselib_ns_per_triplet']:.0f} ns" if q else ""),
            q.get("opencv_ns_per_triplet"),
            "ns",
            q.get("compile_s"),
        ),
        "linear_step_ns": (ls.get("ns"), None, None, None, ls.get("compile_s")),
    }


def targets(res: dict) -> dict[str, dict]:
    """Every target of `TARGETS` beside its figure in `res` (the sections' results): the
    figure, the bound, `met` and the verdict (`"met"`, `"missed by 2.7x"`, or `"not
    measured"` where its section is missing or failed), the peer (what and its figure)
    and the compile time of the jaxpose call."""
    out = {}
    for key, (figure, peer, peer_figure, peer_unit, compile_s) in _figures(res).items():
        T = TARGETS[key]
        if figure is None or not math.isfinite(figure):
            figure, met, word = None, None, "not measured"
        elif T.unit == "%":
            met = figure >= T.bound
            word = "met" if met else f"missed by {100 * (T.bound - figure):.2f} points"
        else:
            met = figure >= T.bound if T.higher_is_better else figure <= T.bound
            word = verdict(figure, T.bound, higher_is_better=T.higher_is_better)
        out[key] = {
            "what": T.what,
            "figure": figure,
            "unit": T.unit,
            "target": T.bound,
            "higher_is_better": T.higher_is_better,
            "met": met,
            "verdict": word,
            "peer": peer if peer_figure is not None else None,
            "peer_figure": peer_figure,
            "peer_unit": peer_unit if peer_figure is not None else None,
            "compile_s": compile_s,
        }
    return out


# --------------------------------------------------------------------------- run

SECTIONS = (
    "peers",
    "paper",
    "paper_phases",
    "latency",
    "batch",
    "batch_memory",
    "classes",
    "p3p",
    "linear_step",
)


def run(quick: bool = False, sections: Sequence[str] = SECTIONS, sizes: Sizes | None = None):
    """The `sections` of `SECTIONS` (all by default) at `sizes` (default `QUICK` when
    `quick`, else `FULL`), and the `targets` table of their figures."""
    s = sizes or (QUICK if quick else FULL)
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        raise ValueError(f"unknown sections {sorted(unknown)}; choose from {SECTIONS}")
    res: dict = {"sizes": dataclasses.asdict(s)}
    if "peers" in sections:
        res["peers"] = peers(s.repeat)
    if "paper" in sections:
        res["paper"] = paper(s.repeat)
    if "paper_phases" in sections:
        res["paper_phases"] = paper_phases(s.repeat, _get(res, "paper", "jaxpose_ms"))
    if "latency" in sections:
        res["latency"] = latency(s.repeat)
    if "batch" in sections:
        res["batch"] = batch(s.batch, s.batch_repeat)
    if "batch_memory" in sections and s.memory:
        res["batch_memory"] = batch_memory(max(s.batch))
    if "classes" in sections:
        res["classes"] = classes(s.classes, s.batch_repeat)
    # (The kernels' calls take milliseconds: more repeats, for a steadier least time.)
    if "p3p" in sections:
        res["p3p"] = p3p(s.p3p, s.repeat // 2)
    if "linear_step" in sections:
        res["linear_step"] = linear_step(s.linear, s.repeat // 2)
    res["targets"] = targets(res)
    return res
