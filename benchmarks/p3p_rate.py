"""P3P: found-the-true-pose rate, accuracy and time of jaxpose beside OpenCV and PoseLib.

Draws random noise-free, non-degenerate instances and solves every one of them with
jaxpose's three-point solver (`jax.jit(jax.vmap(p3p))`, one call for the whole batch),
its batch-first kernel (`jax.jit(p3p_batch)`, the same algorithm in component form),
`cv2.solveP3P(..., flags=cv2.SOLVEPNP_P3P)` (Ding et al., CVPR 2023) and `poselib.p3p`
(Lambda Twist / PoseLib), on the same instances.

Instances: pixels uniform in a 640x480 image (focal 800, principal point at the
centre), depths uniform in [2, 10], a uniformly random rotation and a standard normal
translation (model points m = R^T (p_cam - t)); kept when the image triangle has area
>= 40 px^2 (the paper's threshold) and the model triangle is not nearly collinear (area
/ longest edge^2 >= 1e-3, jaxpose's default).

Per solver: the share of instances where some returned solution is the true pose
(rotation angle error < tol rad and |dt| / |t| < tol; tol = 1e-6 by default), the
99.9th percentile and the median of the best solution's error max(angle, |dt| / |t|),
the mean number of returned solutions (and how many were non-finite), and the time per
triplet: jaxpose amortised over the batch after a warm-up call (best of a few runs; the
vmapped solver and the kernel timed alternately, so that the load of a shared machine
weighs on both alike), the peers as a Python loop of single calls (their figures include
the call overhead).

    python benchmarks/p3p_rate.py --n 100000 --seed 0 --dtype float64

Prints a table and writes JSON to benchmarks/results/p3p_rate.json (float64) or
p3p_rate_float32.json (float32; the peers always run in float64).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/p3p_rate.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from benchmarks._harness import (
    K_PIXELS,
    RESULTS,
    Stopwatch,
    random_rotations,
    rotation_angle,
    timeit_many,
    write_json,
)

K = K_PIXELS
WIDTH, HEIGHT = 640, 480
MIN_AREA = 40.0
COLLINEAR_TOL = 1e-3


def draw(n, seed):
    """`n` random noise-free, non-degenerate instances (see the module docstring)."""
    rng = np.random.default_rng(seed)
    parts = {k: [] for k in ("R", "t", "m", "uv", "f")}
    count, drawn = 0, 0
    while count < n:
        b = n + n // 4 + 16
        uv = rng.uniform([0, 0], [WIDTH, HEIGHT], size=(b, 3, 2))
        rays = np.concatenate([uv, np.ones((b, 3, 1))], -1) @ np.linalg.inv(K).T
        pc = rays * rng.uniform(2, 10, size=(b, 3, 1))
        R = random_rotations(rng, b)
        t = rng.normal(size=(b, 3))
        m = np.einsum("bji,bnj->bni", R, pc - t[:, None])  # pc = R m + t
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        e1, e2, e3 = m[:, 1] - m[:, 0], m[:, 2] - m[:, 0], m[:, 2] - m[:, 1]
        longest = np.max([np.sum(e * e, axis=1) for e in (e1, e2, e3)], axis=0)
        collinear = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1) / longest
        keep = (area >= MIN_AREA) & (collinear >= COLLINEAR_TOL)
        f = pc / np.linalg.norm(pc, axis=-1, keepdims=True)
        for key, val in zip(parts, (R, t, m, uv, f), strict=True):
            parts[key].append(val[keep])
        count += int(keep.sum())
        drawn += b
    out = {k: np.ascontiguousarray(np.concatenate(v)[:n]) for k, v in parts.items()}
    out["rejected_share"] = 1 - count / drawn
    return out


def pose_errors(R_true, t_true, Rs, ts):
    """Rotation angle (rad) and relative translation error of each candidate."""
    Rs, ts = np.asarray(Rs, np.float64), np.asarray(ts, np.float64)
    angle = rotation_angle(Rs, R_true)
    rel_t = np.linalg.norm(ts - t_true, axis=-1) / np.linalg.norm(t_true)
    return angle, rel_t


def summarise(best_angle, best_rel, n_solutions, n_nonfinite, seconds, tol):
    err = np.maximum(best_angle, best_rel)
    found = (best_angle < tol) & (best_rel < tol)
    return {
        "instances": int(len(err)),
        "found_rate": float(np.mean(found)),
        "found": int(found.sum()),
        "found_rate_at_1e-3": float(np.mean(err < 1e-3)),
        "p999_error": float(np.quantile(err, 0.999)),
        "median_error": float(np.median(err)),
        "max_error": float(np.max(err)),
        "mean_solutions": float(np.mean(n_solutions)),
        "nonfinite_solutions": int(np.sum(n_nonfinite)),
        "ns_per_triplet": 1e9 * seconds / len(err),
    }


def best_of(R_true, t_true, candidates):
    """Best (angle, rel) over a list of (R, t) candidates; inf when none is finite."""
    finite = [(R, t) for R, t in candidates if np.isfinite(R).all() and np.isfinite(t).all()]
    if not finite:
        return np.inf, np.inf, len(candidates) - len(finite)
    angle, rel = pose_errors(R_true, t_true, [c[0] for c in finite], [c[1] for c in finite])
    k = np.argmin(np.maximum(angle, rel))
    return angle[k], rel[k], len(candidates) - len(finite)


def _jaxpose_row(data, timing):
    """The accuracy columns of one jaxpose timing (`R`, `t`, `valid` outputs)."""
    import jax

    Rs, ts, valid = (np.asarray(x) for x in timing.result)
    angle, rel = pose_errors(data["R"][:, None], data["t"][:, None], Rs, ts)
    angle = np.where(valid, angle, np.inf)
    rel = np.where(valid, rel, np.inf)
    k = np.argmin(np.maximum(angle, rel), axis=1)
    idx = np.arange(len(k))
    runs = list(timing.times)
    extra = {
        "compile_and_first_call_s": timing.first,
        "runs_s": runs,
        "cpu_s": timing.cpu,
        "device": str(jax.devices()[0]),
    }
    nonfinite = ~(np.isfinite(Rs).all(axis=(-2, -1)) & np.isfinite(ts).all(axis=-1))
    return angle[idx, k], rel[idx, k], valid.sum(1), nonfinite.sum(1), min(runs), extra


def run_jaxpose(data, dtype, repeats, chunk=0, kernel=True):
    """`jax.vmap(p3p)` (with `chunk`: as `lax.map` over vmapped chunks of that size) and,
    with `kernel`, `p3p_batch`, timed alternately on the same instances."""
    import jax
    import jax.numpy as jnp

    from jaxpose.solvers import p3p
    from jaxpose.solvers._kernel_p3p import p3p_batch

    if chunk:
        # The batch as a sequence of vmapped chunks (`lax.map`): each fused kernel then
        # works on cache-resident arrays. Needs len % chunk == 0.
        def batched(f, m):
            shape = (len(f) // chunk, chunk, 3, 3)
            out = jax.lax.map(lambda a: jax.vmap(p3p)(*a), (f.reshape(shape), m.reshape(shape)))
            return jax.tree.map(lambda y: y.reshape(len(f), *y.shape[2:]), out)

        fns = [jax.jit(batched)]
    else:
        fns = [jax.jit(jax.vmap(p3p))]
    if kernel:
        fns.append(jax.jit(p3p_batch))
    f = jnp.asarray(data["f"], dtype)
    m = jnp.asarray(data["m"], dtype)
    timings = timeit_many(fns, f, m, warmup=1, repeat=repeats)
    return [_jaxpose_row(data, timing) for timing in timings]


def run_opencv(data):
    import cv2

    m, uv = data["m"], data["uv"]
    n = len(m)
    results = []
    watch = Stopwatch()
    for i in range(n):
        results.append(cv2.solveP3P(m[i], uv[i], K, None, flags=cv2.SOLVEPNP_P3P))
    seconds = watch.seconds
    out = np.empty((n, 2)), np.empty(n, int), np.empty(n, int)
    for i, (k, rvecs, tvecs) in enumerate(results):
        cands = [(cv2.Rodrigues(r)[0], tv.ravel()) for r, tv in zip(rvecs[:k], tvecs[:k])]
        a, r, bad = best_of(data["R"][i], data["t"][i], cands)
        out[0][i] = a, r
        out[1][i], out[2][i] = len(cands), bad
    return out[0][:, 0], out[0][:, 1], out[1], out[2], seconds, {"version": cv2.__version__}


def run_poselib(data):
    from importlib.metadata import version

    import poselib

    f, m = data["f"], data["m"]
    n = len(m)
    results = []
    watch = Stopwatch()
    for i in range(n):
        results.append(poselib.p3p(f[i], m[i]))
    seconds = watch.seconds
    out = np.empty((n, 2)), np.empty(n, int), np.empty(n, int)
    for i, poses in enumerate(results):
        cands = [(p.R, np.asarray(p.t)) for p in poses]
        a, r, bad = best_of(data["R"][i], data["t"][i], cands)
        out[0][i] = a, r
        out[1][i], out[2][i] = len(cands), bad
    return out[0][:, 0], out[0][:, 1], out[1], out[2], seconds, {"version": version("poselib")}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000, help="instances (default 1e5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dtype", choices=["float64", "float32"], default="float64")
    parser.add_argument("--tol", type=float, default=1e-6, help="found-the-true-pose tolerance")
    parser.add_argument("--repeats", type=int, default=3, help="timed jaxpose runs (best kept)")
    parser.add_argument("--no-peers", action="store_true", help="skip OpenCV and PoseLib")
    parser.add_argument(
        "--chunk",
        type=int,
        default=0,
        help="also time jaxpose as lax.map over vmapped chunks of this size (divides --n)",
    )
    parser.add_argument("--out", default=None, help="JSON path (default benchmarks/results/)")
    args = parser.parse_args(argv)

    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)  # this script's own choice
    import jax.numpy as jnp

    data = draw(args.n, args.seed)
    dtype = jnp.float64 if args.dtype == "float64" else jnp.float32
    vmapped, kernel = run_jaxpose(data, dtype, args.repeats)
    runs = {f"jaxpose p3p ({args.dtype})": vmapped, f"jaxpose kernel ({args.dtype})": kernel}
    if args.chunk:
        name = f"  same, chunks of {args.chunk}"
        runs[name] = run_jaxpose(data, dtype, args.repeats, args.chunk, kernel=False)[0]
    if not args.no_peers:
        runs["cv2.solveP3P (float64)"] = run_opencv(data)
        runs["poselib.p3p (float64)"] = run_poselib(data)

    rows = {}
    for name, (angle, rel, nsol, nonfinite, seconds, extra) in runs.items():
        rows[name] = summarise(angle, rel, nsol, nonfinite, seconds, args.tol) | extra
    # Instances every solver got right / wrong, for a like-for-like reading.
    found = {k: (r[0] < args.tol) & (r[1] < args.tol) for k, r in runs.items()}

    print(
        f"P3P on {args.n} random noise-free non-degenerate instances (seed {args.seed}); "
        f"true pose found = angle and |dt|/|t| < {args.tol:g}"
    )
    head = (
        f"{'solver':<26}{'found':>10}{'found@1e-3':>12}{'p99.9 err':>11}{'median err':>12}"
        f"{'mean #sol':>10}{'non-finite':>11}{'ns/triplet':>12}"
    )
    print(head)
    print("-" * len(head))
    for name, r in rows.items():
        print(
            f"{name:<26}{100 * r['found_rate']:>9.4f}%{100 * r['found_rate_at_1e-3']:>11.4f}%"
            f"{r['p999_error']:>11.2e}{r['median_error']:>12.2e}{r['mean_solutions']:>10.3f}"
            f"{r['nonfinite_solutions']:>11d}{r['ns_per_triplet']:>12.0f}"
        )
    names = list(found)
    missed = {k: int((~v).sum()) for k, v in found.items()}
    print(f"missed instances: {missed}")
    if len(names) > 1:
        ours = found[names[0]]
        for other in (k for k in names[1:] if not k.startswith(" ")):
            only_other = int((found[other] & ~ours).sum())
            only_ours = int((ours & ~found[other]).sum())
            print(f"  found by {other} but not jaxpose: {only_other}; the reverse: {only_ours}")
    for name in names[:2]:
        r = rows[name]
        print(
            f"{name}: compile + first call {r['compile_and_first_call_s']:.1f} s, timed runs "
            f"{', '.join(f'{x:.3f}' for x in r['runs_s'])} s for {args.n} triplets"
        )
    ref_row, kernel_row = rows[names[0]], rows[names[1]]
    speedup = ref_row["ns_per_triplet"] / kernel_row["ns_per_triplet"]
    print(
        f"kernel / vmap(p3p): {speedup:.1f} times faster (wall), "
        f"{ref_row['cpu_s'] / kernel_row['cpu_s']:.1f} times (process CPU); "
        f"peers timed as a Python loop of single calls; {os.cpu_count()} CPUs"
    )

    result = {
        "args": vars(args),
        "instances": {"n": args.n, "rejected_as_degenerate_share": data["rejected_share"]},
        "rows": rows,
        "kernel_speedup": speedup,
        "jax_version": jax.__version__,
        "machine": platform.platform(),
        "cpu_count": os.cpu_count(),
    }
    default = "p3p_rate.json" if args.dtype == "float64" else "p3p_rate_float32.json"
    # "machine" holds the platform string (as the notebook reads it), "host" the description.
    out = write_json(Path(args.out) if args.out else RESULTS / default, result, key="host")
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main()
