"""The measurements of `benchmarks/scale.py`, one configuration per call: each runs in a
fresh process (`python -m benchmarks._scale_workers '<spec as JSON>'`, through
`_harness.spawn`) so that its compile is cold and its peak memory its own, or in the
calling process (`scale.py --in-process`).

- `single_worker`: one problem of `n` matches through a jitted `jaxpose.solve` with one
  way to pick the triplets: lowering, XLA compile, first call and warm time; XLA's memory
  figure of the compiled program; the growth of the process's peak RSS.
- `batch_worker`: `jaxpose.solve_pnp_batch` over `B` problems, chunked or not: first call
  and warm time (wall and CPU), the memory of one chunk's program, the RSS growth.
"""

from __future__ import annotations

import math
import os
import resource
import sys
import threading
import time
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/_scale_workers.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from benchmarks._harness import (
    K_PIXELS,
    Stopwatch,
    batch_problems,
    compilation_cache,
    timeit,
    worker_main,
)


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _rss_mb() -> float | None:
    """The current resident set of this process (MB), from `/proc/self/statm`."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):  # pragma: no cover (not Linux)
        return None
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


class _PeakRss:
    """Peak resident memory while the block runs, above its level on entry: a thread
    samples `/proc/self/statm` every millisecond (JAX releases the GIL while a compiled
    program runs). Unlike `ru_maxrss`, it excludes the compiler's own peak."""

    def __enter__(self):
        self.base = _rss_mb()
        self.peak = self.base
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self):
        while not self._stop.is_set() and self.base is not None:
            self.peak = max(self.peak, _rss_mb())
            time.sleep(0.001)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        if self.base is not None:
            self.peak = max(self.peak, _rss_mb())

    @property
    def growth(self) -> float | None:
        return None if self.base is None else self.peak - self.base


def _memory(compiled) -> dict:
    m = compiled.memory_analysis()
    if m is None:  # pragma: no cover (a backend without the analysis)
        return {
            "temp_bytes": None,
            "argument_bytes": None,
            "output_bytes": None,
            "peak_bytes": None,
        }
    temp, arg, out = (
        int(m.temp_size_in_bytes),
        int(m.argument_size_in_bytes),
        int(m.output_size_in_bytes),
    )
    return {
        "temp_bytes": temp,
        "argument_bytes": arg,
        "output_bytes": out,
        "peak_bytes": temp + arg + out,
        "code_bytes": int(m.generated_code_size_in_bytes),
    }


def _setup_jax(cache_dir: str | None) -> None:
    jax.config.update("jax_enable_x64", True)
    if cache_dir:
        compilation_cache(cache_dir, min_compile_time_s=0, min_entry_size_bytes=0)
    jax.block_until_ready(jnp.zeros(1) + 1)  # the runtime itself, outside the measurement


def single_worker(spec: dict) -> dict:
    """One problem of `spec["n"]` matches, one strategy: compile, time, memory."""
    _setup_jax(spec.get("cache_dir"))
    n, method = spec["n"], spec.get("method", "mixed")
    max_triplets, budget = spec["max_triplets"], spec["triplet_budget"]
    scene = jp.apps.random_scene(np.random.default_rng(spec.get("seed", 0) + n), n, noise=1.0)
    args = tuple(jnp.asarray(x) for x in (scene.camera, scene.model_points, scene.image_points))
    rss0 = _maxrss_mb()

    def f(C, M, I):
        s = jp.solve(C, M, I, method=method, max_triplets=max_triplets, triplet_budget=budget)
        return s.pose.R, s.pose.t, s.error, s.accepted

    watch = Stopwatch()
    lowered = jax.jit(f).lower(*args)
    lower_s = watch.lap()
    compiled = lowered.compile()
    xla_s = watch.lap()
    with _PeakRss() as run_rss:
        timing = timeit(
            compiled,
            *args,
            warmup=1,
            repeat=spec.get("repeat", 5),
            budget_s=spec.get("budget_s", 5),
        )
    out = timing.result
    first = lower_s + xla_s + timing.first
    candidates = int(jp.strategy.triplet_indices(n, max_triplets).shape[0])
    solved = candidates if budget is None else min(candidates, budget)
    return {
        "n": n,
        "strategy": spec["strategy"],
        "method": method,
        "max_triplets": max_triplets,
        "triplet_budget": budget,
        "triplets_exhaustive": math.comb(n, 3),
        "triplets_candidates": candidates,
        "triplets_solved": solved,
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "first_call_s": first,
        "compile_s": first - timing.best,
        "warm_s": timing.best,
        "warm_cpu_s": timing.cpu,
        "calls": timing.calls,
        "memory": _memory(compiled),
        "rss_growth_mb": _maxrss_mb() - rss0,
        "rss_peak_mb": _maxrss_mb(),
        "run_rss_growth_mb": run_rss.growth,
        "error_px": float(out[2]),
        "accepted": bool(out[3]),
        "t": [float(v) for v in np.asarray(out[1])],
        "cache_dir": bool(spec.get("cache_dir")),
    }


def batch_worker(spec: dict) -> dict:
    """`solve_pnp_batch` over `spec["B"]` problems (n = 16), chunked by `chunk_size`."""
    _setup_jax(spec.get("cache_dir"))
    from jaxpose.api._batch import _compiled, _tail_size
    from jaxpose.api._pnp import (
        CHUNK,
        MIN_CHUNK,
        _batched_opencv,
        _pad_points,
        _stages,
        _values,
    )

    B, chunk_size, budget = spec["B"], spec["chunk_size"], spec["triplet_budget"]
    method, n = spec.get("method", "mixed"), spec.get("n", 16)
    K = np.array(K_PIXELS)
    obj, img = batch_problems(B, n, seed=spec.get("seed", 1))
    rss0 = _maxrss_mb()

    def call():
        return jp.solve_pnp_batch(
            obj, img, K, method=method, triplet_budget=budget, chunk_size=chunk_size
        )

    first = timeit(call, warmup=0, repeat=1)  # outside the RSS window: the compile's peak
    ok = first.result[0]
    with _PeakRss() as run_rss:
        warm = timeit(
            call, warmup=0, repeat=spec.get("repeat", 3), budget_s=spec.get("budget_s", 10)
        )
    rss1 = _maxrss_mb()
    # The program of one chunk (already built: the program's in-process memo returns it),
    # of the shape `solve_pnp_batch` runs: by default the bucket of the batch (a chunk of
    # `CHUNK`, or the smallest `MIN_CHUNK * 2^k` holding a smaller batch).
    if chunk_size is None:
        chunk = CHUNK if B >= CHUNK else _tail_size(B, CHUNK, MIN_CHUNK, 1)
    else:
        chunk = min(B, chunk_size)
    watch = Stopwatch()
    with jax.enable_x64(True):
        given = jp.Options(method=method, triplet_budget=budget)
        options = _stages(given)[0]
        prog = _compiled(_batched_opencv, (options,), (), None, 2, 3)
        rows = np.arange(chunk) % B
        o, i, m = _pad_points(obj[rows].astype(float), img[rows].astype(float))
        compiled = prog.executable(*(jnp.asarray(a) for a in (K, _values(given), o, i, m)))
    analysis_s = watch.seconds
    return {
        "B": B,
        "n": n,
        "chunk_size": chunk_size,
        "chunk": chunk,
        "method": method,
        "triplet_budget": budget,
        "first_call_s": first.best,
        "compile_s": max(first.best - warm.best, 0.0),
        "warm_s": warm.best,
        "warm_cpu_s": warm.cpu,
        "calls": warm.calls,
        "per_problem_us": 1e6 * warm.best / B,
        "per_problem_cpu_us": 1e6 * warm.cpu / B,
        "memory": _memory(compiled),
        "memory_analysis_s": analysis_s,
        "input_mb": (obj.nbytes + img.nbytes) / 2**20,
        "rss_growth_mb": rss1 - rss0,
        "rss_peak_mb": rss1,
        "run_rss_growth_mb": run_rss.growth,
        "ok": float(np.mean(ok)),
        "cache_dir": bool(spec.get("cache_dir")),
    }


WORKERS = {"single": single_worker, "batch": batch_worker}

if __name__ == "__main__":
    worker_main(WORKERS)
