"""Scaling of jaxpose: time, peak memory and compile time versus the number of matches `n`
and the batch size `B` (issue: scaling; targets in `TARGETS`).

Sections (float64, x64 enabled by this script and by each of its worker processes):

- `n`: one problem (`jaxpose.random_scene`, 1 px noise, a general 3x4 camera) solved by a
  jitted `jaxpose.solve` for `n` in (4, 6, 10, 16, 20, 50, 100, 200), with three ways to
  pick the triplets:
  - `exhaustive`: all `C(n, 3)` (`max_triplets=None`); grows as `n^3 / 6` triplets, each
    scored over all `n` matches, so its cost grows as `n^4`;
  - `sampled`: the library's default `max_triplets=2000`: exhaustive while
    `C(n, 3) <= 2000` (n <= 23), above that a fixed, seeded uniform sample of 2000
    triplets (`jaxpose.triplet_indices(n, 2000)`), so the cost grows as `n` only;
  - `budget8`: `triplet_budget=8`, the 8 candidate triplets with the largest image
    triangles (`jaxpose.spread_triplets`), the fast path for batches.
  Per configuration: warm time (minimum over repeats of the compiled call), compile time
  (trace + lower, and XLA's compile, apart; the first call minus the warm one), the
  triplets solved, XLA's own memory figure of the compiled program
  (`memory_analysis()`: temp + argument + output bytes) and, as a cross-check, the
  growth of the worker process's peak RSS (`ru_maxrss`). Every configuration runs in a
  fresh worker process (so that every compile is cold); exhaustive runs above
  `exhaustive_max` triplets are skipped and their time projected from the `T * n` cost
  model fitted on the measured ones.
- `batch`: `jaxpose.solve_pnp_batch(n=16, triplet_budget=8)` for `B` in (1, 10, 100, 1000,
  10^4[, 10^5, 10^6]) beside a loop of `cv2.solvePnP(SQPNP)` + `cv2.solvePnPRefineLM` (per
  problem time from at most 2000 problems), with `chunk_size` in (None, 1000, 100) at the
  largest batches: the memory of one chunk's program (XLA) and the worker's RSS growth
  show that chunking bounds memory. Large batches tile a pool of 10^4 distinct problems.
- `cache`: cold compile against JAX's persistent compilation cache: the workers share a
  fresh `jax_compilation_cache_dir` (`jax_persistent_cache_min_compile_time_secs=0`); a
  configuration run again in a new process loads its executable from the cache (the
  trace and lowering to StableHLO are not cached: they are paid again).

    python benchmarks/scale.py --quick   # n in (6, 16, 50), B up to 10^4
    python benchmarks/scale.py           # everything (about half an hour on 2 cores)

Prints tables, writes `benchmarks/results/scale.json` (`scale_quick.json`) and a plot
`scale.png` (`scale_quick.png`). `run(quick, out_dir=...)` is the entry point for
`benchmarks/run.py`; `main(argv)` the command line, both return the result dict.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

TARGETS = {"compile_s": 5.0, "latency_ms": 5.0}

N_FULL = (4, 6, 10, 16, 20, 50, 100, 200)
N_QUICK = (6, 16, 50)
B_FULL = (1, 10, 100, 1000, 10_000, 100_000)
B_QUICK = (1, 10, 100, 1000, 10_000)
BUDGET = 8
SAMPLE = 2000  # the library's default max_triplets
POOL = 10_000  # distinct problems; larger batches repeat them
MARK = "SCALE_RESULT "


def _triplets(n: int) -> int:
    return n * (n - 1) * (n - 2) // 6


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
        import threading

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


def _best(fn, repeat: int, budget_s: float) -> tuple[float, int, float]:
    """Minimum wall time of `fn()` over up to `repeat` calls (at least one), stopping once
    `budget_s` seconds are spent. Returns `(seconds, calls, cpu_seconds)`: the last is the
    least process CPU time (all threads) of a call, which other processes on a loaded
    machine do not inflate (the minimum wall time of short calls can dodge them, that of
    long calls cannot: compare sizes on CPU time when the load exceeds the cores)."""
    times: list[float] = []
    cpu: list[float] = []
    start = time.perf_counter()
    while len(times) < max(1, repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if time.perf_counter() - start > budget_s:
            break
    return min(times), len(times), min(cpu)


# ----------------------------------------------------------------------------- workers


def _setup_jax(cache_dir: str | None):
    import jax

    jax.config.update("jax_enable_x64", True)
    if cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return jax


def single_worker(spec: dict) -> dict:
    """One problem of `spec["n"]` matches, one strategy: compile, time, memory."""
    jax = _setup_jax(spec.get("cache_dir"))
    import jax.numpy as jnp
    import numpy as np

    import jaxpose as jp

    n, method = spec["n"], spec.get("method", "mixed")
    max_triplets, budget = spec["max_triplets"], spec["triplet_budget"]
    scene = jp.random_scene(np.random.default_rng(spec.get("seed", 0) + n), n, noise=1.0)
    args = tuple(jnp.asarray(x) for x in (scene.camera, scene.model_points, scene.image_points))
    jax.block_until_ready(jnp.zeros(1) + 1)  # the runtime itself, outside the measurement
    rss0 = _maxrss_mb()

    def f(C, M, I):
        s = jp.solve(C, M, I, method=method, max_triplets=max_triplets, triplet_budget=budget)
        return s.pose.R, s.pose.t, s.error, s.accepted

    t0 = time.perf_counter()
    lowered = jax.jit(f).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    with _PeakRss() as run_rss:
        out = jax.block_until_ready(compiled(*args))
        t3 = time.perf_counter()
        warm, calls, cpu = _best(
            lambda: jax.block_until_ready(compiled(*args)),
            spec.get("repeat", 5),
            spec.get("budget_s", 5),
        )
    candidates = int(jp.triplet_indices(n, max_triplets).shape[0])
    solved = candidates if budget is None else min(candidates, budget)
    return {
        "n": n,
        "strategy": spec["strategy"],
        "method": method,
        "max_triplets": max_triplets,
        "triplet_budget": budget,
        "triplets_exhaustive": _triplets(n),
        "triplets_candidates": candidates,
        "triplets_solved": solved,
        "lower_s": t1 - t0,
        "xla_compile_s": t2 - t1,
        "first_call_s": t3 - t0,
        "compile_s": (t3 - t0) - warm,
        "warm_s": warm,
        "warm_cpu_s": cpu,
        "calls": calls,
        "memory": _memory(compiled),
        "rss_growth_mb": _maxrss_mb() - rss0,
        "rss_peak_mb": _maxrss_mb(),
        "run_rss_growth_mb": run_rss.growth,
        "error_px": float(out[2]),
        "accepted": bool(out[3]),
        "t": [float(v) for v in np.asarray(out[1])],
        "cache_dir": bool(spec.get("cache_dir")),
    }


def _problems(B: int, n: int, seed: int):
    """`B` problems (OpenCV's convention) tiled from at most `POOL` distinct ones."""
    import numpy as np

    import jaxpose as jp

    rng = np.random.default_rng(seed)
    m = min(B, POOL)
    scenes = [jp.random_scene(rng, n, noise=1.0, world_camera=False) for _ in range(m)]
    obj = np.stack([s.model_points for s in scenes])
    img = np.stack([s.image_points for s in scenes])
    if B > m:
        reps = math.ceil(B / m)
        obj, img = np.tile(obj, (reps, 1, 1))[:B], np.tile(img, (reps, 1, 1))[:B]
    return obj, img


K_BATCH = ((800.0, 0.0, 320.0), (0.0, 800.0, 240.0), (0.0, 0.0, 1.0))


def batch_worker(spec: dict) -> dict:
    """`solve_pnp_batch` over `spec["B"]` problems (n = 16), chunked by `chunk_size`."""
    jax = _setup_jax(spec.get("cache_dir"))
    import numpy as np

    import jaxpose as jp
    from jaxpose.api._batch import _compiled
    from jaxpose.api._solve import _batched_opencv

    B, chunk_size, budget = spec["B"], spec["chunk_size"], spec.get("triplet_budget", BUDGET)
    method, n = spec.get("method", "mixed"), spec.get("n", 16)
    K = np.array(K_BATCH)
    obj, img = _problems(B, n, spec.get("seed", 1))
    jax.block_until_ready(jax.numpy.zeros(1) + 1)
    rss0 = _maxrss_mb()

    def call():
        return jp.solve_pnp_batch(
            obj, img, K, method=method, triplet_budget=budget, chunk_size=chunk_size
        )

    t0 = time.perf_counter()
    ok, _, _ = call()
    first = time.perf_counter() - t0
    with _PeakRss() as run_rss:
        warm, calls, cpu = _best(call, spec.get("repeat", 3), spec.get("budget_s", 10))
    rss1 = _maxrss_mb()
    # The program of one chunk (already compiled: this lowering hits the in-memory cache).
    chunk = min(B, chunk_size or B)
    dev = jax.devices()[0]
    t1 = time.perf_counter()
    with jax.enable_x64(True):
        prog = _compiled(_batched_opencv, (method, budget), (), None, 1, 2)
        compiled = prog.lower(
            jax.device_put(K, dev),
            jax.device_put(obj[:chunk], dev),
            jax.device_put(img[:chunk], dev),
        ).compile()
    analysis_s = time.perf_counter() - t1
    return {
        "B": B,
        "n": n,
        "chunk_size": chunk_size,
        "chunk": chunk,
        "method": method,
        "triplet_budget": budget,
        "first_call_s": first,
        "compile_s": max(first - warm, 0.0),
        "warm_s": warm,
        "warm_cpu_s": cpu,
        "calls": calls,
        "per_problem_us": 1e6 * warm / B,
        "per_problem_cpu_us": 1e6 * cpu / B,
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


def _spawn(spec: dict, in_process: bool, timeout: float) -> dict:
    """Run one worker: in a fresh Python process (default), or here (`in_process`)."""
    if in_process:
        try:
            return WORKERS[spec["kind"]](spec)
        except Exception as e:  # pragma: no cover (reported, not fatal)
            return {"failed": f"{type(e).__name__}: {e}"}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"failed": f"timed out after {timeout:.0f} s"}
    for line in proc.stdout.splitlines():
        if line.startswith(MARK):
            return json.loads(line[len(MARK) :])
    return {"failed": f"exit {proc.returncode}: {proc.stderr.strip()[-600:]}"}


# ----------------------------------------------------------------------------- sections


def _strategies(n: int, exhaustive_max: int, budget_n=None) -> list[dict]:
    """The configurations measured at `n` (a strategy is skipped where it would repeat
    another: below 2000 triplets `sampled` is `exhaustive`, below 8 so is `budget8`)."""
    T = _triplets(n)
    out = []
    if T <= exhaustive_max:
        out.append({"strategy": "exhaustive", "max_triplets": None, "triplet_budget": None})
    if T > SAMPLE:
        out.append({"strategy": "sampled", "max_triplets": SAMPLE, "triplet_budget": None})
    if min(T, SAMPLE) > BUDGET and (budget_n is None or n in budget_n):
        out.append({"strategy": "budget8", "max_triplets": SAMPLE, "triplet_budget": BUDGET})
    return out


def _fit_exhaustive(rows: list[dict]) -> float | None:
    """Seconds per (triplet x match) of the exhaustive strategy, from its largest runs."""
    ex = [r for r in rows if r["strategy"] == "exhaustive" and "warm_s" in r and r["n"] >= 16]
    if not ex:
        return None
    ex = sorted(ex, key=lambda r: r["n"])[-2:]
    return float(sum(r["warm_s"] / (r["triplets_solved"] * r["n"]) for r in ex) / len(ex))


def _switch(rows: list[dict]) -> dict:
    """Where exhaustive triplets stop paying: the smallest measured `n` where the
    exhaustive run costs more than twice the sampled one while the sample reaches the
    same answer (final error within 1e-6 px), and where it passes the latency target."""
    by = {(r["n"], r["strategy"]): r for r in rows if "warm_s" in r}
    latency = [
        n
        for (n, s), r in sorted(by.items())
        if s == "exhaustive" and 1e3 * r["warm_s"] > TARGETS["latency_ms"]
    ]
    stop, compared = None, []
    for (n, s), r in sorted(by.items()):
        if s != "exhaustive" or (n, "sampled") not in by:
            continue
        smp = by[(n, "sampled")]
        same = abs(r["error_px"] - smp["error_px"]) <= 1e-6
        ratio = r["warm_s"] / smp["warm_s"]
        cpu = r.get("warm_cpu_s", r["warm_s"]) / max(smp.get("warm_cpu_s", smp["warm_s"]), 1e-12)
        compared.append(
            {
                "n": n,
                "exhaustive_over_sampled": ratio,
                "exhaustive_over_sampled_cpu": cpu,
                "same_answer": same,
                "error_px": [r["error_px"], smp["error_px"]],
            }
        )
        if stop is None and ratio > 2 and same:
            stop = n
    library = next(n for n in range(3, 1000) if _triplets(n) > SAMPLE)
    text = (
        f"The library switches from exhaustive to a fixed seeded sample of {SAMPLE} triplets "
        f"when C(n, 3) > {SAMPLE}, i.e. from n = {library} (max_triplets={SAMPLE}); "
        f"triplet_budget={BUDGET} keeps the {BUDGET} largest image triangles among those. "
    )
    if stop is not None:
        text += (
            f"Measured: exhaustive stops paying at n = {stop} (the {_triplets(stop)} triplets "
            f"cost {next(c['exhaustive_over_sampled'] for c in compared if c['n'] == stop):.1f}x "
            f"the {SAMPLE}-sample, which reaches the same answer; the measured n below it "
            f"have C(n, 3) <= {SAMPLE}, where the two are the same set)"
        )
    else:
        text += "Measured: no n where the sample was both >2x faster and at the same answer"
    if latency:
        text += (
            f"; the exhaustive single call passes the {TARGETS['latency_ms']:g} ms latency "
            f"target from n = {latency[0]}."
        )
    else:
        text += "."
    return {
        "library_switch_n": library,
        "max_triplets": SAMPLE,
        "exhaustive_stops_paying_n": stop,
        "exhaustive_over_latency_target_from_n": latency[0] if latency else None,
        "compared": compared,
        "text": text,
    }


def n_section(
    n_values, exhaustive_max, repeat, cache_dir, in_process, method, log, budget_n=None
) -> dict:
    rows = []
    for n in n_values:
        for cfg in _strategies(n, exhaustive_max, budget_n):
            spec = {"kind": "single", "n": n, "method": method, "repeat": repeat, **cfg}
            spec["cache_dir"] = cache_dir
            log(f"n = {n}, {cfg['strategy']}: compiling and timing")
            row = _spawn(spec, in_process, timeout=1200)
            rows.append({"n": n, **cfg, **row})
        if _triplets(n) > exhaustive_max:
            rows.append(
                {
                    "n": n,
                    "strategy": "exhaustive",
                    "max_triplets": None,
                    "triplet_budget": None,
                    "triplets_exhaustive": _triplets(n),
                    "skipped": f"C(n, 3) = {_triplets(n)} > {exhaustive_max}",
                }
            )
    per = _fit_exhaustive(rows)
    for r in rows:
        if "skipped" in r and per is not None:
            r["projected_warm_s"] = per * r["triplets_exhaustive"] * r["n"]
    return {"rows": rows, "exhaustive_s_per_triplet_match": per, "switch": _switch(rows)}


def _opencv_per_problem(count: int, n: int = 16, seed: int = 1, repeat: int = 5):
    """Seconds per problem of the OpenCV loop: the least wall and CPU time over `repeat`
    loops of (at most) 100 problems each, a duration like that of a B = 100 call."""
    import cv2
    import numpy as np

    obj, img = _problems(count, n, seed)
    K = np.array(K_BATCH)
    m = min(count, 100)

    def loop(start):
        for i in range(start, start + m):
            _, rv, tv = cv2.solvePnP(obj[i], img[i], K, None, flags=cv2.SOLVEPNP_SQPNP)
            cv2.solvePnPRefineLM(obj[i], img[i], K, None, rv, tv)

    starts = iter(range(0, max(count - m, 0) + 1, m))
    wall, _, cpu = _best(lambda: loop(next(starts, 0)), repeat, 30.0)
    return wall / m, cpu / m


def _batch_configs(sizes, quick: bool, one_call_max: int, chunks) -> list[tuple[int, int | None]]:
    """(B, chunk_size) pairs: one call up to `one_call_max` problems; above, chunks of each
    of `chunks` (the smallest only up to 10^4 problems) and, in full mode up to 10^4
    problems, the whole batch at once for the memory comparison."""
    out = []
    for B in sizes:
        if B <= one_call_max:
            out.append((B, None))
            continue
        if B <= 10_000 and not quick:
            out.append((B, None))
        for c in sorted(chunks, reverse=True):
            if c == max(chunks) or B <= 10_000:
                out.append((B, c))
    return out


def batch_section(
    sizes, quick, repeat, cache_dir, in_process, method, log, one_call_max=1000, chunks=(1000, 100)
) -> dict:
    log("OpenCV loop (SQPnP + RefineLM): timing")
    per_cv, per_cv_cpu = _opencv_per_problem(min(max(sizes), 2000))
    rows = []
    for B, chunk_size in _batch_configs(sizes, quick, one_call_max, chunks):
        spec = {
            "kind": "batch",
            "B": B,
            "chunk_size": chunk_size,
            "method": method,
            "repeat": repeat if B <= 1000 else 1,
            "cache_dir": cache_dir,
        }
        log(f"B = {B}, chunk_size = {chunk_size}: compiling and timing")
        row = _spawn(spec, in_process, timeout=3000)
        row = {"B": B, "chunk_size": chunk_size, **row}
        if "warm_s" in row:
            row["opencv_s"] = per_cv * B
            row["opencv_per_problem_us"] = 1e6 * per_cv
            row["vs_opencv"] = per_cv * B / row["warm_s"]
            row["opencv_per_problem_cpu_us"] = 1e6 * per_cv_cpu
            row["vs_opencv_cpu"] = per_cv_cpu * B / max(row["warm_cpu_s"], 1e-12)
        rows.append(row)
    return {
        "rows": rows,
        "opencv_per_problem_us": 1e6 * per_cv,
        "opencv_per_problem_cpu_us": 1e6 * per_cv_cpu,
    }


def cache_section(n_rows, b_rows, configs, cache_dir, in_process, log) -> dict:
    """Configurations run again in a fresh process: their executables now come from the
    persistent cache that their first (cold) run filled."""
    if in_process or cache_dir is None:
        return {"skipped": "needs fresh worker processes and a cache directory", "rows": []}
    rows = []
    for kind, key in configs:
        cold = next(
            (r for r in (n_rows if kind == "single" else b_rows) if _key(kind, r) == key), None
        )
        if cold is None or "failed" in cold or "skipped" in cold:
            continue
        spec = {k: cold[k] for k in _SPEC_KEYS[kind]}
        spec.update(kind=kind, cache_dir=cache_dir, repeat=1)
        log(f"cached compile: {kind} {key}")
        hot = _spawn(spec, in_process, timeout=1200)
        if "failed" in hot:
            rows.append({"kind": kind, "config": list(key), "failed": hot["failed"]})
            continue
        row = {"kind": kind, "config": list(key), "cold_compile_s": cold["compile_s"]}
        row["cached_compile_s"] = hot["compile_s"]
        if kind == "single":
            row.update(
                cold_lower_s=cold["lower_s"],
                cold_xla_s=cold["xla_compile_s"],
                cached_lower_s=hot["lower_s"],
                cached_xla_s=hot["xla_compile_s"],
                cached_rss_growth_mb=hot["rss_growth_mb"],
                cold_rss_growth_mb=cold["rss_growth_mb"],
            )
        else:
            row.update(
                cached_rss_growth_mb=hot["rss_growth_mb"], cold_rss_growth_mb=cold["rss_growth_mb"]
            )
        rows.append(row)
    # Chunked batches run a program that a smaller batch compiled before: a cache hit too.
    for r in b_rows:
        cold = next(
            (c for c in b_rows if c.get("B") == r.get("chunk") and c.get("chunk_size") is None),
            None,
        )
        if r.get("chunk_size") is None or cold is None or "warm_s" not in r or "warm_s" not in cold:
            continue
        rows.append(
            {
                "kind": "batch",
                "config": [r["B"], r["chunk_size"]],
                "cold_compile_s": cold["compile_s"],
                "cached_compile_s": r["compile_s"],
                "cold_rss_growth_mb": cold["rss_growth_mb"],
                "cached_rss_growth_mb": r["rss_growth_mb"],
                "note": f"program of B = {cold['B']} (one call) reused by chunks of {r['chunk']}",
            }
        )
    return {"rows": rows, "target_s": TARGETS["compile_s"]}


_SPEC_KEYS = {
    "single": ("n", "strategy", "max_triplets", "triplet_budget", "method"),
    "batch": ("B", "chunk_size", "method"),
}


def _key(kind: str, row: dict) -> tuple:
    if kind == "single":
        return (row.get("n"), row.get("strategy"))
    return (row.get("B"), row.get("chunk_size"))


# ----------------------------------------------------------------------------- output


def _mb(x) -> str:
    return "-" if x is None else f"{x / 2**20:.2f} MB"


def _ms(x) -> str:
    return "-" if x is None else (f"{1e3 * x:.2f} ms" if x < 10 else f"{x:.1f} s")


def _rss(r: dict) -> str:
    run = r.get("run_rss_growth_mb")
    return f"{'-' if run is None else f'{run:.1f}'} MB (+{r['rss_growth_mb']:.0f})"


def print_tables(res: dict, console) -> None:
    from rich.table import Table

    t = Table(title="One problem vs n (jit(jaxpose.solve), float64, 1 px)")
    cols = ("n", "strategy", "triplets", "warm (CPU)", "compile (trace+XLA)", "XLA peak")
    cols += ("RSS run (+compile)",)
    for c in cols + ("error px",):
        t.add_column(c, justify="left" if c == "strategy" else "right")
    for r in res["n"]["rows"]:
        if "skipped" in r:
            proj = r.get("projected_warm_s")
            t.add_row(
                str(r["n"]),
                r["strategy"],
                str(r["triplets_exhaustive"]),
                f"~{_ms(proj)} (projected)" if proj else "-",
                "skipped",
                "",
                "",
                "",
            )
            continue
        if "failed" in r:
            t.add_row(str(r["n"]), r["strategy"], "", "failed", r["failed"][:60], "", "", "")
            continue
        t.add_row(
            str(r["n"]),
            r["strategy"],
            f"{r['triplets_solved']} of {r['triplets_exhaustive']}",
            f"{_ms(r['warm_s'])} ({_ms(r['warm_cpu_s'])})",
            f"{r['compile_s']:.1f} s ({r['lower_s']:.1f}+{r['xla_compile_s']:.1f})",
            _mb(r["memory"]["peak_bytes"]),
            _rss(r),
            f"{r['error_px']:.4f}",
        )
    console.print(t)
    console.print(res["n"]["switch"]["text"])

    b = Table(title="Batches: solve_pnp_batch(n = 16, triplet_budget = 8) vs OpenCV loop")
    cols = ("B", "chunk", "time", "per problem", "OpenCV", "jaxpose is", "CPU: is")
    for c in cols + ("first call", "XLA peak / chunk", "RSS run (+compile)"):
        b.add_column(c, justify="right")
    for r in res["batch"]["rows"]:
        if "failed" in r:
            b.add_row(str(r["B"]), str(r["chunk_size"]), "failed", r["failed"][:60])
            continue
        b.add_row(
            str(r["B"]),
            str(r["chunk"]),
            _ms(r["warm_s"]),
            f"{r['per_problem_us']:.0f} us",
            f"{r['opencv_per_problem_us']:.0f} us",
            f"{r['vs_opencv']:.2f}x",
            f"{r['per_problem_cpu_us']:.0f}/{r['opencv_per_problem_cpu_us']:.0f} us "
            f"{r['vs_opencv_cpu']:.2f}x",
            f"{r['first_call_s']:.1f} s",
            _mb(r["memory"]["peak_bytes"]),
            _rss(r),
        )
    console.print(b)
    c = res["cache"]
    if c.get("rows"):
        ct = Table(
            title=f"Compile: cold vs persistent cache (target <= {TARGETS['compile_s']:g} s)"
        )
        for col in ("config", "cold", "cached", "of which trace+lower (cached)", "RSS cold/cached"):
            ct.add_column(col, justify="right")
        for r in c["rows"]:
            if "failed" in r:
                ct.add_row(str(r["config"]), "failed", r["failed"][:60], "", "")
                continue
            ct.add_row(
                f"{r['kind']} {r['config']}",
                f"{r['cold_compile_s']:.1f} s",
                f"{r['cached_compile_s']:.1f} s",
                f"{r['cached_lower_s']:.1f} s" if "cached_lower_s" in r else "-",
                f"{r['cold_rss_growth_mb']:.0f} / {r['cached_rss_growth_mb']:.0f} MB",
            )
        console.print(ct)
    else:
        console.print(f"compile cache: {c.get('skipped', 'no rows')}")


def plot(res: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    rows = [r for r in res["n"]["rows"] if "warm_s" in r]
    for s, style in (("exhaustive", "o-"), ("sampled", "s-"), ("budget8", "^-")):
        rs = sorted((r for r in rows if r["strategy"] == s), key=lambda r: r["n"])
        if s == "sampled":  # below 2000 triplets the sample is the exhaustive set
            rs = sorted(
                [
                    r
                    for r in rows
                    if r["strategy"] == "exhaustive" and r["triplets_exhaustive"] <= SAMPLE
                ]
                + rs,
                key=lambda r: r["n"],
            )
        if not rs:
            continue
        ns = [r["n"] for r in rs]
        label = f"sampled ({SAMPLE}; = exhaustive below)" if s == "sampled" else s
        ax[0, 0].loglog(ns, [r["warm_s"] for r in rs], style, label=label)
        ax[0, 1].loglog(ns, [r["memory"]["peak_bytes"] / 2**20 for r in rs], style, label=label)
    proj = [r for r in res["n"]["rows"] if r.get("projected_warm_s")]
    if proj:
        ax[0, 0].loglog(
            [r["n"] for r in proj],
            [r["projected_warm_s"] for r in proj],
            "o",
            mfc="none",
            color="C0",
            label="exhaustive (projected)",
        )
    sw = res["n"]["switch"]["library_switch_n"]
    for a in ax[0]:
        a.axvline(sw, color="grey", ls=":", lw=1)
        a.set_xlabel("matches n")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    ax[0, 0].set_ylabel("warm time, one problem (s)")
    ax[0, 1].set_ylabel("XLA peak memory (MB)")
    ax[0, 0].set_title(f"dotted: library switch to a {SAMPLE}-sample (n = {sw})", fontsize=9)
    brows = [r for r in res["batch"]["rows"] if "warm_s" in r]
    chunks = sorted({r["chunk"] for r in brows if r["chunk_size"] is not None})
    one = sorted((r for r in brows if r["chunk_size"] is None), key=lambda r: r["B"])
    if one:
        ax[1, 0].loglog(
            [r["B"] for r in one],
            [r["per_problem_us"] for r in one],
            "o-",
            label="jaxpose, one call",
        )
        ax[1, 1].loglog(
            [r["B"] for r in one],
            [r["memory"]["peak_bytes"] / 2**20 for r in one],
            "o-",
            label="XLA peak, one call",
        )
        ax[1, 1].loglog(
            [r["B"] for r in one],
            [max(r["run_rss_growth_mb"] or 0, 1e-2) for r in one],
            "o--",
            label="RSS growth while running, one call",
        )
    for i, c in enumerate(chunks):
        rs = sorted((r for r in brows if r["chunk"] == c and r["chunk_size"]), key=lambda r: r["B"])
        ax[1, 0].loglog(
            [r["B"] for r in rs],
            [r["per_problem_us"] for r in rs],
            "s",
            color=f"C{i + 2}",
            label=f"jaxpose, chunks of {c}",
        )
        ax[1, 1].loglog(
            [r["B"] for r in rs],
            [r["memory"]["peak_bytes"] / 2**20 for r in rs],
            "s",
            color=f"C{i + 2}",
            label=f"XLA peak, chunks of {c}",
        )
        ax[1, 1].loglog(
            [r["B"] for r in rs],
            [max(r["run_rss_growth_mb"] or 0, 1e-2) for r in rs],
            "x",
            color=f"C{i + 2}",
            label=f"RSS growth while running, chunks of {c}",
        )
    if one:
        ax[1, 0].loglog(
            [r["B"] for r in one],
            [r["per_problem_cpu_us"] for r in one],
            "o:",
            color="C0",
            mfc="none",
            label="jaxpose, one call, CPU time",
        )
    cv = res["batch"]["opencv_per_problem_us"]
    ax[1, 0].axhline(cv, color="k", ls="--", lw=1, label="OpenCV SQPnP + RefineLM loop")
    ax[1, 0].axhline(
        res["batch"]["opencv_per_problem_cpu_us"], color="k", ls=":", lw=1, label="OpenCV, CPU time"
    )
    ax[1, 0].set_ylabel("time per problem (us): wall, and CPU (dotted)")
    ax[1, 1].set_ylabel("memory (MB)")
    for a in ax[1]:
        a.set_xlabel("problems in the batch B (n = 16, triplet_budget = 8)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7)
    from matplotlib.ticker import ScalarFormatter

    for a in ax.flat:
        a.xaxis.set_major_formatter(ScalarFormatter())
        a.xaxis.set_minor_formatter(plt.NullFormatter())
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- entry points


def run(
    quick: bool = False,
    *,
    out_dir: str | Path | None = None,
    console=None,
    n_values=None,
    batch_sizes=None,
    method: str = "mixed",
    repeat: int | None = None,
    exhaustive_max: int | None = None,
    in_process: bool = False,
    cache: bool = True,
    cache_configs=None,
    one_call_max: int = 1000,
    chunks=(1000, 100),
) -> dict:
    """Measure every section; with `out_dir`, write the JSON and the plot there and print
    the tables. Returns the result dict."""
    from rich.console import Console

    console = console or Console(width=None if sys.stdout.isatty() else 140)
    n_values = tuple(n_values or (N_QUICK if quick else N_FULL))
    batch_sizes = tuple(batch_sizes or (B_QUICK if quick else B_FULL))
    repeat = repeat or (3 if quick else 5)
    exhaustive_max = exhaustive_max or (20_000 if quick else 200_000)
    start = time.perf_counter()
    load = [os.getloadavg()]

    def log(msg: str) -> None:
        load.append(os.getloadavg())
        console.log(msg)

    with tempfile.TemporaryDirectory(prefix="jaxpose-scale-cache-") as tmp:
        cache_dir = tmp if cache and not in_process else None
        budget_n = (16,) if quick else None  # quick: the budgeted path at n = 16 only
        nres = n_section(
            n_values, exhaustive_max, repeat, cache_dir, in_process, method, log, budget_n
        )
        bres = batch_section(
            batch_sizes, quick, repeat, cache_dir, in_process, method, log, one_call_max, chunks
        )
        if cache_configs is None:
            singles = [("single", _key("single", r)) for r in nres["rows"] if "warm_s" in r]
            batches = [
                ("batch", _key("batch", r))
                for r in bres["rows"]
                if "warm_s" in r and r["chunk_size"] is None
            ]
            if quick:  # the paper-size problem only (chunked batches reuse programs anyway)
                singles = [s for s in singles if s[1] == (16, "exhaustive")]
                batches = []
            cache_configs = singles + batches
        cres = cache_section(nres["rows"], bres["rows"], cache_configs, cache_dir, in_process, log)
    load.append(os.getloadavg())
    try:
        sys.path.insert(0, str(HERE))
        from run import machine

        info = machine()
    except Exception as e:  # pragma: no cover
        info = {"error": str(e)}
    res = {
        "n": nres,
        "batch": bres,
        "cache": cres,
        "targets": TARGETS,
        "quick": quick,
        "method": method,
        "in_process": in_process,
        "load_average": {
            "max_1min": max(x[0] for x in load),
            "min_1min": min(x[0] for x in load),
            "samples": [list(x) for x in load],
        },
        "machine": info,
        "seconds": time.perf_counter() - start,
    }
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        name = "scale_quick" if quick else "scale"
        (out / f"{name}.json").write_text(json.dumps(res, indent=2))
        plot(res, out / f"{name}.png")
        print_tables(res, console)
        console.print(
            f"wrote {out / (name + '.json')} and {name}.png ({res['seconds']:.0f} s; load "
            f"{res['load_average']['min_1min']:.1f}-{res['load_average']['max_1min']:.1f})"
        )
    return res


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="n in (6, 16, 50), B up to 10^4")
    parser.add_argument("--out", default=str(HERE / "results"))
    parser.add_argument("--n", type=int, nargs="+", default=None, help="numbers of matches")
    parser.add_argument("--batch", type=int, nargs="+", default=None, help="batch sizes")
    parser.add_argument("--method", default="mixed")
    parser.add_argument("--repeat", type=int, default=None)
    parser.add_argument("--exhaustive-max", type=int, default=None)
    parser.add_argument("--chunks", type=int, nargs="+", default=[1000, 100])
    parser.add_argument("--one-call-max", type=int, default=1000, help="larger B: chunked")
    parser.add_argument("--in-process", action="store_true", help="no worker processes")
    parser.add_argument("--no-cache", action="store_true", help="skip the compile-cache runs")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        spec = json.loads(args.worker)
        res = WORKERS[spec["kind"]](spec)
        print(MARK + json.dumps(res), flush=True)
        return res
    import jax

    jax.config.update("jax_enable_x64", True)
    return run(
        args.quick,
        out_dir=args.out,
        n_values=args.n,
        batch_sizes=args.batch,
        method=args.method,
        repeat=args.repeat,
        exhaustive_max=args.exhaustive_max,
        in_process=args.in_process,
        cache=not args.no_cache,
        one_call_max=args.one_call_max,
        chunks=tuple(args.chunks),
    )


if __name__ == "__main__":
    main()
