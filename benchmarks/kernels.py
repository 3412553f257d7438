"""Speed of the batch-first kernels of the linear method against the vmapped references.

    python -m benchmarks.kernels            # full
    python -m benchmarks.kernels --quick    # fewer repeats, a smaller scoring batch

Sections (figures beside the reference timed in the same run, float64 and float32):

- `step`: one depth-weighted linear step (`linear_step_kernel`) for n = 16, over
  P = 1,000 / 8,000 / 100,000 problems per call, against
  `jax.jit(jax.vmap(linear_step))`; a call runs `STEPS` steps (`jax.lax.fori_loop`), the
  time is per problem and step. The target: `TARGETS["step_ns_f64"]`.
- `chunks`: the same over 100,000 problems, run in blocks of `size` problems
  (`in_chunks`, every block all its steps), for several sizes.
- `method`: `linear_kernel` (5 steps, the error and the status) against the vmapped
  `linear`, per problem.
- `scoring`: the Eq. 8 error of 4 x C(16, 3) candidate poses per problem
  (`pixel_error_kernel`, poses `(P, C)` against problems `(P, 1)`) against the vmapped
  `pose_errors`, per candidate and match.
- `compile`: first-call compile times of the jitted kernels.

Every time is the least wall time over repeats (the processor time of the same calls is
recorded too: on a shared machine it is the steadier figure). Writes
`benchmarks/results/kernels.json` (`kernels_quick.json` with `--quick`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/kernels.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from benchmarks._harness import RESULTS, Stopwatch, rich_console, timeit_many, write_json

TARGETS = {"step_ns_f64": 500.0}
STEPS = 5
N = 16
WARMUP = 3
POOL = 2000


def _kernels():
    from jaxpose.solvers import _kernel_linear as kl

    return kl


def problems(P: int, dtype, seed: int = 0):
    """`P` random problems of `N` matches (`jaxpose.apps.random_scene`, 1 px noise, tiled
    from `POOL` distinct ones) and starts 0.1 rad from the truth: `(obs, R, t)`."""
    rng = np.random.default_rng(seed)
    m = min(P, POOL)
    scenes = [jp.apps.random_scene(rng, N, noise=1.0) for _ in range(m)]
    C = np.stack([s.camera for s in scenes])
    M = np.stack([s.model_points for s in scenes])
    I = np.stack([s.image_points for s in scenes])
    axis = rng.normal(size=(m, 3))
    axis *= 0.1 / np.linalg.norm(axis, axis=1, keepdims=True)
    dR = np.asarray(jax.vmap(jp.rotvec_to_matrix)(jnp.asarray(axis)))
    R = dR @ np.stack([s.R for s in scenes])
    t = np.stack([s.t for s in scenes]) + 0.05 * rng.normal(size=(m, 3))
    idx = np.arange(P) % m
    C, M, I, R, t = (jnp.asarray(a[idx], dtype) for a in (C, M, I, R, t))
    obs = jax.jit(jax.vmap(jp.observations))(C, M, I)
    return obs, R, t


def _step_loops():
    kl = _kernels()
    from jaxpose.solvers._components import mat_from_array, vec_from_array

    def kernel(R, t, m):
        R, t = mat_from_array(R), vec_from_array(t)

        def body(_, c):
            return kl.linear_step_kernel(c[0], c[1], m)

        return jax.lax.fori_loop(0, STEPS, body, (R, t, jnp.zeros_like(t.x)))

    def reference(R, t, obs):
        from jaxpose.solvers._linear import linear_step

        step = jax.vmap(lambda R, t, o: linear_step(jp.Pose(R, t), o))

        def body(_, c):
            return step(c[0].R, c[0].t, obs)

        zero = jnp.zeros(R.shape[0], R.dtype)
        return jax.lax.fori_loop(0, STEPS, body, (jp.Pose(R, t), zero))

    return kernel, reference


def _times(timing, count: int) -> dict:
    return {
        "ns": 1e9 * timing.best / count,
        "cpu_ns": 1e9 * timing.cpu / count,
        "first_s": timing.first,
    }


def step(P: int, dtype, repeat: int, reference: bool = True) -> dict:
    kl = _kernels()
    obs, R, t = problems(P, dtype)
    m = jax.jit(kl.matches_from_observations)(obs)
    kernel, ref = _step_loops()
    fk, fr = jax.jit(kernel), jax.jit(ref)
    fns = [lambda: fk(R, t, m)] + ([lambda: fr(R, t, obs)] if reference else [])
    timings = timeit_many(fns, warmup=WARMUP, repeat=repeat)
    out = {"P": P, "kernel": _times(timings[0], P * STEPS)}
    if reference:
        out["reference"] = _times(timings[1], P * STEPS)
        out["speedup"] = timings[1].best / timings[0].best
    return out


def chunks(P: int, sizes: Sequence[int], dtype, repeat: int) -> dict:
    kl = _kernels()
    obs, R, t = problems(P, dtype)
    m = jax.jit(kl.matches_from_observations)(obs)
    kernel, _ = _step_loops()
    fns = [jax.jit(lambda R, t, m, s=s: kl.in_chunks(kernel, R, t, m, size=s)) for s in sizes]
    timings = timeit_many([lambda f=f: f(R, t, m) for f in fns], warmup=WARMUP, repeat=repeat)
    rows = {str(s): _times(tm, P * STEPS) for s, tm in zip(sizes, timings)}
    best = min(rows, key=lambda s: rows[s]["ns"])
    return {"P": P, "sizes": rows, "best_size": int(best)}


def method(P: int, dtype, repeat: int) -> dict:
    kl = _kernels()
    from jaxpose.solvers._components import mat_from_array, vec_from_array

    obs, R, t = problems(P, dtype)
    m = jax.jit(kl.matches_from_observations)(obs)
    fk = jax.jit(lambda R, t, m: kl.linear_kernel(mat_from_array(R), vec_from_array(t), m))
    fr = jax.jit(jax.vmap(lambda R, t, o: jp.solvers.linear(o, jp.Pose(R, t), iterations=STEPS)))
    tk, tr = timeit_many([lambda: fk(R, t, m), lambda: fr(R, t, obs)], warmup=WARMUP, repeat=repeat)
    return {
        "P": P,
        "iterations": STEPS,
        "kernel": _times(tk, P),
        "reference": _times(tr, P),
        "speedup": tr.best / tk.best,
    }


def scoring(P: int, dtype, repeat: int) -> dict:
    """Eq. 8 errors of `C = 4 C(N, 3)` candidates per problem."""
    kl = _kernels()
    from jaxpose.solvers._components import mat_from_array, vec_from_array
    from jaxpose.strategy._triplets import pose_errors

    C = 4 * (N * (N - 1) * (N - 2) // 6)
    obs, R, t = problems(P, dtype)
    rng = np.random.default_rng(1)
    axis = rng.normal(size=(P * C, 3))
    dR = jax.vmap(jp.rotvec_to_matrix)(jnp.asarray(axis * 0.3, dtype)).reshape(P, C, 3, 3)
    Rc = dR @ R[:, None]
    tc = t[:, None] + jnp.asarray(rng.normal(size=(P, C, 3)) * 0.1, dtype)
    m = jax.jit(kl.matches_from_observations)(obs)
    m1 = jax.tree.map(lambda a: a[:, None], m)
    fk = jax.jit(lambda R, t, m: kl.pixel_error_kernel(mat_from_array(R), vec_from_array(t), m))
    fr = jax.jit(jax.vmap(lambda R, t, o: pose_errors(jp.Pose(R, t), o)))
    tk, tr = timeit_many(
        [lambda: fk(Rc, tc, m1), lambda: fr(Rc, tc, obs)], warmup=WARMUP, repeat=repeat
    )
    count = P * C * N
    return {
        "P": P,
        "candidates": C,
        "kernel": _times(tk, count),
        "reference": _times(tr, count),
        "speedup": tr.best / tk.best,
    }


def compile_times(dtype) -> dict:
    """Tracing, lowering and compiling each kernel once (P = 8,000, n = 16, caches
    cleared first)."""
    kl = _kernels()
    from jaxpose.solvers._components import mat_from_array, vec_from_array

    obs, R, t = problems(8000, dtype)
    m = kl.matches_from_observations(obs)
    Rm, tm = mat_from_array(R), vec_from_array(t)
    kernel, _ = _step_loops()
    cases = {
        "matches_from_observations": (kl.matches_from_observations, (obs,)),
        "linear_step_kernel": (kl.linear_step_kernel, (Rm, tm, m)),
        f"{STEPS} steps (fori_loop)": (kernel, (R, t, m)),
        "linear_kernel": (kl.linear_kernel, (Rm, tm, m)),
        "pixel_error_kernel": (kl.pixel_error_kernel, (Rm, tm, m)),
    }
    out = {}
    for name, (fn, args) in cases.items():
        jax.clear_caches()  # a cold compile, not one found in memory
        watch = Stopwatch()
        jax.jit(fn).lower(*args).compile()
        out[name] = watch.seconds
    return out


def run(quick: bool = False) -> dict:
    repeat = 3 if quick else 7
    sizes = [1000, 8000, 100_000]
    res: dict = {"steps_per_call": STEPS, "n": N, "targets": TARGETS}
    res["load_average_before"] = list(os.getloadavg())
    for name, dtype in (("float64", jnp.float64), ("float32", jnp.float32)):
        sec: dict = {}
        sec["step"] = [step(P, dtype, repeat if P < 50_000 else 2) for P in sizes]
        sec["chunks"] = chunks(100_000, [500, 1000, 2000, 4000, 10_000], dtype, 2 if quick else 3)
        sec["method"] = method(8000, dtype, repeat)
        sec["scoring"] = scoring(20 if quick else 100, dtype, repeat)
        sec["compile_s"] = compile_times(dtype)
        res[name] = sec
    res["load_average_after"] = list(os.getloadavg())
    return res


def _ratio(value: float, target: float) -> str:
    verdict = "met" if value <= target else f"missed by {value / target:.2f}x"
    return f"<= {target:g} ns: {verdict}"


def print_table(res: dict, console) -> None:
    from rich.table import Table

    target = res["targets"]["step_ns_f64"]
    t = Table(title=f"Linear step, n = {res['n']} ({res['steps_per_call']} steps per call)")
    for col in (
        "dtype",
        "problems per call",
        "kernel",
        "(cpu)",
        "vmapped ref.",
        "speedup",
        "target (float64)",
    ):
        t.add_column(col, justify="right")
    for dtype in ("float64", "float32"):
        sec = res[dtype]
        for row in sec["step"]:
            k = row["kernel"]
            ref = row.get("reference")
            t.add_row(
                dtype,
                f"{row['P']:,}",
                f"{k['ns']:.0f} ns",
                f"{k['cpu_ns']:.0f} ns",
                f"{ref['ns']:.0f} ns" if ref else "",
                f"{row['speedup']:.1f}x" if ref else "",
                _ratio(k["ns"], target) if dtype == "float64" else "",
            )
        ch = sec["chunks"]
        best = ch["sizes"][str(ch["best_size"])]
        t.add_row(
            dtype,
            f"{ch['P']:,} in blocks of {ch['best_size']:,}",
            f"{best['ns']:.0f} ns",
            f"{best['cpu_ns']:.0f} ns",
            "",
            "",
            _ratio(best["ns"], target) if dtype == "float64" else "",
        )
    console.print(t)
    for dtype in ("float64", "float32"):
        sec = res[dtype]
        ch = sec["chunks"]
        blocks = ", ".join(f"{s}: {v['ns']:.0f} ns" for s, v in ch["sizes"].items())
        console.print(f"{dtype} blocks over {ch['P']:,} problems (per step): {blocks}")
        me, sc = sec["method"], sec["scoring"]
        console.print(
            f"{dtype} linear_kernel ({me['iterations']} steps + status) over {me['P']:,}: "
            f"{me['kernel']['ns']:.0f} ns per problem, vmapped linear "
            f"{me['reference']['ns']:.0f} ns ({me['speedup']:.1f}x)"
        )
        console.print(
            f"{dtype} Eq. 8 scoring, {sc['candidates']} candidates x {res['n']} matches x "
            f"{sc['P']} problems: {sc['kernel']['ns']:.2f} ns per candidate and match, "
            f"vmapped pose_errors {sc['reference']['ns']:.2f} ns ({sc['speedup']:.1f}x)"
        )
        comp = ", ".join(f"{k} {v:.1f} s" for k, v in sec["compile_s"].items())
        console.print(f"{dtype} compile: {comp}")
    console.print(
        f"load average before {res['load_average_before']}, after {res['load_average_after']}"
    )


def main(argv: Sequence[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--out", default=str(RESULTS), help="output folder")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    console = rich_console(120)
    res = run(quick=args.quick)
    path = write_json(
        Path(args.out) / ("kernels_quick.json" if args.quick else "kernels.json"), res, indent=2
    )
    print_table(res, console)
    console.print(f"wrote {path}")
    return res


if __name__ == "__main__":
    main()
