"""What every benchmark shares: the machine description, timing, fresh worker processes,
the problems several benchmarks draw, JSON output and the wording of targets.

- `machine()`, `versions()`: what the figures were measured on and with.
- `timeit(fn, *args, ...)` (and `timeit_many` for functions timed alternately): warm-up
  calls, then the wall and process-CPU time of each timed call, outputs blocked on with
  `jax.block_until_ready`; `Stopwatch` for one-off durations (a loop over problems, a
  compile, a whole run).
- `spawn(module, spec)` / `worker_main(workers)`: one measurement in a fresh Python
  process (cold compiles, a clean peak memory), its result sent back as JSON;
  `peak_memory_mb()`: the peak resident memory of this process.
- Problems: `K_PIXELS` (f = 800 px, 640x480), `bench_problem` (the paper's bench),
  `batch_problems` (independent random scenes, OpenCV's convention), `opencv_block` (the
  OpenCV SQPnP + RefineLM loop they are compared with), `random_rotations`.
- `rotation_angle`: the angle between rotations, accurate at small angles.
- `write_json(path, result)`: the result with the machine description and a timestamp.
- `verdict`, `against`, `times_faster`: "met" / "missed by 2.7x", "<= 3 ms: met".
- `rich_console(width)`, `compilation_cache(path)`: a rich console, JAX's persistent cache.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

import jaxpose as jp
from jaxpose.apps._bench import random_rotations as random_rotations

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

# --------------------------------------------------------------------------- machine

PACKAGES = ("jax", "jaxlib", "numpy", "optimistix", "equinox", "poselib", "matplotlib")


def _package_versions() -> dict:
    out: dict[str, str | None] = {"jaxpose": jp.__version__, "opencv": cv2.__version__}
    for pkg in PACKAGES:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            out[pkg] = None
    return out


def versions() -> dict:
    """The versions of jaxpose, OpenCV and the numerical packages (`None`: not
    installed), and the repository's commit."""
    out = _package_versions()
    try:
        out["jaxpose_commit"] = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):  # pragma: no cover
        out["jaxpose_commit"] = None
    return out


def _proc_field(path: str, prefix: str) -> str | None:
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(prefix):
                return line.split(":", 1)[1].strip()
    except OSError:  # pragma: no cover - not Linux
        pass
    return None


def _simd() -> str | None:
    """The widest x86 vector extension the processor has (`"avx512f"`, `"avx2"`...): the
    machines named alike ("AMD EPYC") come with AVX2 only or with AVX-512, and their
    timings differ by that."""
    flags = set((_proc_field("/proc/cpuinfo", "flags") or "").split())
    return next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), None)


def machine() -> dict:
    """The machine, the load on it and the versions that matter for timings.

    `cores` and `cpu_count`, `devices` and `jax_devices` are the same figures under the
    names of the earlier result files (both are read by the notebook)."""
    memory = _proc_field("/proc/meminfo", "MemTotal")
    try:
        devices = [str(d) for d in jax.devices()]
    except RuntimeError:  # pragma: no cover
        devices = []
    info = {
        "cpu": _proc_field("/proc/cpuinfo", "model name")
        or platform.processor()
        or platform.machine(),
        "simd": _simd(),
        "cores": os.cpu_count(),
        "cpu_count": os.cpu_count(),
        "memory_gb": round(int(memory.split()[0]) / 2**20, 1) if memory else None,
        "load_average": list(os.getloadavg()),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "devices": devices,
        "jax_devices": devices,
    }
    keep = ("jax", "jaxlib", "jaxpose", "numpy", "opencv", "poselib")
    return info | {k: v for k, v in _package_versions().items() if k in keep}


# --------------------------------------------------------------------------- timing


@dataclasses.dataclass(frozen=True)
class Timing:
    """The timed calls of one function.

    - `times`, `cpu_times`: wall and process-CPU seconds per call, one entry per timed
      sample (a sample of `number` calls counts once, divided by `number`). CPU time
      counts every thread of this process: other processes on a loaded machine do not
      inflate it (the least wall time of short calls can dodge them, that of long calls
      cannot).
    - `first`: wall seconds of the first warm-up call (compile included), or `None`.
    - `result`: the output of the last call.
    """

    times: tuple[float, ...]
    cpu_times: tuple[float, ...]
    first: float | None
    result: Any = dataclasses.field(repr=False)

    @property
    def best(self) -> float:
        return min(self.times)

    @property
    def median(self) -> float:
        return statistics.median(self.times)

    @property
    def cpu(self) -> float:
        return min(self.cpu_times)

    @property
    def calls(self) -> int:
        return len(self.times)


def timeit_many(
    fns: Sequence[Callable],
    *args,
    warmup: int = 1,
    repeat: int = 5,
    number: int = 1,
    budget_s: float | None = None,
    block: bool = True,
) -> list[Timing]:
    """Time several functions of the same arguments alternately, so that the load of a
    shared machine weighs on all alike.

    **Arguments:**
    - `fns`: the functions, each called as `fn(*args)`.
    - `warmup`: untimed rounds first (each function once per round, in order); the
      first round's wall times are kept as `Timing.first`.
    - `repeat`: timed rounds (at least one); `number`: calls per timed sample.
    - `budget_s`: stop after the round during which this many seconds of timed rounds
      have passed.
    - `block`: wait for the outputs with `jax.block_until_ready` inside the timed window
      (`False` for functions returning host values, e.g. OpenCV's).

    **Returns:** one `Timing` per function.
    """

    def call(fn):
        out = fn(*args)
        return jax.block_until_ready(out) if block else out

    k = len(fns)
    first: list[float | None] = [None] * k
    result: list[Any] = [None] * k
    for w in range(warmup):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            result[i] = call(fn)
            if w == 0:
                first[i] = time.perf_counter() - t0
    wall: list[list[float]] = [[] for _ in fns]
    cpu: list[list[float]] = [[] for _ in fns]
    start = time.perf_counter()
    while len(wall[0]) < max(1, repeat):
        for i, fn in enumerate(fns):
            c0 = time.process_time()
            t0 = time.perf_counter()
            for _ in range(number):
                result[i] = call(fn)
            t1 = time.perf_counter()
            c1 = time.process_time()
            wall[i].append((t1 - t0) / number)
            cpu[i].append((c1 - c0) / number)
        if budget_s is not None and time.perf_counter() - start > budget_s:
            break
    return [Timing(tuple(w), tuple(c), f, r) for w, c, f, r in zip(wall, cpu, first, result)]


def timeit(
    fn: Callable,
    *args,
    warmup: int = 1,
    repeat: int = 5,
    number: int = 1,
    budget_s: float | None = None,
    block: bool = True,
) -> Timing:
    """`fn(*args)`: `warmup` untimed calls (the first one's time kept as `first`), then
    `repeat` timed samples of `number` calls each (see `timeit_many`). `Timing.best` is
    the least wall time per call, `Timing.median` the median."""
    (out,) = timeit_many(
        (fn,), *args, warmup=warmup, repeat=repeat, number=number, budget_s=budget_s, block=block
    )
    return out


def side_by_side(ours, peer, rounds: int, calls: int) -> dict:
    """`ours` (a fast call) and `peer` (a slow one) timed in alternating rounds, so that
    a change of load on a shared machine weighs on both alike: each round times `calls`
    back-to-back calls of `ours`, then one of `peer`. Returns the least wall time of each
    (ms), and the median over rounds of `ours`' first call of a round (`after_peer_ms`:
    the call that follows the peer's, when `ours`' code and threads have gone cold)."""
    best, first, peer_best = math.inf, [], math.inf
    for _ in range(rounds):
        for i in range(calls):
            t0 = time.perf_counter()
            ours()
            dt = time.perf_counter() - t0
            best = min(best, dt)
            if i == 0:
                first.append(dt)
        t0 = time.perf_counter()
        peer()
        peer_best = min(peer_best, time.perf_counter() - t0)
    return {
        "ms": 1e3 * best,
        "peer_ms": 1e3 * peer_best,
        "after_peer_ms": 1e3 * statistics.median(first),
    }


class Stopwatch:
    """Wall seconds since it was made (`seconds`) and since the previous `lap()`."""

    def __init__(self) -> None:
        self.start = self._lap = time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.start

    def lap(self) -> float:
        now = time.perf_counter()
        out, self._lap = now - self._lap, now
        return out


# --------------------------------------------------------------------------- workers

MARK = "BENCHMARK_RESULT "


def spawn(module: str, spec: dict, *, timeout: float) -> dict:
    """Run `python -m <module> '<spec as JSON>'` in a fresh process at the repository
    root; `module` ends with `worker_main(...)`. Returns the dict the worker printed, or
    `{"failed": why}` (a timeout, a crash: reported, not raised)."""
    cmd = [sys.executable, "-m", module, json.dumps(spec)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"failed": f"timed out after {timeout:.0f} s"}
    for line in proc.stdout.splitlines():
        if line.startswith(MARK):
            return json.loads(line[len(MARK) :])
    return {"failed": f"exit {proc.returncode}: {proc.stderr.strip()[-600:]}"}


def worker_main(workers: dict[str, Callable[[dict], dict]], argv: Sequence[str] | None = None):
    """The worker side of `spawn`: run `workers[spec["kind"]](spec)` for the JSON spec in
    `argv[0]` and print its result on one marked line."""
    spec = json.loads((sys.argv[1:] if argv is None else argv)[0])
    res = workers[spec["kind"]](spec)
    print(MARK + json.dumps(res), flush=True)
    return res


def peak_memory_mb() -> dict:
    """The peak resident memory of this process so far (MB): `vm_hwm` (`VmHWM` of
    `/proc/self/status`; `None` off Linux) and `ru_maxrss` (`getrusage`). In a process
    started by `subprocess` (`vfork` + `exec`), `ru_maxrss` starts at the parent's peak:
    `vm_hwm` is the process's own figure."""
    hwm = _proc_field("/proc/self/status", "VmHWM")
    return {
        "ru_maxrss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "vm_hwm": int(hwm.split()[0]) / 1024.0 if hwm else None,
    }


# --------------------------------------------------------------------------- problems

K_PIXELS = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
K_PIXELS.setflags(write=False)
"""Intrinsics of the random problems: f = 800 px, a 640x480 image, centred."""


def bench_problem(seed: int = 0):
    """The paper's bench (`jaxpose.apps.default_bench(seed)`) and its camera, model and
    image points as JAX arrays: `(bench, (C, M, I))`."""
    bench = jp.apps.default_bench(seed=seed)
    arrays = tuple(jnp.asarray(x) for x in (bench.camera, bench.model_points, bench.image_points))
    return bench, arrays


def batch_problems(
    count: int, n: int = 16, *, seed: int = 1, pool: int = 10_000, noise: float = 1.0
) -> tuple[Float[np.ndarray, "B n 3"], Float[np.ndarray, "B n 2"]]:
    """`count` random problems of `n` matches with `noise` px (`jaxpose.apps.random_scene`,
    OpenCV's convention: camera-frame object points, pixels for `K_PIXELS`), tiled from
    at most `pool` distinct ones. The first `k` problems of a larger draw are those of a
    draw of `k` (same `seed`)."""
    rng = np.random.default_rng(seed)
    m = min(count, pool)
    scenes = [jp.apps.random_scene(rng, n, noise=noise, world_camera=False) for _ in range(m)]
    obj = np.stack([s.model_points for s in scenes])
    img = np.stack([s.image_points for s in scenes])
    if count > m:
        reps = -(-count // m)
        obj, img = np.tile(obj, (reps, 1, 1))[:count], np.tile(img, (reps, 1, 1))[:count]
    return obj, img


def opencv_block(obj, img, K, start: int, count: int) -> None:
    """The OpenCV baseline of the batch benchmarks: `cv2.solvePnP(SQPNP)` then
    `cv2.solvePnPRefineLM` on problems `start .. start + count - 1`."""
    for i in range(start, start + count):
        _, rv, tv = cv2.solvePnP(obj[i], img[i], K, None, flags=cv2.SOLVEPNP_SQPNP)
        cv2.solvePnPRefineLM(obj[i], img[i], K, None, rv, tv)


def rotation_angle(R_a, R_b):
    """The angle (radians) of `R_a^T R_b`, from `|R_a - R_b|_F = 2 sqrt(2) sin(angle / 2)`:
    accurate at small angles, unlike `acos` of the trace. Any batch shape."""
    frob = np.linalg.norm(np.asarray(R_a) - np.asarray(R_b), axis=(-2, -1))
    return 2 * np.arcsin(np.clip(frob / (2 * np.sqrt(2)), 0, 1))


# --------------------------------------------------------------------------- output


def write_json(path: str | Path, result: dict, *, indent: int = 1, key: str = "machine") -> Path:
    """Write `result` as JSON at `path` (its folder made), after adding to it (in place)
    the machine description under `key` unless already there, and `timestamp` (UTC,
    ISO 8601)."""
    result.setdefault(key, machine())
    result["timestamp"] = datetime.now(UTC).isoformat(timespec="seconds")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=indent))
    return path


def verdict(value: float, target: float, *, higher_is_better: bool) -> str:
    """`"met"`, or how far from the target: `"missed by 2.7x"`."""
    met = value >= target if higher_is_better else value <= target
    if met:
        return "met"
    factor = target / value if higher_is_better else value / target
    return f"missed by {factor:.1f}x"


def against(value: float, target: float, *, higher_is_better: bool, unit: str = "") -> str:
    """The target and the verdict: `"<= 3 ms: missed by 2.7x"`, `">= 30x: met"`."""
    sign = ">=" if higher_is_better else "<="
    return f"{sign} {target:g}{unit}: {verdict(value, target, higher_is_better=higher_is_better)}"


def times_faster(ratio: float, digits: int = 1) -> str:
    """A speed ratio (peer time / jaxpose time): `"15.1x faster"`."""
    return f"{ratio:.{digits}f}x faster"


def rich_console(width: int = 120):
    """A rich console: the terminal's width, or `width` columns when not a terminal."""
    from rich.console import Console

    return Console(width=None if sys.stdout.isatty() else width)


def compilation_cache(
    path: str | Path | None = None,
    *,
    min_compile_time_s: float = 0.5,
    min_entry_size_bytes: int | None = None,
) -> None:
    """JAX's persistent compilation cache in `path` (default the one the `jaxpose`
    command shares, `~/.cache/jaxpose/xla`): a second run loads its compiled programs
    instead of compiling them again."""
    cache = Path(path) if path is not None else Path.home() / ".cache" / "jaxpose" / "xla"
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError:  # pragma: no cover - read-only home
        return
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_time_s)
    if min_entry_size_bytes is not None:
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", min_entry_size_bytes)
