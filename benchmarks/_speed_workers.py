"""The measurement of `benchmarks/speed.py` that needs a fresh process: the peak resident
memory of a process making the batch benchmark's `jaxpose.solve_pnp_batch` call
(`python -m benchmarks._speed_workers '<spec as JSON>'`, through `_harness.spawn`).

- `batch_worker`: draws `B` problems of `n` matches (`_harness.batch_problems`, as the
  `batch` section does), then calls `solve_pnp_batch` with its defaults twice (the first
  call compiles); reports the process's peak resident memory, compile included (`VmHWM`;
  `ru_maxrss` beside it, which is not this process's own figure: a process started by
  `vfork` + `exec`, as `subprocess` does, inherits its parent's `ru_maxrss`), its RSS
  before the call, the two calls' times and the share of accepted problems.
"""

from __future__ import annotations

import sys
from pathlib import Path

if __name__ == "__main__" and not __package__:  # run as `python benchmarks/_speed_workers.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax
import numpy as np

import jaxpose as jp
from benchmarks._harness import K_PIXELS, Stopwatch, batch_problems, peak_memory_mb, worker_main


def _rss_mb() -> float | None:
    """The current resident memory of this process (MB; `None` off Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:  # pragma: no cover - not Linux
        pass
    return None


def batch_worker(spec: dict) -> dict:
    """`solve_pnp_batch` (defaults) over `spec["B"]` problems of `spec["n"]` matches."""
    jax.config.update("jax_enable_x64", True)
    B, n, seed = spec["B"], spec.get("n", 16), spec.get("seed", 1)
    obj, img = batch_problems(B, n, seed=seed, pool=B)
    before = _rss_mb()
    watch = Stopwatch()
    ok, _, _ = jp.solve_pnp_batch(obj, img, K_PIXELS)
    first = watch.lap()
    jp.solve_pnp_batch(obj, img, K_PIXELS)
    warm = watch.lap()
    peak = peak_memory_mb()
    return {
        "B": B,
        "n": n,
        "peak_mb": peak["ru_maxrss"] if peak["vm_hwm"] is None else peak["vm_hwm"],
        "vm_hwm_mb": peak["vm_hwm"],
        "ru_maxrss_mb": peak["ru_maxrss"],
        "rss_before_call_mb": before,
        "input_mb": (obj.nbytes + img.nbytes) / 2**20,
        "first_call_s": first,
        "warm_s": warm,
        "compile_s": max(first - warm, 0.0),
        "ok": float(np.mean(ok)),
    }


WORKERS = {"batch": batch_worker}

if __name__ == "__main__":
    worker_main(WORKERS)
